"""Training on annotated ground truth: interpolated frames used, occluded ones skipped, and
keyframes only on request (masks are matched against every annotated row first, so that a
skipped row never lends its mask to a neighbour)."""

import numpy as np
from review_fixtures import make_scene

from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.training.examples import annotated_examples


def test_sources_select_the_examples(tmp_path):
    scene = make_scene(tmp_path / "scene", n_frames=20)
    gt = read_poses(scene.gt_path)
    source = np.where(gt.frame % 5 == 0, "keyframe", "interpolated").astype(object)
    source[gt.frame < 4] = "occluded"
    annotated = PoseTable(gt.frame, gt.track_id, gt.cls, gt.xyz, gt.heading, gt.size, source)

    def examples(truth, **kw):
        ex = annotated_examples(scene, "c0", truth, None, 64, 4, **kw)
        return ex.target[np.lexsort(ex.target.T)]

    everything = examples(gt)
    used = examples(annotated, sources=("keyframe", "interpolated"))
    assert np.array_equal(used, examples(gt.take(gt.frame >= 4)))
    assert 0 < len(used) < len(everything)
    keyframes = examples(annotated, sources=("keyframe",))
    assert np.array_equal(keyframes, examples(gt.take((gt.frame >= 4) & (gt.frame % 5 == 0))))
    # a table without sources (truth from elsewhere) is used whole
    assert np.array_equal(examples(gt, sources=("keyframe",)), everything)


def test_config_names_the_rows():
    from seg2pose.training.config import TrainConfig
    from seg2pose.training.training_data import truth_sources

    # never unchecked estimates nor occluded rows
    assert truth_sources(TrainConfig.quick()) == ("keyframe", "estimate-accepted", "interpolated",
                                                  "reviewed")
    assert truth_sources(TrainConfig.quick().replace(annotated_rows="keyframes")) == (
        "keyframe", "estimate-accepted")
