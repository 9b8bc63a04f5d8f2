#!/usr/bin/env python
"""A simulated stereo-car dataset folder as a KITTI odometry folder (issue 16: a KITTI stand-in).

    python scripts/kitti_from_sim.py SIM_FOLDER OUT_FOLDER [--left left --right right]

SIM_FOLDER is ``scripts/simulate_sequence.py``'s output with rendered images of a rectified,
level, forward stereo pair on the tractor (``configs/rigs/kitti_car.yaml``). OUT_FOLDER gets what
``ampc_vo.io.kitti`` reads (DESIGN 5, 8): ``image_l/``, ``image_r/`` (links to the PNGs),
``calib.txt`` (P0, P1 of the rectified pair), ``poses.txt`` (the left camera in the first
left-camera frame, KITTI's convention) and ``times.txt``. So ``run_odometry.py`` (with
``configs/vo/kitti.yaml``), ``evaluate.py``, ``kitti_baseline.py`` and ``kitti_compare.py`` run on it
unchanged. Refuses a pair that is not rectified (different intrinsics or rotations, a baseline off
the left camera's x axis): KITTI's reader assumes it.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

import numpy as np  # noqa: E402

from ampc_vo.errors import DatasetError  # noqa: E402
from ampc_vo.geometry import invert_pose  # noqa: E402
from ampc_vo.io.folder import read_dataset  # noqa: E402
from ampc_vo.io.kitti import camera_poses  # noqa: E402
from ampc_vo.rig import Camera  # noqa: E402
from ampc_vo.tools.cli import exit_codes  # noqa: E402

logger = logging.getLogger(__name__)


def rectified_baseline(left: Camera, right: Camera) -> float:
    """The stereo baseline (metres, along the left camera's x axis) of a rectified pair;
    :class:`DatasetError` if the pair is not one (intrinsics, rotations, a baseline off x)."""
    if (left.fx, left.fy, left.cx, left.cy, left.width, left.height) != (right.fx, right.fy, right.cx, right.cy, right.width, right.height):
        raise DatasetError(f"cameras {left.name!r} and {right.name!r} have different intrinsics: not a rectified pair")
    if left.distortion or right.distortion:
        raise DatasetError("a rectified pair has no distortion")
    if not np.allclose(left.R_body_camera, right.R_body_camera, atol=1e-9):
        raise DatasetError(f"cameras {left.name!r} and {right.name!r} are rotated relative to each other: not a rectified pair")
    offset = left.R_body_camera.T @ (right.center - left.center)  # right centre in the left camera frame
    if np.linalg.norm(offset[1:]) > 1e-6 or offset[0] <= 0.0:
        raise DatasetError(f"right camera at {offset} in the left camera frame: a rectified pair has it on the +x axis")
    return float(offset[0])


def projection_rows(left: Camera, baseline: float) -> tuple[np.ndarray, np.ndarray]:
    """KITTI's P0, P1 (3x4): ``K [I | 0]`` and ``K [I | -baseline e_x]``."""
    K = np.array([[left.fx, 0.0, left.cx], [0.0, left.fy, left.cy], [0.0, 0.0, 1.0]])
    P0 = np.hstack([K, np.zeros((3, 1))])
    P1 = np.hstack([K, K @ np.array([[-baseline], [0.0], [0.0]])])
    return P0, P1


def left_camera_poses(T_world_tractor: np.ndarray, T_body_left: np.ndarray) -> np.ndarray:
    """(F, 3, 4) poses of the left camera in the first left-camera frame (KITTI poses.txt)."""
    T_world_left = camera_poses(T_world_tractor, T_body_left)
    return (invert_pose(T_world_left[0]) @ T_world_left)[:, :3, :]


def _link(target: Path, link: Path) -> None:
    if link.is_symlink() or link.exists():
        link.unlink()
    link.symlink_to(target.resolve())


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sim_folder", type=Path, help="simulated dataset folder with images")
    parser.add_argument("out", type=Path, help="KITTI folder to write")
    parser.add_argument("--left", default="left", help="left camera name in the rig")
    parser.add_argument("--right", default="right", help="right camera name in the rig")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    dataset = read_dataset(args.sim_folder, load_measurements_file=False)
    if not dataset.has_images or dataset.groundtruth is None:
        raise DatasetError(f"{args.sim_folder}: needs rendered images and groundtruth.csv")
    left, right = dataset.rig.camera(args.left), dataset.rig.camera(args.right)
    baseline = rectified_baseline(left, right)
    args.out.mkdir(parents=True, exist_ok=True)
    for folder, camera in (("image_l", left), ("image_r", right)):
        (args.out / folder).mkdir(exist_ok=True)
        for frame in range(len(dataset)):
            _link(dataset.image_path(frame, camera.name), args.out / folder / f"{frame:06d}.png")
    P0, P1 = projection_rows(left, baseline)
    np.savetxt(args.out / "calib.txt", np.vstack([P0.reshape(1, 12), P1.reshape(1, 12)]), fmt="%.12e")
    poses = left_camera_poses(dataset.groundtruth.T_world_tractor, left.T_body_camera)
    np.savetxt(args.out / "poses.txt", poses.reshape(len(poses), 12), fmt="%.12e")
    np.savetxt(args.out / "times.txt", dataset.timestamps - dataset.timestamps[0], fmt="%.6f")
    logger.info("wrote %s: %d stereo frames, baseline %.3f m", args.out, len(dataset), baseline)
    return 0


if __name__ == "__main__":
    sys.exit(main())
