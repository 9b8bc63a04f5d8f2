#!/usr/bin/env python3
"""Contact sheet of rendered camera images along routes (docs/contact_sheet.png, docs/contact_sheet_realistic.png).

    PYTHONPATH=. python scripts/make_contact_sheet.py [--config configs/sim/demo.yaml ...]
        [--rig configs/rigs/default.yaml] [--frames 20 80 140 190] [--out docs/contact_sheet.png]

Rows are (route, frame) pairs, columns are the rig's cameras; each tile is labelled with route,
camera, frame and hitch angle. Images are formed exactly as ``scripts/simulate_sequence.py`` writes
them (``render.render_frame_images``: capture times, rolling shutter, blur, auto exposure,
vignetting, noise, traffic and the trailer box as the config asks). Frames beyond a route's end are
skipped.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

REPOSITORY_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPOSITORY_ROOT))

from ampc_vo.rig import load_rig  # noqa: E402
from ampc_vo.sim.config import load_sim_config  # noqa: E402
from ampc_vo.sim.render import Renderer, render_frame_images, render_options_from_dict, sequence_job  # noqa: E402
from ampc_vo.sim.simulation import simulate  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", nargs="+", default=[str(REPOSITORY_ROOT / "configs" / "sim" / "demo.yaml")])
    parser.add_argument("--rig", default=None, help="rig.yaml (default: each config's rig)")
    parser.add_argument("--frames", type=int, nargs="*", default=[20, 80, 140, 190])
    parser.add_argument("--scale", type=float, default=0.5, help="tile size relative to the image")
    parser.add_argument("--out", default=str(REPOSITORY_ROOT / "docs" / "contact_sheet.png"))
    args = parser.parse_args()

    rows = []
    for config_path in args.config:
        config = load_sim_config(config_path)
        result = simulate(config, load_rig(args.rig) if args.rig else None)
        renderer = Renderer(result.scene, None, render_options_from_dict(config.render))
        job = sequence_job(renderer, result.rig, result.trajectory, **result.render_inputs())
        route = Path(config_path).stem
        for frame in [f for f in args.frames if 0 <= f < len(result.trajectory)]:
            images = render_frame_images(renderer, job, frame)
            tiles = []
            for camera in result.rig.cameras:
                tile = cv2.resize(images[camera.name], None, fx=args.scale, fy=args.scale, interpolation=cv2.INTER_AREA)
                tile = cv2.cvtColor(tile, cv2.COLOR_GRAY2BGR)
                label = f"{route}: {camera.name} ({camera.body})  frame {frame}  hitch {np.degrees(result.trajectory.hitch_angle[frame]):+.1f} deg"
                cv2.rectangle(tile, (0, 0), (tile.shape[1], 16), (0, 0, 0), -1)
                cv2.putText(tile, label, (4, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.34, (255, 255, 255), 1, cv2.LINE_AA)
                tiles.append(cv2.copyMakeBorder(tile, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=(40, 40, 40)))
            rows.append(np.hstack(tiles))
    width = max(row.shape[1] for row in rows)
    sheet = np.vstack([cv2.copyMakeBorder(row, 0, 0, 0, width - row.shape[1], cv2.BORDER_CONSTANT, value=(40, 40, 40)) for row in rows])
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, sheet)
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]}): {len(rows)} rows")


if __name__ == "__main__":
    main()
