#!/usr/bin/env python
"""Accuracy with an imperfect extrinsic calibration: each camera mount rotated in turn.

    python scripts/experiment_calibration.py [--route demo] [--degrees 0.5] [--axes tilt pan roll] [--config CONFIG]

The route (``configs/sim/<route>.yaml``, bearings with its noise and outliers) is simulated with
the rig of its file; the odometry (full mode) then runs with a rig whose camera mount is rotated
by ``--degrees`` about the camera's own axis (``tilt``: camera x, looking up/down; ``pan``: camera
y, left/right; ``roll``: the optical axis), one camera and one axis at a time, plus once with every
camera tilted (a body pitch error, e.g. from the load). Prints a Markdown table of tractor ATE
(SE(3)) and hitch RMSE / maximum against the correctly calibrated run.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ampc_vo.config import load_config  # noqa: E402
from ampc_vo.tools.cli import exit_codes  # noqa: E402
from ampc_vo.tools.experiments import CAMERA_AXES, miscalibrated_rig, score_on_simulation  # noqa: E402
from ampc_vo.sim.simulation import simulate  # noqa: E402

ROUTES = Path(__file__).resolve().parents[1] / "configs" / "sim"


def _row(label: str, metrics, reference=None) -> str:
    ratio = "" if reference is None else f" | {metrics.hitch_rmse_deg / reference.hitch_rmse_deg:.1f}x"
    return (f"| {label} | {metrics.tractor_ate_m:.2f} m ({100.0 * metrics.tractor_ate_m / metrics.distance_m:.2f} %) | "
            f"{metrics.hitch_rmse_deg:.2f} / {metrics.hitch_max_deg:.2f} deg{ratio} |")


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--route", default="demo", help="route file in configs/sim (default: demo)")
    parser.add_argument("--degrees", type=float, default=0.5, help="rotation of the mount (default 0.5 deg)")
    parser.add_argument("--axes", nargs="+", choices=sorted(CAMERA_AXES), default=["tilt", "pan", "roll"])
    parser.add_argument("--config", type=Path, default=None, help="VO config (default: the built-in defaults)")
    args = parser.parse_args(argv)
    config = dataclasses.replace(load_config(args.config), mode="full")
    result = simulate(ROUTES / f"{args.route}.yaml")
    reference = score_on_simulation(result, config)
    print(f"route {args.route}, mounts rotated by {args.degrees:g} deg")
    print("| calibration | tractor ATE | hitch RMSE / max | hitch RMSE against exact |")
    print("|---|---|---|---|")
    print(_row("exact", reference, reference), flush=True)
    for camera in result.rig.cameras:
        for axis in args.axes:
            rig = miscalibrated_rig(result.rig, (camera.name,), axis, args.degrees)
            print(_row(f"{camera.name} ({camera.body}) {axis}", score_on_simulation(result, config, rig), reference), flush=True)
    every = miscalibrated_rig(result.rig, result.rig.camera_names, "tilt", args.degrees)
    print(_row("every camera tilt", score_on_simulation(result, config, every), reference), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
