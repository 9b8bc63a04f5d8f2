"""The processes of a run, by PID (Linux ``/proc``): the frontend worker and multiprocessing's
resource tracker a run starts, and whether a process still runs (issue 14: no process of ours is
left behind). Used by ``scripts/benchmark_interrupts.py`` and the fault-injection tests."""
from __future__ import annotations

import time
from pathlib import Path

WORKER_MARK = "spawn_main"  # the command line of a spawned multiprocessing worker
TRACKER_MARK = "resource_tracker"  # that of multiprocessing's resource tracker


def child_processes(pid: int) -> dict[int, str]:
    """The processes whose parent is ``pid``: PID -> command line (empty where /proc is absent)."""
    found = {}
    for entry in Path("/proc").iterdir() if Path("/proc").is_dir() else ():
        if not entry.name.isdigit():
            continue
        try:
            if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                found[int(entry.name)] = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, ValueError, IndexError):
            continue
    return found


def run_helpers(pid: int) -> tuple[int | None, int | None]:
    """PIDs of the frontend worker and the resource tracker started by the run ``pid`` (``None``
    for one not (yet) started)."""
    children = child_processes(pid)
    worker = next((child for child, command in children.items() if WORKER_MARK in command), None)
    tracker = next((child for child, command in children.items() if TRACKER_MARK in command), None)
    return worker, tracker


def process_running(pid: int) -> bool:
    """The process exists and is not a zombie (ended, waiting to be reaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def wait_gone(pids: list[int], seconds: float) -> list[int]:
    """Wait up to ``seconds`` for ``pids`` to end; the ones still running."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(process_running(pid) for pid in pids):
        time.sleep(0.01)
    return [pid for pid in pids if process_running(pid)]
