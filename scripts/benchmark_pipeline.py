#!/usr/bin/env python
"""Whole-pipeline speed on rendered images (issue 7: 4 cameras at 640x480, >= 10 frames/s).

    python scripts/benchmark_pipeline.py [DATASET] [--config CONFIG] [--frames N] [--workers process thread none]
                                         [--reference REV [--repeat N]]

Runs the odometry (image decoding + frontend + solvers + smoother) on DATASET (default: the
built-in demo sequence, rendered into the cache on first use) once per frontend worker
(``frontend_worker``: the frontend in its own process, the default; in a thread of the backend's
process, the reference it replaced) and prints for each the frames per second, the median time per
frame of the frontend, the median time per keyframe of the backend with its breakdown, and the
per-frame budget this amounts to; then the speed ratio against the reference of the same run.
Timings depend on the machine's load: the script prints the load average next to them.

``--reference REV``: instead, the pipeline of this code and of git revision REV (exported into a
temporary folder) run in turn, ``--repeat`` times each with the order alternating, each in a
process of its own with the first worker of ``--workers``; printed are every run and the speed ratio
this / REV of each back-to-back pair and their median (on a machine shared with other work the
ratio of neighbouring runs is steadier than either speed).
"""
from __future__ import annotations

import argparse
import dataclasses
import io
import os
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPOSITORY))

from ampc_vo.config import FRONTEND_WORKERS, load_config  # noqa: E402
from ampc_vo.errors import AmpcError  # noqa: E402
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
    parser.add_argument("--reference", metavar="REV", help="time this code against git revision REV, run by run in turn (module docstring)")
    parser.add_argument("--repeat", type=int, default=3, help="with --reference: runs of each (default 3)")
    args = parser.parse_args(argv)
    from ampc_vo.tools.demo import demo_dataset

    dataset = args.dataset or demo_dataset()
    if args.reference:
        return _against_revision(args, dataset)
    return _workers_in_turn(args, dataset)


def _workers_in_turn(args: argparse.Namespace, dataset: Path) -> int:
    """The pipeline once per frontend worker of ``args.workers``, in this process."""
    from ampc_vo.tools.runner import run_sequence
    from ampc_vo.frontend.sources import open_sequence

    base = load_config(args.config)
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


def _export_revision(revision: str, folder: Path) -> Path:
    """The files of git revision ``revision`` of this repository, written into ``folder``."""
    archive = subprocess.run(["git", "-C", str(REPOSITORY), "archive", "--format=tar", revision], capture_output=True)
    if archive.returncode != 0:
        raise AmpcError(f"--reference: git archive {revision} failed: {archive.stderr.decode(errors='replace').strip()}")
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as files:
        files.extractall(folder, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))  # the filter: Python >= 3.10.12
    return folder


def _one_run(root: Path, args: argparse.Namespace, dataset: Path) -> tuple[float, str]:
    """Frames per second of the pipeline of the code in ``root`` (its own benchmark script, in a
    process of its own) and its printed figures."""
    command = [sys.executable, str(root / "scripts" / "benchmark_pipeline.py"), str(dataset), "--workers", args.workers[0]]
    command += (["--config", str(args.config)] if args.config else []) + (["--frames", str(args.frames)] if args.frames else [])
    run = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(root)})
    speed = re.search(r"whole pipeline: ([0-9.]+) frames/s", run.stdout)
    if run.returncode != 0 or speed is None:
        raise AmpcError(f"benchmark of {root} failed (exit code {run.returncode}): {run.stderr.strip()[-2000:]}")
    figures = [line.strip() for line in run.stdout.splitlines() if line.lstrip().startswith(("whole pipeline", "frontend", "frontend_worker"))]
    return float(speed.group(1)), "; ".join(figures)


def _against_revision(args: argparse.Namespace, dataset: Path) -> int:
    """This code and revision ``args.reference`` run by run in turn (module docstring)."""
    with tempfile.TemporaryDirectory(prefix="benchmark-reference-") as folder:
        roots = {"this": REPOSITORY, args.reference: _export_revision(args.reference, Path(folder))}
        speeds: dict[str, list[float]] = {name: [] for name in roots}
        for repeat in range(args.repeat):
            for name in (list(roots) if repeat % 2 == 0 else list(roots)[::-1]):
                speed, figures = _one_run(roots[name], args, dataset)
                speeds[name].append(speed)
                print(f"run {repeat + 1} {name}: {figures}", flush=True)
    ratios = [this / reference for this, reference in zip(speeds["this"], speeds[args.reference])]
    print(f"frames/s this: {', '.join(f'{speed:.1f}' for speed in speeds['this'])}; "
          f"{args.reference}: {', '.join(f'{speed:.1f}' for speed in speeds[args.reference])}")
    print(f"speed this / {args.reference}, pair by pair: {', '.join(f'{ratio:.2f}' for ratio in ratios)}; median {statistics.median(ratios):.2f}x")
    return 0


def _print_run(worker: str, summary, load_before: float) -> None:
    breakdown = summary.backend_ms_breakdown
    keyframe_share = summary.keyframes / max(summary.frames, 1)
    print(f"\nfrontend_worker {worker}  (load average before/after: {load_before:.2f} / {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores)")
    print(f"  whole pipeline: {summary.frames_per_second:.1f} frames/s ({1e3 * summary.seconds_per_frame:.1f} ms per frame, target <= 100)")
    print(f"  frontend (wait for the images, decoded while the previous frame was tracked, + track + reject + unproject, all cameras): "
          f"{breakdown.get('frontend', 0.0):.1f} ms per frame (median)")
    print(f"  backend: {summary.backend_ms_median:.1f} ms per keyframe (median): "
          + ", ".join(f"{name} {value:.1f}" for name, value in breakdown.items() if name != "frontend")
          + f"; of it CPU time of the backend's thread {summary.backend_cpu_ms_median:.1f} ms (the rest: waiting for a core)")
    print(f"  backend amortised over frames: {summary.backend_ms_median * keyframe_share:.1f} ms per frame")


if __name__ == "__main__":
    sys.exit(main())
