"""The one source of road-user sizes (``seg2pose.io.scene.road_user_sizes``) used by review,
MCAP export and conflicts: rows' own sizes first, then the scene's class sizes, then a car."""

from __future__ import annotations

import numpy as np

from seg2pose.io.scene import DEFAULT_CLASS_SIZES, road_user_sizes


def test_class_sizes_by_name_then_lower_case_and_unknown_as_a_car():
    out, unknown = road_user_sizes(np.array(["car", "Pedestrian", "zeppelin", "car"], object))
    np.testing.assert_array_equal(out, [[4.5, 1.8, 1.5], [0.6, 0.6, 1.75], [4.5, 1.8, 1.5],
                                        [4.5, 1.8, 1.5]])
    assert unknown == ["zeppelin"]


def test_own_sizes_win_where_finite_element_by_element():
    own = np.array([[5.0, np.nan, 2.0], [np.nan, np.nan, np.nan]])
    out, _ = road_user_sizes(["car", "bicyclist"], own)
    np.testing.assert_array_equal(out, [[5.0, 1.8, 2.0], [1.8, 0.6, 1.7]])


def test_footprints_only_keep_the_class_height():
    out, _ = road_user_sizes(["bus"], np.array([[10.0, 2.0]]))
    np.testing.assert_array_equal(out, [[10.0, 2.0, 3.2]])


def test_a_scenes_own_table_replaces_the_defaults_and_sizes_its_unknowns():
    sizes = dict(DEFAULT_CLASS_SIZES, car=(4.0, 1.7, 1.4))
    out, unknown = road_user_sizes(["car", "tram"], None, sizes)
    np.testing.assert_array_equal(out, [[4.0, 1.7, 1.4], [4.0, 1.7, 1.4]])
    assert unknown == ["tram"]


def test_empty():
    out, unknown = road_user_sizes([])
    assert out.shape == (0, 3) and unknown == []
