"""The project's exception types: one base class, one subclass per kind of bad input."""
from __future__ import annotations


class AmpcError(Exception):
    """Base class of every error ampc-vo raises on purpose."""


class ConfigError(AmpcError, ValueError):
    """A configuration or rig file is missing a field or has an invalid value."""


class DatasetError(AmpcError):
    """A dataset folder is missing files, has unreadable images or inconsistent tables."""


class BearingError(AmpcError, ValueError):
    """Bearing vectors of the wrong shape, with NaN, or of zero length."""


class OutputError(AmpcError):
    """The output folder cannot be created or written (a file in its place, no permission, ...)."""


class SourceError(AmpcError):
    """A measurement source failed while running (e.g. its worker process died)."""
