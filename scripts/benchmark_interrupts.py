#!/usr/bin/env python
"""How a run on images ends when signalled (issue 14): exit code, time to exit, time until its
frontend worker and resource tracker are gone, poses written before and after the signal.

    python scripts/benchmark_interrupts.py [DATASET] [--trials N]

DATASET: a dataset folder with images (default: configs/sim/ci_short.yaml rendered into a
temporary folder, about 20 s). Each trial runs scripts/run_odometry.py (smoother lag 1 s, so the
first poses come early), waits until it has written 2 poses, sends SIGTERM, SIGINT or SIGKILL.
"""
from __future__ import annotations

import argparse
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.tools.cli import exit_codes  # noqa: E402
from ampc_vo.tools.processes import run_helpers, wait_gone  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _pose_rows(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line and not line.startswith("#")) if path.is_file() else 0


def trial(dataset: Path, work: Path, number: int) -> str:
    """One signalled run; its result line."""
    out = work / "out"
    shutil.rmtree(out, ignore_errors=True)
    config = work / "short_lag.yaml"
    config.write_text("smoother: {lag_s: 1.0}\n")
    process = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "run_odometry.py"), str(dataset), "--out", str(out), "--no-progress",
                                "--config", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    worker = tracker = None
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None and not (worker and tracker and _pose_rows(out / "tractor.tum") >= 2):
        found = run_helpers(process.pid)
        worker, tracker = found[0] or worker, found[1] or tracker
        time.sleep(0.02)
    if process.poll() is not None or not (worker and tracker):
        process.kill()
        return f"{signal.Signals(number).name}: the run ended before it could be signalled (exit {process.wait()})"
    before = _pose_rows(out / "tractor.tum")
    sent = time.monotonic()
    process.send_signal(number)
    code = process.wait(timeout=60)
    exited = time.monotonic() - sent
    left = wait_gone([worker, tracker], 30.0)
    gone = time.monotonic() - sent
    return (f"{signal.Signals(number).name}: exit code {code}, exited after {exited * 1e3:.0f} ms, worker and resource tracker "
            f"{'still running: ' + str(left) if left else f'gone after {gone * 1e3:.0f} ms'}, poses {before} -> {_pose_rows(out / 'tractor.tum')}")


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, nargs="?", default=None, help="dataset folder with images (default: the CI route rendered)")
    parser.add_argument("--trials", type=int, default=3, help="trials per signal (default 3)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="ampc_vo_interrupts_") as temporary:
        work = Path(temporary)
        dataset = args.dataset
        if dataset is None:
            from ampc_vo.sim.simulation import simulate_dataset

            dataset = work / "ci_short"
            simulate_dataset(ROOT / "configs" / "sim" / "ci_short.yaml", dataset, with_images=True)
        for number in (signal.SIGTERM, signal.SIGINT, signal.SIGKILL):
            for _ in range(args.trials):
                print(trial(dataset, work, number), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
