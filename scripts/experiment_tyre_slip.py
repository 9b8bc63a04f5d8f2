#!/usr/bin/env python
"""Accuracy when the tyres slip: the non-holonomic model (DESIGN 2, (NH)) broken as by real tyres.

    python scripts/experiment_tyre_slip.py [--routes city_block suburb] [--slips 0 0.5 1.0] [--config CONFIG]

For each route file and slip setting (``tyre_slip_deg_per_mps2``: each axle's velocity turned
outward of its heading by that many degrees per m/s^2 of lateral acceleration; ``ampc_vo.sim.kinematics``)
the route is simulated (bearings, the route file's noise and outliers), the odometry runs in full
mode and is evaluated against the truth. Prints a Markdown table: the largest slip angle of the
tractor axle along the route, tractor ATE (SE(3)), hitch RMSE and maximum.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ampc_vo.config import load_config  # noqa: E402
from ampc_vo.tools.cli import exit_codes  # noqa: E402
from ampc_vo.tools.experiments import score_on_simulation  # noqa: E402
from ampc_vo.geometry import wrap_angle, yaw_of  # noqa: E402
from ampc_vo.io.groundtruth import Trajectory  # noqa: E402
from ampc_vo.sim.kinematics import axle_positions
from ampc_vo.sim.config import load_sim_config  # noqa: E402
from ampc_vo.sim.simulation import simulate  # noqa: E402

ROUTES = Path(__file__).resolve().parents[1] / "configs" / "sim"


def largest_axle_slip_deg(trajectory: Trajectory, tractor_axle_x: float, trailer_axle_x: float) -> float:
    """Largest angle between the tractor axle's heading and its velocity (central differences), deg."""
    axle, _ = axle_positions(trajectory, tractor_axle_x, trailer_axle_x)
    velocity = axle[2:] - axle[:-2]
    moving = np.linalg.norm(velocity[:, :2], axis=1) > 1e-3
    heading = np.array([yaw_of(pose) for pose in trajectory.T_world_tractor[1:-1]])
    angle = wrap_angle(np.arctan2(velocity[:, 1], velocity[:, 0]) - heading)
    return float(np.degrees(np.max(np.abs(angle[moving])))) if moving.any() else 0.0


def run_case(route: str, slip_deg: float, config) -> dict:
    result = simulate(dataclasses.replace(load_sim_config(ROUTES / f"{route}.yaml"), tyre_slip=math.radians(slip_deg)))
    metrics = score_on_simulation(result, config)
    return {"route": route, "slip": slip_deg, "largest_slip_deg": largest_axle_slip_deg(result.trajectory, result.rig.axle_x("tractor"), result.rig.axle_x("trailer")),
            "ate_m": metrics.tractor_ate_m, "ate_percent": 100.0 * metrics.tractor_ate_m / metrics.distance_m,
            "hitch_rmse_deg": metrics.hitch_rmse_deg, "hitch_max_deg": metrics.hitch_max_deg}


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--routes", nargs="+", default=["city_block", "suburb"], help="route files in configs/sim")
    parser.add_argument("--slips", nargs="+", type=float, default=[0.0, 0.5, 1.0], help="tyre_slip_deg_per_mps2 values")
    parser.add_argument("--config", type=Path, default=None, help="VO config (default: the built-in defaults)")
    args = parser.parse_args(argv)
    config = dataclasses.replace(load_config(args.config), mode="full")
    print("| route | slip setting (deg per m/s^2) | largest axle slip | tractor ATE | hitch RMSE / max |")
    print("|---|---|---|---|---|")
    for route in args.routes:
        for slip in args.slips:
            row = run_case(route, slip, config)
            print(f"| {route} | {slip:g} | {row['largest_slip_deg']:.1f} deg | {row['ate_m']:.2f} m ({row['ate_percent']:.2f} %) | "
                  f"{row['hitch_rmse_deg']:.2f} / {row['hitch_max_deg']:.2f} deg |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
