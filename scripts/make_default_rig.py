#!/usr/bin/env python3
"""Write configs/rigs/default.yaml (pinhole) and configs/rigs/fisheye.yaml (equidistant).

Semitrailer: tractor axle 0.5 m ahead of the fifth wheel, trailer axle 8 m behind the king-pin.
Cameras: tractor 'front' and 'left', trailer 'rear' and 'right', all tilted 10 deg down.
Usage: python scripts/make_default_rig.py [--out-dir configs/rigs]
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from ampc_vo.geometry import make_pose
from ampc_vo.rig import Body, Camera, Rig, camera_rotation, save_rig

PITCH_DOWN = math.radians(10.0)
# name, body, position in the body frame (m), yaw of the optical axis (deg)
MOUNTS = (
    ("front", "tractor", (2.5, 0.0, 2.5), 0.0),
    ("left", "tractor", (1.5, 1.25, 2.6), 90.0),
    ("rear", "trailer", (-13.0, 0.0, 3.0), 180.0),
    ("right", "trailer", (-6.0, -1.3, 3.0), -90.0),
)


def build_rig(model: str) -> Rig:
    cameras = []
    for name, body, position, yaw_deg in MOUNTS:
        pose = make_pose(camera_rotation(math.radians(yaw_deg), PITCH_DOWN), np.array(position))
        if model == "pinhole":
            intrinsics = dict(fx=320.0, fy=320.0, cx=319.5, cy=239.5, distortion=())
        else:  # equidistant fisheye, ~190 deg diagonal field of view
            intrinsics = dict(fx=240.0, fy=240.0, cx=319.5, cy=239.5, distortion=(0.02, -0.004, 0.0005, 0.0))
        cameras.append(Camera(name=name, body=body, model=model, width=640, height=480, T_body_camera=pose, **intrinsics))
    return Rig(bodies={"tractor": Body("tractor", 0.5), "trailer": Body("trailer", -8.0)}, cameras=tuple(cameras))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out-dir", default=str(Path(__file__).resolve().parents[1] / "configs" / "rigs"))
    args = parser.parse_args()
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    save_rig(build_rig("pinhole"), out_dir / "default.yaml")
    save_rig(build_rig("fisheye"), out_dir / "fisheye.yaml")
    print(f"wrote {out_dir / 'default.yaml'} and {out_dir / 'fisheye.yaml'}")


if __name__ == "__main__":
    main()
