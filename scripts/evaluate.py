#!/usr/bin/env python
"""Evaluate an odometry run against a dataset's ground truth (issue 5, DESIGN section 5).

    python scripts/evaluate.py OUT DATASET [--seconds-per-frame S] [--title TEXT]
    python scripts/evaluate.py OUT LOG --groundtruth-topic TOPIC [--hitch-csv CSV] [--rig RIG.yaml]
    python scripts/evaluate.py OUT TRUTH.tum [--hitch-csv CSV] [--rig RIG.yaml]

Reads OUT/tractor.tum, OUT/trailer.tum, OUT/hitch.csv (and OUT/timing.json if present) and
DATASET/groundtruth.csv (a KITTI folder: poses.txt, compared in the left-camera frame); writes OUT/metrics.json and OUT/evaluation.png and prints a table.
Only files the run recorded in OUT/run.json are read; a run still writing, a stale file of another
run, or a run of another dataset folder is refused (exit 2, nothing written).

Exit codes (ampc_vo.tools.cli): 0 done, 1 failed, 2 bad input, 130 SIGINT, 143 SIGTERM.
For a recording (issue 15) the ground truth is its pose topic (nav_msgs/Odometry or
geometry_msgs/PoseStamped of the tractor body frame) or a TUM file, with the hitch angle from a CSV
timestamp,hitch_angle when there is one (trailer ATE at the trailer axle of --rig); it is
interpolated at the estimate's times.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.tools.cli import ExitContext, run_cli  # noqa: E402


def _is_recording_truth(path: Path) -> bool:
    from ampc_vo.io.bags import is_log

    return path.suffix == ".tum" or is_log(path)


def _recording_truth(args: argparse.Namespace):
    """Ground truth of a recording or TUM file, at the estimate's times (issue 15)."""
    from ampc_vo.io.groundtruth_log import load_log_groundtruth, truth_at
    from ampc_vo.io.outputs import TRACTOR_FILE, read_tum
    from ampc_vo.rig import load_rig

    rig = load_rig(args.rig) if args.rig is not None else None
    axle_x = rig.axle_x("trailer") if rig is not None and rig.has_trailer else 0.0
    truth = load_log_groundtruth(args.dataset, args.groundtruth_topic, args.hitch_csv, axle_x)
    return truth_at(truth, read_tum(args.out / TRACTOR_FILE).timestamps)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path, help="odometry output folder (tractor.tum, trailer.tum, hitch.csv)")
    parser.add_argument("dataset", type=Path, help="dataset folder with groundtruth.csv, or a KITTI folder with poses.txt")
    parser.add_argument("--seconds-per-frame", type=float, default=None, help="override OUT/timing.json")
    parser.add_argument("--max-time-diff", type=float, default=0.01, help="timestamp association tolerance (s)")
    parser.add_argument("--title", default="", help="plot title")
    parser.add_argument("--no-plot", action="store_true", help="do not write evaluation.png")
    parser.add_argument("--groundtruth-topic", default=None, metavar="TOPIC", help="a recording's pose topic (Odometry or PoseStamped)")
    parser.add_argument("--hitch-csv", type=Path, default=None, metavar="CSV", help="hitch angle ground truth: timestamp,hitch_angle (rad)")
    parser.add_argument("--rig", type=Path, default=None, help="rig.yaml (trailer axle for the trailer ATE of a recording)")
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

    truth = _recording_truth(args) if _is_recording_truth(args.dataset) else load_groundtruth(args.dataset)
    if args.dataset.suffix != ".tum":  # a TUM ground truth is not what the run read
        require_run_dataset(args.out, args.dataset)
    evaluation, written = evaluate_run_folder(args.out, truth, args.seconds_per_frame, args.max_time_diff, title=args.title, plot=not args.no_plot)
    print(f"evaluation of {args.out} against {args.dataset}")
    print(evaluation.metrics.table())
    print("wrote " + " and ".join(str(path) for path in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
