#!/usr/bin/env python
"""Evaluate an odometry run against a dataset's ground truth (issue 5, DESIGN section 5).

    python scripts/evaluate.py OUT DATASET [--seconds-per-frame S] [--title TEXT]

Reads OUT/tractor.tum, OUT/trailer.tum, OUT/hitch.csv (and OUT/timing.json if present) and
DATASET/groundtruth.csv (a KITTI folder: poses.txt, compared in the left-camera frame); writes OUT/metrics.json and OUT/evaluation.png and prints a table.
Only files the run recorded in OUT/run.json are read; a run still writing, a stale file of another
run, or a run of another dataset folder is refused (exit 2, nothing written).

Exit codes (ampc_vo.tools.cli): 0 done, 1 failed, 2 bad input, 130 SIGINT, 143 SIGTERM.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.tools.cli import ExitContext, run_cli  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path, help="odometry output folder (tractor.tum, trailer.tum, hitch.csv)")
    parser.add_argument("dataset", type=Path, help="dataset folder with groundtruth.csv, or a KITTI folder with poses.txt")
    parser.add_argument("--seconds-per-frame", type=float, default=None, help="override OUT/timing.json")
    parser.add_argument("--max-time-diff", type=float, default=0.01, help="timestamp association tolerance (s)")
    parser.add_argument("--title", default="", help="plot title")
    parser.add_argument("--no-plot", action="store_true", help="do not write evaluation.png")
    args = parser.parse_args(argv)
    if args.seconds_per_frame is not None and not args.seconds_per_frame > 0:
        parser.error(f"--seconds-per-frame must be > 0, got {args.seconds_per_frame}")
    if not args.max_time_diff > 0:
        parser.error(f"--max-time-diff must be > 0 (seconds), got {args.max_time_diff}")
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    return run_cli(lambda context: _evaluate(args, context))


def _evaluate(args: argparse.Namespace, context: ExitContext) -> int:
    """The evaluation itself; errors and interrupts become exit codes in :func:`run_cli`."""
    from ampc_vo.io.datasets import load_groundtruth
    from ampc_vo.tools.evaluation import evaluate_run_folder, require_run_dataset

    truth = load_groundtruth(args.dataset)
    require_run_dataset(args.out, args.dataset)
    evaluation, written = evaluate_run_folder(args.out, truth, args.seconds_per_frame, args.max_time_diff, title=args.title, plot=not args.no_plot)
    print(f"evaluation of {args.out} against {args.dataset}")
    print(evaluation.metrics.table())
    print("wrote " + " and ".join(str(path) for path in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
