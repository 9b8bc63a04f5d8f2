"""A stream of frames produced in a worker process beside the backend (issue 7: whole-pipeline speed).

The backend (GTSAM with the Python error functions of ``factors/``) holds the GIL for most of its
time, so a frontend in a worker *thread* of the same process keeps waiting for it: on the 2-core
machine the two shared about 1.5 cores. In a process of its own the frontend (image decoding, KLT,
RANSAC, detection) runs on the other core, and only its small results (bearings, pixels, ids,
reports; the images when a recording needs them) cross over.

:func:`stream_in_process` runs ``make_stream(*args)`` in a spawned process (fork is unsafe with
OpenCV's thread pool; :class:`WorkerStartError` on the first ``next`` when no process can be
started there, e.g. without ``/dev/shm``) and yields its items in order through a bounded queue, so at most
``queue_size`` frames are produced ahead of the consumer. The worker's log records are handed to
this process's loggers; an exception in the worker is raised here as the same exception (the
worker's traceback is logged at DEBUG); a worker that dies without a word (killed, crashed) gives a
:class:`~ampc_vo.errors.SourceError`. Closing the stream early (an error in the backend, Ctrl-C)
stops the worker. The worker ends with its consumer whatever kills that (SIGTERM, SIGKILL, a
crash): a watchdog thread in the worker waits on the parent's sentinel and exits the process the
moment the parent is gone (:func:`_exit_with_parent`), so no orphan keeps multiprocessing's
resource tracker alive either. The worker does not import the caller's ``__main__`` (multiprocessing's spawn
would: it re-runs a script without a ``if __name__ == "__main__"`` guard and fails for code read
from stdin), so ``make_stream`` must live in an importable module.
"""
from __future__ import annotations

import contextlib
import logging
import logging.handlers
import multiprocessing
import multiprocessing.connection
import os
import pickle
import queue as queue_module
import sys
import threading
import traceback
import types
from typing import Any, Callable, Iterator

from threadpoolctl import threadpool_limits

from ampc_vo.errors import SourceError

logger = logging.getLogger(__name__)

_STEP, _LOG, _ERROR, _DONE = "step", "log", "error", "done"
_POLL_S = 0.5  # how often the consumer checks that a silent worker is still alive


class WorkerStartError(SourceError):
    """The worker process could not be started (the caller may run the stream in this process)."""


class _ConsumerGone(Exception):
    """The consuming process has ended (killed): nobody reads the queue any more."""


def _send(channel: Any, message: tuple) -> None:
    """Put ``message`` on the queue, waiting while it is full; :class:`_ConsumerGone` when the
    consumer died meanwhile (so a worker whose consumer was killed ends instead of waiting forever)."""
    parent = multiprocessing.parent_process()
    while True:
        try:
            channel.put(message, timeout=_POLL_S)
            return
        except queue_module.Full:
            if parent is not None and not parent.is_alive():
                raise _ConsumerGone from None


class _ForwardingHandler(logging.handlers.QueueHandler):
    """Puts the worker's log records (message already formatted) on the stream's queue."""

    def enqueue(self, record: logging.LogRecord) -> None:
        try:
            _send(self.queue, (_LOG, record))
        except _ConsumerGone:
            pass


def _exit_with_parent() -> None:
    """Exit this (worker) process as soon as its parent has ended, for whatever reason: a daemon
    thread blocks on the parent's sentinel (a pipe that reads end-of-file when the parent dies) and
    then calls ``os._exit`` (no clean-up that could block on the queue's pipe, nobody reads it)."""
    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        multiprocessing.connection.wait([parent.sentinel])
        os._exit(0)

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def _worker_main(channel: Any, make_stream: Callable[..., Iterator[Any]], args: tuple, log_level: int) -> None:
    """Entry point of the worker process: produce every item, then a done marker (or the error)."""
    _exit_with_parent()
    root = logging.getLogger()
    root.handlers[:] = [_ForwardingHandler(channel)]
    root.setLevel(log_level)
    try:
        with threadpool_limits(limits=1, user_api="blas"):  # small arrays: BLAS threads only spin
            for item in make_stream(*args):
                _send(channel, (_STEP, item))
        _send(channel, (_DONE, None))
    except (KeyboardInterrupt, _ConsumerGone):  # Ctrl-C reaches the whole process group: the consumer handles it
        channel.cancel_join_thread()  # items nobody will read must not keep this process from ending
        return
    except BaseException as error:  # noqa: BLE001 - everything goes back to the consumer
        details = traceback.format_exc()
        try:
            pickle.dumps(error)
        except Exception:  # an exception that cannot cross processes: keep its text
            error = SourceError(f"{type(error).__name__}: {error}")
        try:
            _send(channel, (_ERROR, (error, details)))
        except _ConsumerGone:
            pass


@contextlib.contextmanager
def _main_module_hidden() -> Iterator[None]:
    """Start processes with a blank stand-in for ``__main__``: spawn then has no main module to
    re-import in the child (module docstring)."""
    main = sys.modules["__main__"]
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


def stream_in_process(make_stream: Callable[..., Iterator[Any]], args: tuple = (), queue_size: int = 4,
                      name: str = "frontend") -> Iterator[Any]:
    """Yield the items of ``make_stream(*args)`` computed in a worker process (module docstring).

    ``make_stream`` must be a function of an importable module (not ``__main__``) and ``args``
    picklable (they are sent to the spawned process). Items are produced at most ``queue_size``
    ahead of the consumer.
    """
    if queue_size < 1:
        raise ValueError(f"queue_size must be >= 1, got {queue_size}")
    try:
        context = multiprocessing.get_context("spawn")
        channel = context.Queue(maxsize=queue_size)
        process = context.Process(target=_worker_main, args=(channel, make_stream, args, logging.getLogger().getEffectiveLevel()),
                                  name=f"ampc-vo-{name}", daemon=True)
        with _main_module_hidden():
            process.start()
    except (OSError, ImportError, TypeError, pickle.PicklingError) as error:  # no semaphores (/dev/shm), no fork/exec, unpicklable args
        raise WorkerStartError(f"the {name} process could not be started ({type(error).__name__}: {error})") from None
    try:
        while True:
            try:
                kind, payload = channel.get(timeout=_POLL_S)
            except queue_module.Empty:
                if process.is_alive():
                    continue
                try:  # it may have put its last items just before it ended
                    kind, payload = channel.get(timeout=_POLL_S)
                except queue_module.Empty:
                    raise SourceError(f"the {name} process stopped unexpectedly (exit code {process.exitcode})") from None
            if kind == _STEP:
                yield payload
            elif kind == _LOG:
                target = logging.getLogger(payload.name)
                if target.isEnabledFor(payload.levelno):
                    target.handle(payload)
            elif kind == _ERROR:
                error, details = payload
                logger.debug("%s process failed:\n%s", name, details)
                raise error
            else:
                return
    finally:
        if process.is_alive():
            process.terminate()
        process.join(timeout=5.0)
        channel.close()
        channel.cancel_join_thread()
