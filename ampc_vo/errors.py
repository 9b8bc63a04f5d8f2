"""The project's exception types: one base class, one subclass per kind of bad input or failure.

Every error carries the process exit code the command-line tools end with (``exit_code``, README
"Exit codes"): 2 for bad input (the user can fix the dataset, config, rig or arguments), 1 for a
run that failed for another reason (a worker died, the disk filled up, nothing could be measured).
"""
from __future__ import annotations

EXIT_DONE = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_SIGINT = 130  # 128 + SIGINT (2), what shells report for Ctrl-C
EXIT_SIGTERM = 143  # 128 + SIGTERM (15): timeout, systemd, docker stop


def first_line(error: BaseException) -> str:
    """An exception's message in one line, for logs and summaries: its first paragraph (the non-empty
    lines up to the next empty one, joined; GTSAM's begin with a newline and name the variable on
    their second line), or the exception type's name when it has none."""
    paragraph: list[str] = []
    for line in str(error).splitlines():
        if line.strip():
            paragraph.append(line.strip())
        elif paragraph:
            break
    return " ".join(paragraph) if paragraph else type(error).__name__


class AmpcError(Exception):
    """Base class of every error ampc-vo raises on purpose."""

    exit_code = EXIT_BAD_INPUT


class ConfigError(AmpcError, ValueError):
    """A configuration or rig file is missing a field or has an invalid value."""


class DatasetError(AmpcError):
    """A dataset folder is missing files, has unreadable images or inconsistent tables."""


class BearingError(AmpcError, ValueError):
    """Bearing vectors of the wrong shape, with NaN, or of zero length."""


class OutputError(AmpcError):
    """The output folder cannot be created or written (a file in its place, no permission, in use
    by another run, ...)."""


class WriteError(OutputError):
    """Writing an output failed during the run (disk full, ...): what was written before is kept."""

    exit_code = EXIT_FAILED


class SourceError(AmpcError):
    """A measurement source failed while running (e.g. its worker process died)."""

    exit_code = EXIT_FAILED


class NothingMeasuredError(AmpcError):
    """A run ended without one measured motion (nothing to track, too few frames): it wrote no
    poses rather than made-up ones."""

    exit_code = EXIT_FAILED


class Interrupted(KeyboardInterrupt):
    """SIGTERM (or SIGINT) received: raised in the main thread by :mod:`ampc_vo.tools.cli`'s
    handler, so the run unwinds exactly as after Ctrl-C (the window is written, workers stop)."""

    def __init__(self, signal_number: int, exit_code: int) -> None:
        super().__init__(signal_number)
        self.signal_number = signal_number
        self.exit_code = exit_code
