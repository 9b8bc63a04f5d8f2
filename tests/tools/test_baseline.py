"""Stereo PnP baseline on the KITTI clip: guards the frontend's tracking and stereo matching with
real images (a broken tracker, stereo matcher or rig would give metres of error)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ampc_vo.tools.baseline import stereo_pnp_odometry
from ampc_vo.geometry import relative_pose, rotation_angle

KITTI_CLIP = Path(__file__).resolve().parents[3] / "shared" / "data" / "kitti-clip"
FRAMES = 12


@pytest.mark.skipif(not KITTI_CLIP.is_dir(), reason=f"KITTI clip not found at {KITTI_CLIP}")
def test_stereo_pnp_follows_the_kitti_ground_truth():
    from ampc_vo.io.kitti import load_kitti

    dataset = load_kitti(KITTI_CLIP)
    result = stereo_pnp_odometry(dataset.rig, ((dataset.timestamps[k], dataset.images(k)) for k in range(FRAMES)))
    assert not result.failed_frames and np.all(result.inliers[1:] > 30)
    truth = dataset.T_world_tractor[:FRAMES]
    # frame-to-frame motion: ~1.2 m per frame, translation within 5 cm and rotation within 0.3 deg
    for k in range(1, FRAMES):
        expected, estimated = relative_pose(truth[k - 1], truth[k]), relative_pose(result.T_world_body[k - 1], result.T_world_body[k])
        assert np.linalg.norm(expected[:3, 3] - estimated[:3, 3]) < 0.05, k
        assert np.degrees(rotation_angle(expected[:3, :3].T @ estimated[:3, :3])) < 0.3, k
    # end point after ~13 m: within 2 % of the distance (no alignment: both start at the identity)
    distance = np.sum(np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1))
    assert np.linalg.norm(result.T_world_body[-1, :3, 3] - truth[-1, :3, 3]) < 0.02 * distance
