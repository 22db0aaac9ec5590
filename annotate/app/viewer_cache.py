"""The cameras' videos and mask outlines a page of the annotation app shows in its viewer:
which frames a page covers (``page_frames``) and their encoding ahead of the first page load
(``prepare_viewer``, cached by s2p_review.video_asset), apart from the page's session so that
``s2p annotate`` can prepare them without building a page."""

from __future__ import annotations


def page_frames(scene, run, cameras, frames) -> tuple[list[str], int, int, dict]:
    """(cameras shown, first, last frame, camera -> frames with video) of a page: what
    ``log_scene`` would log, from the selection and the cached video assets alone."""
    from s2p_review.selection import select
    from s2p_review.video_asset import video_asset

    sel = select(scene, [run] if run is not None else [], frames, cameras)
    video = {}
    for c in sel.cameras:
        asset = video_asset(scene, c, sel.first, sel.last)  # cached by prepare_viewer
        video[c] = set(map(int, asset.frames)) if asset is not None else set()
    return sel.cameras, sel.first, sel.last, video


def prepare_viewer(scene_dir, run=None, cameras=None) -> None:
    """Encode the cameras' videos and mask outlines for the viewer before a page asks for them
    (cached: s2p_review.video_asset), with a progress bar here, so that the first page load
    does not wait silently. The same frames and cameras as a page's (``log_scene``)."""
    from tqdm import tqdm

    from annotate.estimates import scene_frames
    from s2p_review.recording import outline_table
    from s2p_review.selection import select
    from s2p_review.video_asset import video_asset
    from seg2pose.io.scene import load_scene

    scene = load_scene(scene_dir)
    frames = scene_frames(scene) or (0, 0)
    sel = select(scene, [run] if run is not None else [], frames, cameras)
    for cam in tqdm(sel.cameras, desc="camera views for the viewer (cached: quick after the first start)",
                    unit="camera", leave=False):
        video_asset(scene, cam, sel.first, sel.last)
        if scene.masks_path(cam).exists():
            outline_table(scene, cam, sel.first, sel.last)
