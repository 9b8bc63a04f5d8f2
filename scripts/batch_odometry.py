#!/usr/bin/env python
"""The odometry on a fleet of logs (issue 15; ``ampc_vo.tools.batch``).

    python scripts/batch_odometry.py LOG... --rig RIG.yaml --out OUT [--workers N] [--ray [ADDRESS]]
                                     [--config CONFIG] [--groundtruth-topic TOPIC]

Each LOG (a ROS 1 .bag, a ROS 2 bag folder, an .mcap file, or one of our dataset folders) runs into
OUT/<log name>/; OUT/summary.csv has one row per log (log, frames, distance, frames/s, status and,
with ground truth, the tractor and trailer ATE and the hitch RMSE: --groundtruth-topic in each log,
or <log name>.tum beside it, and <log name>.hitch.csv beside it for the hitch). Local worker processes by
default (--workers, default 1); --ray sends the logs to a Ray cluster (ADDRESS, e.g. ray://head:10001
or auto; without ADDRESS a local cluster of --workers CPUs). A failing log is reported and does not
stop the batch; a rerun skips the logs already done.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.tools.cli import exit_codes  # noqa: E402


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG", help="recordings or dataset folders")
    parser.add_argument("--rig", type=Path, default=None, help="rig.yaml naming each camera's topic (needed for recordings)")
    parser.add_argument("--out", type=Path, required=True, help="output folder: OUT/<log name>/ and OUT/summary.csv")
    parser.add_argument("--config", type=Path, default=None, help="VO config YAML (default: the built-in defaults)")
    parser.add_argument("--workers", type=int, default=1, help="parallel logs (local processes, or the CPUs of a local Ray cluster)")
    parser.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS", help="run on a Ray cluster (no ADDRESS: a local one)")
    parser.add_argument("--groundtruth-topic", default=None, metavar="TOPIC", help="each log's ground-truth pose topic (metrics in summary.csv)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from ampc_vo.tools.batch import OK, SUMMARY_FILE, make_jobs, run_batch

    jobs = make_jobs(args.logs, args.out, args.rig, args.config, args.groundtruth_topic)
    rows = run_batch(jobs, args.out, args.workers, args.ray, progress=not args.no_progress)
    failed = [row for row in rows if row["status"] != OK]
    for row in failed:
        print(f"{row['log']}: {row['status']}", file=sys.stderr)
    print(f"{len(rows) - len(failed)} of {len(rows)} logs done -> {args.out / SUMMARY_FILE}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
