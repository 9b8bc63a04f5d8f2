#!/usr/bin/env python
"""Whole-pipeline speed on rendered images (issue 7: 4 cameras at 640x480, >= 10 frames/s).

    python scripts/benchmark_pipeline.py [DATASET] [--config CONFIG] [--frames N] [--workers process thread none]

Runs the odometry (image decoding + frontend + solvers + smoother) on DATASET (default: the
built-in demo sequence, rendered into the cache on first use) once per frontend worker
(``frontend_worker``: the frontend in its own process, the default; in a thread of the backend's
process, the reference it replaced) and prints for each the frames per second, the median time per
frame of the frontend, the median time per keyframe of the backend with its breakdown, and the
per-frame budget this amounts to; then the speed ratio against the reference of the same run.
Timings depend on the machine's load: the script prints the load average next to them.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ampc_vo.config import FRONTEND_WORKERS, load_config  # noqa: E402
from ampc_vo.tools.cli import exit_codes  # noqa: E402


REFERENCE_WORKER = "thread"  # the frontend in a worker thread of the backend's process (before the process worker)


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, nargs="?", default=None, help="dataset folder with images (default: the demo)")
    parser.add_argument("--config", type=Path, default=None)
    parser.add_argument("--frames", type=int, default=None, help="only the first N frames")
    parser.add_argument("--workers", nargs="+", choices=FRONTEND_WORKERS, default=["process", REFERENCE_WORKER],
                        help=f"frontend workers to time, in turn (default: process, and {REFERENCE_WORKER} as the reference)")
    args = parser.parse_args(argv)
    from ampc_vo.tools.demo import demo_dataset
    from ampc_vo.tools.runner import run_sequence
    from ampc_vo.frontend.sources import open_sequence

    base = load_config(args.config)
    dataset = args.dataset or demo_dataset()
    speeds = {}
    for worker in args.workers:
        config = dataclasses.replace(base, frontend_worker=worker)
        sequence = open_sequence(dataset, config, stop=args.frames)
        load_before = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as out:
            summary, _ = run_sequence(sequence, config, out, progress=False)
        if not speeds:
            print(f"dataset {sequence.path} ({sequence.kind}), cameras {', '.join(sequence.rig.camera_names)}")
            print(f"frames {summary.frames}, keyframes {summary.keyframes} ({summary.keyframes / max(summary.frames, 1):.2f} per frame)")
        speeds[worker] = summary.frames_per_second
        _print_run(worker, summary, load_before)
    if len(speeds) > 1:
        reference = REFERENCE_WORKER if REFERENCE_WORKER in speeds else list(speeds)[-1]
        print(f"speed against frontend_worker {reference} (same run): "
              + ", ".join(f"{worker} {speed / speeds[reference]:.2f}x" for worker, speed in speeds.items() if worker != reference))
    return 0


def _print_run(worker: str, summary, load_before: float) -> None:
    breakdown = summary.backend_ms_breakdown
    keyframe_share = summary.keyframes / max(summary.frames, 1)
    print(f"\nfrontend_worker {worker}  (load average before/after: {load_before:.2f} / {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores)")
    print(f"  whole pipeline: {summary.frames_per_second:.1f} frames/s ({1e3 * summary.seconds_per_frame:.1f} ms per frame, target <= 100)")
    print(f"  frontend (decode + track + reject + unproject, all cameras): {breakdown.get('frontend', 0.0):.1f} ms per frame (median)")
    print(f"  backend: {summary.backend_ms_median:.1f} ms per keyframe (median): "
          + ", ".join(f"{name} {value:.1f}" for name, value in breakdown.items() if name != "frontend"))
    print(f"  backend amortised over frames: {summary.backend_ms_median * keyframe_share:.1f} ms per frame")


if __name__ == "__main__":
    sys.exit(main())
