#!/usr/bin/env python
"""Simulate, run and evaluate several routes in one go: the accuracy table of the README.

    python scripts/evaluate_routes.py --out OUT [--routes city_block suburb ...] [--rig RIG] [--no-images] [--config CONFIG]

For each route file ``configs/sim/<route>.yaml``: the dataset is simulated into
``OUT/data/<route>[-<rig>][-bearings]`` (rendered images unless ``--no-images``; an existing
complete dataset folder is reused), the odometry runs on it into ``OUT/runs/<name>`` and is evaluated
there (``metrics.json``, ``evaluation.png``). Prints one Markdown row per route (distance, tractor
ATE, hitch RMSE and maximum, frames per second) and writes the table to ``OUT/routes.md``.
Rendering takes about a minute per 600 frames on two cores.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ampc_vo.config import load_config  # noqa: E402
from ampc_vo.errors import ConfigError  # noqa: E402
from ampc_vo.tools.cli import exit_codes  # noqa: E402

ROUTES = Path(__file__).resolve().parents[1] / "configs" / "sim"
HEADER = ("| route | distance | tractor ATE | hitch RMSE / max | frames/s |", "|---|---|---|---|---|")


def evaluate_route(route: str, out: Path, rig: Path | None, images: bool, config) -> str:
    """Simulate (unless already there), run and evaluate one route; its Markdown row."""
    import dataclasses

    from ampc_vo.io.folder import FRAMES_FILE
    from ampc_vo.tools.evaluation import evaluate_run_folder
    from ampc_vo.tools.runner import run_sequence
    from ampc_vo.sim.config import load_sim_config
    from ampc_vo.sim.simulation import simulate_dataset
    from ampc_vo.frontend.sources import open_sequence

    route_file = ROUTES / f"{route}.yaml"
    if not route_file.is_file():
        raise ConfigError(f"{route_file}: no such route (routes: {', '.join(sorted(path.stem for path in ROUTES.glob('*.yaml')))})")
    name = route + ("" if rig is None else f"-{rig.stem}") + ("" if images else "-bearings")
    dataset = out / "data" / name
    if not (dataset / FRAMES_FILE).is_file():  # frames.csv is written last: its presence marks a complete folder
        sim = load_sim_config(route_file)
        if rig is not None:
            sim = dataclasses.replace(sim, rig_path=rig.resolve())
        simulate_dataset(sim, dataset, with_images=images, progress=True)
    sequence = open_sequence(dataset, config)
    run_dir = out / "runs" / name
    summary, _ = run_sequence(sequence, config, run_dir, progress=False)
    evaluation, _ = evaluate_run_folder(run_dir, sequence.truth, title=f"{name} ({sequence.kind})")
    metrics = evaluation.metrics
    hitch = "-" if metrics.hitch_rmse_deg is None else f"{metrics.hitch_rmse_deg:.2f}° / {metrics.hitch_max_deg:.2f}°"
    return (f"| {name}, {sequence.kind} | {metrics.distance_m:.0f} m | {metrics.tractor_ate_m:.2f} m "
            f"({100.0 * metrics.tractor_ate_m / metrics.distance_m:.2f} %) | {hitch} | {summary.frames_per_second:.1f} |")


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="folder for the datasets, runs and routes.md")
    parser.add_argument("--routes", nargs="+", default=["city_block", "suburb"], help="route files in configs/sim (default: the two long ones)")
    parser.add_argument("--rig", type=Path, default=None, help="rig.yaml instead of the routes' own (e.g. configs/rigs/fisheye.yaml)")
    parser.add_argument("--no-images", action="store_true", help="simulated bearings instead of rendered images")
    parser.add_argument("--config", type=Path, default=None, help="VO config (default: the built-in defaults)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.rig is not None and not args.rig.is_file():
        raise ConfigError(f"{args.rig}: rig file not found")
    config = load_config(args.config)
    rows = list(HEADER)
    print("\n".join(HEADER), flush=True)
    for route in args.routes:
        rows.append(evaluate_route(route, args.out, args.rig, not args.no_images, config))
        print(rows[-1], flush=True)
    (args.out / "routes.md").write_text("\n".join(rows) + "\n", encoding="utf-8")
    print(f"wrote {args.out / 'routes.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
