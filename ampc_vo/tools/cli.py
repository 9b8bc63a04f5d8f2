"""Exit codes, signals and the one-line exit message of every command-line tool (issue 14).

Every script's ``main`` runs inside :func:`run_cli`, which guarantees a documented exit code and a
one-line message on stderr for every way a run can end (README "Exit codes"):

====  ==========================================================================================
0     done
1     failed: the run could not complete (a worker died, the disk filled up, nothing could be
      measured, an unexpected error: its traceback is logged at DEBUG level)
2     bad input: dataset, config, rig, arguments or output folder (the message names file and field)
130   interrupted by SIGINT (Ctrl-C)
143   interrupted by SIGTERM (``timeout``, systemd, ``docker stop``)
====  ==========================================================================================

SIGTERM is turned into :class:`~ampc_vo.errors.Interrupted` (a ``KeyboardInterrupt``) raised in
the main thread, so it unwinds exactly like Ctrl-C: the pipeline writes the keyframes still in its
window, the frontend worker process is stopped, the run folder is marked ``interrupted``. A second
signal during that clean-up is ignored (SIGKILL still ends the process; the worker then follows
on its own, :mod:`ampc_vo.frontend.worker`).
"""
from __future__ import annotations

import contextlib
import errno
import functools
import logging
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

from ampc_vo.errors import EXIT_FAILED, EXIT_SIGINT, EXIT_SIGTERM, AmpcError, Interrupted
from ampc_vo.io.outputs import TRACTOR_FILE

logger = logging.getLogger(__name__)

SIGNAL_EXIT_CODES = {signal.SIGINT: EXIT_SIGINT, signal.SIGTERM: EXIT_SIGTERM}


@dataclass
class ExitContext:
    """What the exit message can say about a run: where its outputs go (``None``: not decided yet)."""

    outputs: Path | None = None

    def interrupted_note(self) -> str:
        if self.outputs is None:
            return "nothing was written"
        poses = _pose_count(Path(self.outputs) / TRACTOR_FILE)
        if not poses:
            return f"no poses were written yet ({self.outputs})"
        return f"the {poses} poses written so far are in {self.outputs}"


def _pose_count(path: Path) -> int:
    """Data rows of a TUM file (0 when absent or unreadable)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as handle:
            return sum(1 for line in handle if line.strip() and not line.startswith("#"))
    except OSError:
        return 0


@contextlib.contextmanager
def signals_as_interrupts() -> Iterator[None]:
    """While active, SIGTERM raises :class:`Interrupted` in the main thread (SIGINT raises its
    usual ``KeyboardInterrupt``); the first signal only, later ones are logged and ignored so the
    clean-up it started can finish. The previous handlers are restored on exit."""
    received: list[int] = []

    def handler(number: int, _frame: object) -> None:
        if received:
            logger.warning("%s again: still writing the last estimates (SIGKILL stops at once)", signal.Signals(number).name)
            return
        received.append(number)
        raise Interrupted(number, SIGNAL_EXIT_CODES[number])

    previous = {number: signal.getsignal(number) for number in SIGNAL_EXIT_CODES}
    for number in SIGNAL_EXIT_CODES:
        signal.signal(number, handler)
    try:
        yield
    finally:
        for number, old in previous.items():
            signal.signal(number, old)


def exit_message(error: BaseException, context: ExitContext) -> tuple[int, str]:
    """The exit code and the one-line message for ``error`` (module docstring)."""
    if isinstance(error, Interrupted):
        return error.exit_code, f"interrupted ({signal.Signals(error.signal_number).name}): {context.interrupted_note()}"
    if isinstance(error, KeyboardInterrupt):
        return EXIT_SIGINT, f"interrupted (SIGINT): {context.interrupted_note()}"
    if isinstance(error, AmpcError):
        return error.exit_code, f"error: {error}"
    if isinstance(error, OSError):
        where = f"{error.filename}: " if error.filename else ""
        reason = "disk full" if error.errno == errno.ENOSPC else (error.strerror or str(error))
        return EXIT_FAILED, f"failed: {where}{reason}"
    return EXIT_FAILED, f"failed: {type(error).__name__}: {error} (the traceback is logged at DEBUG level)"


def exit_codes(main: Callable[..., int]) -> Callable[..., int]:
    """Decorator for a script's ``main(argv)`` that needs no :class:`ExitContext`: it runs under
    :func:`run_cli` (argparse's own exit 2 for bad arguments passes through)."""

    @functools.wraps(main)
    def wrapped(*args: object, **kwargs: object) -> int:
        return run_cli(lambda context: main(*args, **kwargs))

    return wrapped


def run_cli(main: Callable[[ExitContext], int]) -> int:
    """Run a script's ``main(context)`` with :func:`signals_as_interrupts`; any error or interrupt
    becomes its exit code with one line on stderr (module docstring)."""
    context = ExitContext()
    try:
        with signals_as_interrupts():
            return main(context)
    except SystemExit:
        raise
    except BaseException as error:  # noqa: BLE001 - every way out gets its code and message
        code, message = exit_message(error, context)
        if code == EXIT_FAILED and not isinstance(error, AmpcError):
            logger.debug("traceback", exc_info=error)
        print(message.replace("\n", " "), file=sys.stderr)
        return code
