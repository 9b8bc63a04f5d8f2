#!/usr/bin/env python3
"""Contact sheet of rendered camera images along a route (docs/contact_sheet.png).

    PYTHONPATH=. python scripts/make_contact_sheet.py [--config configs/sim/demo.yaml]
        [--rig configs/rigs/default.yaml] [--frames 20 80 140 190] [--out docs/contact_sheet.png]

Rows are frames, columns are the rig's cameras; each tile is labelled with camera, frame and hitch
angle. Rendering uses the same scene and options as ``scripts/simulate_sequence.py``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

REPOSITORY_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPOSITORY_ROOT))

from ampc_vo.sim.kinematics import simulate_kinematics  # noqa: E402
from ampc_vo.sim.render import Renderer, render_options_from_dict  # noqa: E402
from ampc_vo.rig import load_rig  # noqa: E402
from ampc_vo.sim.scene import build_scene  # noqa: E402
from ampc_vo.sim.config import load_sim_config  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPOSITORY_ROOT / "configs" / "sim" / "demo.yaml"))
    parser.add_argument("--rig", default=None, help="rig.yaml (default: the config's rig)")
    parser.add_argument("--frames", type=int, nargs="*", default=[20, 80, 140, 190])
    parser.add_argument("--scale", type=float, default=0.5, help="tile size relative to the image")
    parser.add_argument("--out", default=str(REPOSITORY_ROOT / "docs" / "contact_sheet.png"))
    args = parser.parse_args()

    config = load_sim_config(args.config)
    rig = load_rig(args.rig) if args.rig else config.load_rig()
    trajectory = simulate_kinematics(config.route, config.rate_hz, rig.axle_x("tractor"), rig.axle_x("trailer"),
                                     config.initial_hitch_angle, config.duration)
    scene = build_scene(trajectory, np.random.default_rng(config.seed), config.scene)
    renderer = Renderer(scene, None, render_options_from_dict(config.render))
    rows = []
    for frame in [f for f in args.frames if 0 <= f < len(trajectory)]:
        tiles = []
        for camera in rig.cameras:
            image = renderer.render(camera, trajectory.pose(camera.body)[frame] @ camera.T_body_camera)
            tile = cv2.resize(image, None, fx=args.scale, fy=args.scale, interpolation=cv2.INTER_AREA)
            tile = cv2.cvtColor(tile, cv2.COLOR_GRAY2BGR)
            label = f"{camera.name} ({camera.body}, {camera.model})  frame {frame}  hitch {np.degrees(trajectory.hitch_angle[frame]):+.1f} deg"
            cv2.rectangle(tile, (0, 0), (tile.shape[1], 16), (0, 0, 0), -1)
            cv2.putText(tile, label, (4, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.36, (255, 255, 255), 1, cv2.LINE_AA)
            tiles.append(cv2.copyMakeBorder(tile, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=(40, 40, 40)))
        rows.append(np.hstack(tiles))
    sheet = np.vstack(rows)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, sheet)
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]}): {len(rows)} frames x {len(rig.cameras)} cameras")


if __name__ == "__main__":
    main()
