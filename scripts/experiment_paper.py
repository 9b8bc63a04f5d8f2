#!/usr/bin/env python
"""The paper's claim, measured: optimising over all parameters beats estimating each rigid part
alone (issue 5). Sweeps pixel noise and routes, runs the four modes on the same measurements in
one process, writes a markdown table and a PNG.

    python scripts/experiment_paper.py --out OUT [--routes demo city_block] [--noise 0.5 1 2]
                                       [--outliers 0.05] [--config CONFIG]

Each (route, noise) is simulated once (bearings only, seeded by the sim config); the modes
``full``, ``no_trailer_constraint``, ``separate`` and ``tractor_only`` run on it. Writes
OUT/results.md, OUT/results.json and OUT/results.png (hitch RMSE and tractor RPE per mode).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

from ampc_vo.config import MODES, load_config
from ampc_vo.io.groundtruth import GroundTruth
from ampc_vo.tools.evaluation import evaluate
from ampc_vo.io.outputs import HitchSeries, Trajectory
from ampc_vo.backend.pipeline import run_on_frames
from ampc_vo.sim.config import load_sim_config
from ampc_vo.sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]


def run_case(route: str, noise: float, outliers: float, config, modes) -> list[dict]:
    sim_config = dataclasses.replace(load_sim_config(ROOT / "configs" / "sim" / f"{route}.yaml"), pixel_noise_px=noise, outlier_fraction=outliers)
    result = simulate(sim_config)
    truth = result.trajectory
    ground_truth = GroundTruth(truth.timestamps, truth.T_world_tractor, truth.T_world_trailer, truth.hitch_angle)
    frames = [result.measurements.observations(frame, result.rig) for frame in range(result.measurements.frame_count)]
    rows = []
    for mode in modes:
        mode_config = config.with_mode(mode)
        # noise model and thresholds follow the pixel noise (as a user would set them for a camera)
        mode_config = dataclasses.replace(
            mode_config,
            smoother=dataclasses.replace(mode_config.smoother, pixel_sigma=max(mode_config.smoother.pixel_sigma, noise), gate_px=max(mode_config.smoother.gate_px, 4.0 * noise)),
            ransac=dataclasses.replace(mode_config.ransac, threshold_px=max(mode_config.ransac.threshold_px, 3.0 * noise)),
        )
        started = time.perf_counter()
        summary, estimates = run_on_frames(result.rig, mode_config, frames, None, progress=False)
        stamps = np.array([e.timestamp for e in estimates])
        tractor = Trajectory(stamps, np.array([e.T_world_tractor for e in estimates]))
        trailer = hitch = None
        if estimates[0].T_world_trailer is not None:
            trailer = Trajectory(stamps, np.array([e.T_world_trailer for e in estimates]))
            hitch = HitchSeries(stamps, np.array([e.hitch_angle for e in estimates]), np.array([np.nan if e.hitch_sigma is None else e.hitch_sigma for e in estimates]))
        metrics = evaluate(ground_truth, tractor, trailer, hitch, summary.seconds_per_frame).metrics
        row = {"route": route, "noise_px": noise, "mode": mode, **metrics.to_dict(), "backend_ms": summary.backend_ms_median, "wall_s": time.perf_counter() - started}
        rows.append(row)
        print(f"{route:>14s} {noise:4.1f}px {mode:>22s}: ATE {row['tractor_ate_m']:.2f} m ({100 * row['tractor_ate_m'] / row['distance_m']:.2f}%), "
              f"RPE {_fmt(row['tractor_rpe_percent'])}%, hitch RMSE {_fmt(row['hitch_rmse_deg'])} deg, max {_fmt(row['hitch_max_deg'])} deg", flush=True)
    return rows


def _fmt(value) -> str:
    return "-" if value is None else f"{value:.3f}"


def markdown(rows: list[dict]) -> str:
    lines = ["| route | noise px | mode | distance m | tractor ATE m (%) | tractor RPE % | trailer ATE m | hitch RMSE deg | hitch max deg |",
             "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['route']} | {row['noise_px']} | {row['mode']} | {row['distance_m']:.0f} | {row['tractor_ate_m']:.2f} ({100 * row['tractor_ate_m'] / row['distance_m']:.2f}) | "
                     f"{_fmt(row['tractor_rpe_percent'])} | {_fmt(row['trailer_ate_m'])} | {_fmt(row['hitch_rmse_deg'])} | {_fmt(row['hitch_max_deg'])} |")
    ratios = []
    for (route, noise) in sorted({(row["route"], row["noise_px"]) for row in rows}):
        by_mode = {row["mode"]: row for row in rows if row["route"] == route and row["noise_px"] == noise}
        full = by_mode.get("full")
        if not full:
            continue
        parts = []
        for other in ("separate", "no_trailer_constraint"):
            if other in by_mode and full["hitch_rmse_deg"] and by_mode[other]["hitch_rmse_deg"]:
                parts.append(f"hitch RMSE {other}/full = {by_mode[other]['hitch_rmse_deg'] / full['hitch_rmse_deg']:.2f}")
        if "tractor_only" in by_mode and full["tractor_rpe_percent"] and by_mode["tractor_only"]["tractor_rpe_percent"]:
            parts.append(f"tractor RPE tractor_only/full = {by_mode['tractor_only']['tractor_rpe_percent'] / full['tractor_rpe_percent']:.2f}")
        ratios.append(f"- {route}, {noise} px: " + "; ".join(parts))
    return "\n".join(lines) + "\n\nRatios (> 1: full is better):\n\n" + "\n".join(ratios) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = sorted({(row["route"], row["noise_px"]) for row in rows})
    labels = [f"{route}\n{noise} px" for route, noise in cases]
    modes = [mode for mode in MODES if any(row["mode"] == mode for row in rows)]
    figure, axes = plt.subplots(1, 2, figsize=(13, 4.8))
    width = 0.8 / len(modes)
    for index, mode in enumerate(modes):
        hitch = [next((r["hitch_rmse_deg"] for r in rows if (r["route"], r["noise_px"]) == case and r["mode"] == mode), None) for case in cases]
        rpe = [next((r["tractor_rpe_percent"] for r in rows if (r["route"], r["noise_px"]) == case and r["mode"] == mode), None) for case in cases]
        x = np.arange(len(cases)) + (index - (len(modes) - 1) / 2) * width
        axes[0].bar(x, [np.nan if v is None else v for v in hitch], width, label=mode)
        axes[1].bar(x, [np.nan if v is None else v for v in rpe], width, label=mode)
    for axis, title in zip(axes, ("hitch angle RMSE [deg]", "tractor RPE over 10 m [%]")):
        axis.set_xticks(np.arange(len(cases)), labels, fontsize=8)
        axis.set_title(title)
        axis.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--routes", nargs="+", default=["demo"])
    parser.add_argument("--noise", nargs="+", type=float, default=[0.5, 1.0, 2.0])
    parser.add_argument("--outliers", type=float, default=0.05)
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--config", type=Path, default=None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    config = load_config(args.config)
    config = dataclasses.replace(config, output=dataclasses.replace(config.output, progress=False))
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for route in args.routes:
        for noise in args.noise:
            rows += run_case(route, noise, args.outliers, config, args.modes)
            (args.out / "results.json").write_text(json.dumps(rows, indent=2) + "\n")
    (args.out / "results.md").write_text(markdown(rows))
    plot(rows, args.out / "results.png")
    print(markdown(rows))
    print(f"wrote {args.out / 'results.md'}, results.json, results.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
