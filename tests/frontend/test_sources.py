"""Measurement sources (ampc_vo.frontend.sources): a KITTI folder opens as the stereo image source (the right
camera's observations are the left features matched into it, with cross-camera landmark ids),
its default config, the left/right association the backend relies on, and frame ranges."""
from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from ampc_vo.config import VoConfig, load_config
from ampc_vo.frontend.stereo import StereoMatches, observations_with_stereo
from ampc_vo.observations import CameraObservations, FrameObservations
from ampc_vo.errors import DatasetError
from ampc_vo.frontend.sources import KITTI_CONFIG, default_config_path, frame_selection, open_sequence

KITTI_CLIP = Path(__file__).resolve().parents[3] / "shared" / "data" / "kitti-clip"
needs_clip = pytest.mark.skipif(not KITTI_CLIP.is_dir(), reason=f"KITTI clip not found at {KITTI_CLIP}")


def test_observations_with_stereo_associates_left_and_right_by_landmark_ids():
    left = CameraObservations("left", np.array([3, 5, 9]), np.zeros((3, 2)), np.tile([0.0, 0.0, 1.0], (3, 1)))
    matched = CameraObservations("right", np.array([5, 9]), np.ones((2, 2)), np.tile([0.0, 0.0, 1.0], (2, 1)))
    frame = FrameObservations(7, 0.7, {"left": left})
    result = observations_with_stereo(frame, {("left", "right"): StereoMatches(matched, np.zeros((2, 2)), np.array([10.0, 20.0]))})
    assert (result.frame, result.timestamp) == (7, 0.7) and set(result.cameras) == {"left", "right"}
    np.testing.assert_array_equal(result.cameras["left"].landmark_ids, [3, 5, 9])
    np.testing.assert_array_equal(result.cameras["right"].track_ids, [5, 9])
    np.testing.assert_array_equal(result.cameras["right"].landmark_ids, [5, 9])
    assert frame.cameras["left"].landmark_ids is None          # the input is not modified
    empty = observations_with_stereo(frame, {("left", "right"): StereoMatches.empty("right")})
    assert len(empty.cameras["right"]) == 0 and empty.cameras["right"].landmark_ids.shape == (0,)


def test_default_config_is_the_kitti_one_only_for_kitti_folders(tmp_path):
    assert default_config_path(None) is None and default_config_path(tmp_path) is None
    config = load_config(KITTI_CONFIG)
    assert config.scale.stereo_chord and config.scale.cross_camera and config.mode == "tractor_only"
    assert not VoConfig().scale.stereo_chord                    # off unless a rig has an overlapping pair


@needs_clip
def test_kitti_folder_is_a_stereo_source_with_landmark_ids():
    assert default_config_path(KITTI_CLIP) == KITTI_CONFIG
    config = load_config(KITTI_CONFIG)
    sequence = open_sequence(KITTI_CLIP, config)
    assert sequence.kind == "kitti" and len(sequence) == 51 and sequence.truth is not None
    np.testing.assert_allclose(sequence.T_body_reference, sequence.rig.camera("left").T_body_camera)
    steps = list(itertools.islice(sequence.steps(), 3))
    for step in steps:
        left, right = step.observations.cameras["left"], step.observations.cameras["right"]
        assert len(left) > 200 and len(right) > 0.3 * len(left)       # matched within stereo.max_depth_m (25 m): about half
        np.testing.assert_array_equal(left.landmark_ids, left.track_ids)
        np.testing.assert_array_equal(right.landmark_ids, right.track_ids)
        assert np.all(np.isin(right.track_ids, left.track_ids))     # right "tracks" are the left ids
        # rectified pair: the same row, positive disparity
        index_left = np.searchsorted(left.track_ids, right.track_ids) if np.all(np.diff(left.track_ids) > 0) else \
            np.array([np.flatnonzero(left.track_ids == track)[0] for track in right.track_ids])
        assert np.median(np.abs(left.pixels[index_left, 1] - right.pixels[:, 1])) < 0.5
        assert np.all(left.pixels[index_left, 0] - right.pixels[:, 0] > 0)
        # stereo points only within stereo.max_depth_m (configs/vo/kitti.yaml: far points bent the turn clip)
        left_camera, right_camera = sequence.rig.camera("left"), sequence.rig.camera("right")
        focal_baseline = left_camera.fx * np.linalg.norm(left_camera.center - right_camera.center)
        depths = focal_baseline / (left.pixels[index_left, 0] - right.pixels[:, 0])
        assert config.stereo.max_depth_m <= 30.0 and np.all(depths <= config.stereo.max_depth_m * 1.01)
        assert set(step.frontend.reports) == {"left"}              # the right camera is not tracked on its own
        assert len(step.frontend.stereo[("left", "right")]) == len(right)
    # tracks continue: most left ids of frame 1 are in frame 2, and so are their right matches
    shared = np.intersect1d(steps[1].observations.cameras["right"].track_ids, steps[2].observations.cameras["right"].track_ids)
    assert shared.size > 100


def test_frame_selection_clamps_the_end_and_rejects_empty_or_negative_ranges():
    assert frame_selection(50) == range(0, 50)
    assert frame_selection(50, 10, 20) == range(10, 20)
    assert frame_selection(50, 10, 500) == range(10, 50)
    with pytest.raises(DatasetError, match="no frames selected: start 60"):
        frame_selection(50, 60, None, "data")
    with pytest.raises(DatasetError, match="start at 0"):
        frame_selection(50, -1)


def test_a_frame_range_of_a_bearing_dataset_keeps_frame_numbers_and_times(tmp_path, ci_simulation):
    from ampc_vo.io.folder import write_dataset

    result = ci_simulation
    write_dataset(tmp_path, result.rig, result.trajectory.timestamps, groundtruth=result.trajectory, measurements=result.measurements)
    sequence = open_sequence(tmp_path, VoConfig(), start=12, stop=20)
    steps = list(sequence.steps())
    assert [step.observations.frame for step in steps] == list(range(12, 20))
    np.testing.assert_allclose(sequence.timestamps, result.trajectory.timestamps[12:20])
    np.testing.assert_allclose([step.observations.timestamp for step in steps], result.trajectory.timestamps[12:20])
    assert len(sequence.truth.timestamps) == len(result.trajectory)  # the ground truth stays whole
    for step in steps:
        expected = result.measurements.observations(step.observations.frame, result.rig)
        np.testing.assert_array_equal(step.observations.cameras["front"].track_ids, expected.cameras["front"].track_ids)


@needs_clip
def test_a_frame_range_of_the_kitti_clip_tracks_from_its_first_frame():
    sequence = open_sequence(KITTI_CLIP, load_config(KITTI_CONFIG), start=30, stop=33)
    steps = list(sequence.steps())
    assert [step.observations.frame for step in steps] == [30, 31, 32]
    assert len(steps[0].observations.cameras["left"]) > 100  # features detected at frame 30, not carried from 0
    assert steps[0].frontend.reports["left"].tracked == 0
