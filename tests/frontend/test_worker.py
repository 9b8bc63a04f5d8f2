"""A frame stream in a worker process (ampc_vo.frontend.worker): order, errors, logs, a dying worker, early close.
(That the image source gives the same observations in its own process as inline: tests/test_runner.py.)"""
from __future__ import annotations

import itertools
import logging

import pytest

import worker_support
from ampc_vo.errors import DatasetError, SourceError
from ampc_vo.frontend.worker import stream_in_process


def test_items_arrive_in_order_through_a_small_queue():
    assert list(stream_in_process(worker_support.count_up, (25,), queue_size=2)) == list(range(25))


def test_an_error_in_the_worker_is_raised_here_with_its_type_and_message():
    received = []
    with pytest.raises(DatasetError, match="000007.png cannot be decoded"):
        for item in stream_in_process(worker_support.fail_after, (4,)):
            received.append(item)
    assert received == [0, 1, 2, 3]  # what came before the error is delivered


def test_worker_log_records_reach_this_process_at_its_level(caplog):
    caplog.set_level(logging.INFO)
    assert list(stream_in_process(worker_support.log_then_stop, ("camera rear: blank image",))) == [1]
    messages = [(record.name, record.levelno, record.getMessage()) for record in caplog.records]
    assert ("ampc_vo.frontend.tracker", logging.WARNING, "camera rear: blank image") in messages
    assert not any("not shown" in message for _, _, message in messages)


def test_a_worker_that_dies_gives_a_clear_error():
    received = []
    with pytest.raises(SourceError, match="stopped unexpectedly .*exit code 3"):
        for item in stream_in_process(worker_support.die_after, (3,)):
            received.append(item)
    assert received == [0, 1, 2][: len(received)]  # items still in its send buffer die with it


def test_closing_the_stream_early_stops_the_worker():
    import multiprocessing

    stream = stream_in_process(worker_support.forever, (), queue_size=2)
    assert list(itertools.islice(stream, 5)) == [0, 1, 2, 3, 4]
    stream.close()
    assert not [child for child in multiprocessing.active_children() if child.name == "ampc-vo-frontend"]


_SCRIPT_WITHOUT_MAIN_GUARD = """
import sys
sys.path[:0] = {paths!r}
import worker_support
from ampc_vo.frontend.worker import stream_in_process
print("items", list(stream_in_process(worker_support.count_up, (3,))))
"""


@pytest.mark.parametrize("how", ["file", "stdin"])
def test_callers_main_module_is_not_run_again_in_the_worker(tmp_path, how):
    """A script without a main guard (or read from stdin) streams through a worker process: the
    worker must not re-run it (spawn's default: recursion or a missing '<stdin>' file)."""
    import subprocess
    import sys
    from pathlib import Path

    tests = Path(__file__).resolve().parents[1]
    script = _SCRIPT_WITHOUT_MAIN_GUARD.format(paths=[str(tests), str(tests.parent)])
    if how == "file":
        path = tmp_path / "user_script.py"
        path.write_text(script)
        run = subprocess.run([sys.executable, str(path)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    else:
        run = subprocess.run([sys.executable, "-"], input=script, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.count("items [0, 1, 2]") == 1, run.stdout


_SCRIPT_KILLED_CONSUMER = """
import multiprocessing, sys, time
sys.path[:0] = {paths!r}
import worker_support
from ampc_vo.frontend.worker import stream_in_process
stream = stream_in_process(worker_support.forever, (), queue_size=1)
next(stream), next(stream)
print([child.pid for child in multiprocessing.active_children() if child.name == "ampc-vo-frontend"][0], flush=True)
time.sleep(120)
"""


def test_a_worker_whose_consumer_is_killed_ends_by_itself(tmp_path):
    """SIGKILL of the consumer (no cleanup runs there): the worker, blocked on a full queue, ends."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    tests = Path(__file__).resolve().parents[1]
    consumer = subprocess.Popen([sys.executable, "-c", _SCRIPT_KILLED_CONSUMER.format(paths=[str(tests), str(tests.parent)])],
                                stdout=subprocess.PIPE, text=True)
    worker_pid = int(consumer.stdout.readline())
    consumer.send_signal(signal.SIGKILL)
    consumer.wait(10)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        try:
            os.kill(worker_pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        os.kill(worker_pid, signal.SIGKILL)
        pytest.fail("the worker went on after its consumer was killed")


def test_a_worker_that_cannot_start_is_a_worker_start_error(monkeypatch):
    import ampc_vo.frontend.worker
    from ampc_vo.frontend.worker import WorkerStartError

    class NoSemaphores:
        def Queue(self, *args, **kwargs):
            raise OSError(38, "Function not implemented")

    monkeypatch.setattr(ampc_vo.frontend.worker.multiprocessing, "get_context", lambda method: NoSemaphores())
    with pytest.raises(WorkerStartError, match="could not be started .*Function not implemented"):
        next(stream_in_process(worker_support.count_up, (3,)))
