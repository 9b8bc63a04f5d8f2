"""Shared pytest fixtures (owned by the foundation issue; other modules may add fixtures here)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from ampc_vo.io.folder import write_dataset
from ampc_vo.io.folder import image_relative_path
from ampc_vo.sim.kinematics import simulate_kinematics
from ampc_vo.rig import load_rig
from ampc_vo.sim.routes import route_from_list

REPOSITORY_ROOT = Path(__file__).resolve().parents[1]
CONFIGS = REPOSITORY_ROOT / "configs"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPOSITORY_ROOT


@pytest.fixture(scope="session")
def default_rig():
    """The semitrailer rig of ``configs/rigs/default.yaml`` (4 pinhole cameras)."""
    return load_rig(CONFIGS / "rigs" / "default.yaml")


@pytest.fixture(scope="session")
def fisheye_rig():
    """Same mounts as the default rig with equidistant fisheye cameras."""
    return load_rig(CONFIGS / "rigs" / "fisheye.yaml")


@pytest.fixture(scope="session")
def short_trajectory(default_rig):
    """~3 s at 10 Hz: a straight and a gentle left turn (kinematics only)."""
    route = route_from_list([{"type": "straight", "length": 8}, {"type": "turn", "angle_deg": 20, "radius": 40}], 8.0, "fixture")
    return simulate_kinematics(route, 10.0, default_rig.axle_x("tractor"), default_rig.axle_x("trailer"), initial_hitch_angle=0.02)


@pytest.fixture(scope="session")
def ci_simulation():
    """``configs/sim/ci_short.yaml`` simulated (trajectory, scene, landmarks, measurements), ~2 s."""
    from ampc_vo.sim.simulation import simulate

    return simulate(CONFIGS / "sim" / "ci_short.yaml")


@pytest.fixture
def tiny_dataset(tmp_path, default_rig, short_trajectory) -> Path:
    """A small complete dataset folder in ``tmp_path``: rig.yaml, frames.csv, groundtruth.csv and
    random grey 640x480 PNG images for every camera and frame (5 frames, 4 cameras)."""
    root = tmp_path / "dataset"
    rng = np.random.default_rng(0)
    frames = 5
    trajectory = type(short_trajectory)(
        short_trajectory.timestamps[:frames], short_trajectory.T_world_tractor[:frames],
        short_trajectory.T_world_trailer[:frames], short_trajectory.hitch_angle[:frames],
    )
    write_dataset(root, default_rig, trajectory.timestamps, groundtruth=trajectory, with_images=True)
    for frame in range(frames):
        for camera in default_rig.camera_names:
            path = root / image_relative_path(camera, frame)
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), rng.integers(0, 256, size=(48, 64), dtype=np.uint8).repeat(10, axis=0).repeat(10, axis=1))
    return root
