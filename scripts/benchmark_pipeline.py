#!/usr/bin/env python
"""Whole-pipeline speed on rendered images (issue 7: 4 cameras at 640x480, >= 10 frames/s).

    python scripts/benchmark_pipeline.py [DATASET] [--config CONFIG] [--frames N]

Runs the odometry (image decoding + frontend + solvers + smoother) on DATASET (default: the
built-in demo sequence, rendered into the cache on first use) and prints frames per second, the
median time per frame of the frontend, the median time per keyframe of the backend with its
breakdown, and the per-frame budget this amounts to. Timings depend on the machine's load: the
script prints the load average next to them.
"""
from __future__ import annotations

import argparse
import itertools
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ampc_vo.config import load_config  # noqa: E402
from ampc_vo.errors import AmpcError  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, nargs="?", default=None, help="dataset folder with images (default: the demo)")
    parser.add_argument("--config", type=Path, default=None)
    parser.add_argument("--frames", type=int, default=None, help="only the first N frames")
    args = parser.parse_args(argv)
    try:
        from ampc_vo.demo import demo_dataset
        from ampc_vo.runner import run_sequence
        from ampc_vo.sources import Sequence, open_sequence

        config = load_config(args.config)
        sequence = open_sequence(args.dataset or demo_dataset(), config)
        if args.frames is not None:
            full = sequence
            sequence = Sequence(full.path, full.kind, full.rig, full.timestamps[: args.frames], full.truth,
                                lambda: itertools.islice(full.steps(), args.frames), full.T_body_reference)
        load_before = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as out:
            summary, _ = run_sequence(sequence, config, out, progress=False)
    except AmpcError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    breakdown = summary.backend_ms_breakdown
    frontend_ms = breakdown.get("frontend", 0.0)
    keyframe_share = summary.keyframes / max(summary.frames, 1)
    print(f"dataset {sequence.path} ({sequence.kind}), cameras {', '.join(sequence.rig.camera_names)}")
    print(f"load average before/after: {load_before:.2f} / {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"frames {summary.frames}, keyframes {summary.keyframes} ({keyframe_share:.2f} per frame)")
    print(f"whole pipeline: {summary.frames_per_second:.1f} frames/s ({1e3 * summary.seconds_per_frame:.1f} ms per frame, target <= 100)")
    print(f"frontend (decode + track + reject + unproject, all cameras): {frontend_ms:.1f} ms per frame (median)")
    print(f"backend: {summary.backend_ms_median:.1f} ms per keyframe (median): "
          + ", ".join(f"{name} {value:.1f}" for name, value in breakdown.items() if name != "frontend"))
    print(f"backend amortised over frames: {summary.backend_ms_median * keyframe_share:.1f} ms per frame")
    return 0


if __name__ == "__main__":
    sys.exit(main())
