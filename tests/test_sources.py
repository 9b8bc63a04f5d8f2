"""Measurement sources (ampc_vo.sources): a KITTI folder opens as the stereo image source (the right
camera's observations are the left features matched into it, with cross-camera landmark ids),
its default config, and the left/right association the backend relies on."""
from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from ampc_vo.config import VoConfig, load_config
from ampc_vo.frontend import StereoMatches, observations_with_stereo
from ampc_vo.observations import CameraObservations, FrameObservations
from ampc_vo.sources import KITTI_CONFIG, default_config_path, open_sequence

KITTI_CLIP = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti-clip"
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
        assert len(left) > 200 and len(right) > 0.5 * len(left)
        np.testing.assert_array_equal(left.landmark_ids, left.track_ids)
        np.testing.assert_array_equal(right.landmark_ids, right.track_ids)
        assert np.all(np.isin(right.track_ids, left.track_ids))     # right "tracks" are the left ids
        # rectified pair: the same row, positive disparity
        index_left = np.searchsorted(left.track_ids, right.track_ids) if np.all(np.diff(left.track_ids) > 0) else \
            np.array([np.flatnonzero(left.track_ids == track)[0] for track in right.track_ids])
        assert np.median(np.abs(left.pixels[index_left, 1] - right.pixels[:, 1])) < 0.5
        assert np.all(left.pixels[index_left, 0] - right.pixels[:, 0] > 0)
        assert set(step.frontend.reports) == {"left"}              # the right camera is not tracked on its own
        assert len(step.frontend.stereo[("left", "right")]) == len(right)
    # tracks continue: most left ids of frame 1 are in frame 2, and so are their right matches
    shared = np.intersect1d(steps[1].observations.cameras["right"].track_ids, steps[2].observations.cameras["right"].track_ids)
    assert shared.size > 100
