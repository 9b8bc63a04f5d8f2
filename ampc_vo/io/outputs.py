"""Odometry output files, written incrementally, and their readers (DESIGN section 5).

* ``tractor.tum``, ``trailer.tum``: TUM trajectory format, one pose per line ``t x y z qx qy qz qw``
  (``T_world_tractor`` / ``T_world_trailer``), with a ``#`` comment header.
* ``hitch.csv``: ``timestamp,hitch_angle,hitch_sigma`` in radians, one header line.

:class:`OutputWriter` flushes every row as it is written, so a crash keeps what was done; given the
run's :class:`~ampc_vo.io.run_folder.RunFolder` it records its files there and writes the run's
provenance line (``# ampc-vo run <id>``) under each header. A write that fails (disk full) raises
:class:`~ampc_vo.errors.WriteError`: the rows written before stay.
"""
from __future__ import annotations

import io
import logging
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO

import numpy as np

from ampc_vo.errors import DatasetError, OutputError, WriteError
from ampc_vo.geometry import ROTATION_TOLERANCE, pose_from_xyz_quat, pose_to_xyz_quat
from ampc_vo.io.run_folder import RunFolder

logger = logging.getLogger(__name__)

TRACTOR_FILE = "tractor.tum"
TRAILER_FILE = "trailer.tum"
HITCH_FILE = "hitch.csv"
TUM_HEADER = "# timestamp x y z qx qy qz qw"
HITCH_HEADER = "timestamp,hitch_angle,hitch_sigma"


@dataclass(frozen=True)
class Trajectory:
    """Timestamps (N,) in seconds and poses (N, 4, 4) ``T_world_body``."""

    timestamps: np.ndarray
    poses: np.ndarray

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) positions of the body origin (the hitch centre) in the world."""
        return self.poses[:, :3, 3]


@dataclass(frozen=True)
class HitchSeries:
    """Hitch angle estimates: timestamps (N,), angles (N,) and 1-sigma (N,), radians."""

    timestamps: np.ndarray
    angles: np.ndarray
    sigmas: np.ndarray

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])


def format_tum_row(timestamp: float, pose: np.ndarray) -> str:
    """One TUM line ``t x y z qx qy qz qw`` for a 4x4 pose."""
    values = pose_to_xyz_quat(np.asarray(pose, dtype=float))
    return f"{timestamp:.6f} " + " ".join(f"{value:.9f}" for value in values)


class OutputWriter:
    """Context-managed incremental writer of ``tractor.tum``, ``trailer.tum`` and ``hitch.csv``.

    Files are created (truncated) on entry; each ``write_*`` call appends one line and flushes.
    ``with_trailer=False`` (tractor-only rigs or modes) creates only ``tractor.tum``.
    """

    def __init__(self, directory: str | Path, with_trailer: bool = True, run: RunFolder | None = None) -> None:
        self.directory = Path(directory)
        self.with_trailer = with_trailer
        self.run = run
        self._tractor: IO[str] | None = None
        self._trailer: IO[str] | None = None
        self._hitch: IO[str] | None = None
        self.rows_written = 0

    def __enter__(self) -> "OutputWriter":
        self.open()
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None) -> None:
        self.close()

    def open(self) -> None:
        """Create the output directory and the files with their headers; :class:`OutputError` if
        that is impossible (a file in the folder's place, no permission, ...)."""
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._tractor = self._open(TRACTOR_FILE, TUM_HEADER)
            if self.with_trailer:
                self._trailer = self._open(TRAILER_FILE, TUM_HEADER)
                self._hitch = self._open(HITCH_FILE, HITCH_HEADER)
        except OSError as error:
            self.close()
            raise OutputError(f"{self.directory}: cannot write the outputs there ({error.strerror or error}: {error.filename})") from None

    def _open(self, name: str, header: str) -> IO[str]:
        path = self.directory / name if self.run is None else self.run.path(name)
        handle = open(path, "w", encoding="utf-8")
        handle.write(header + "\n" + ("" if self.run is None else self.run.tag + "\n"))
        handle.flush()
        return handle

    def close(self) -> None:
        for handle in (self._tractor, self._trailer, self._hitch):
            if handle is not None and not handle.closed:
                try:
                    handle.close()
                except OSError as error:  # its last flush failed (disk full): reported by write() already
                    logger.debug("closing %s: %s", handle.name, error)

    def write(
        self,
        timestamp: float,
        T_world_tractor: np.ndarray,
        T_world_trailer: np.ndarray | None = None,
        hitch_angle: float | None = None,
        hitch_sigma: float | None = None,
    ) -> None:
        """Append one estimate; trailer pose and hitch are written when given and enabled."""
        if self._tractor is None:
            raise RuntimeError("OutputWriter.write called before open() / outside its with-block")
        self._append(self._tractor, format_tum_row(timestamp, T_world_tractor))
        if self.with_trailer and T_world_trailer is not None:
            self._append(self._trailer, format_tum_row(timestamp, T_world_trailer))
        if self.with_trailer and hitch_angle is not None:
            sigma = float("nan") if hitch_sigma is None else float(hitch_sigma)
            self._append(self._hitch, f"{timestamp:.6f},{float(hitch_angle):.9f},{sigma:.9f}")
        self.rows_written += 1

    @staticmethod
    def _append(handle: IO[str] | None, line: str) -> None:
        assert handle is not None
        try:
            handle.write(line + "\n")
            handle.flush()
        except OSError as error:
            raise WriteError(f"{handle.name}: cannot write ({error.strerror or error}); the estimates written before are kept") from None


# ---------------------------------------------------------------------- readers
def _without_cut_last_line(path: Path, text: str, columns: int, delimiter: str | None) -> str:
    """``text`` without its last line if a crash cut that line off mid-write (no final newline and
    not ``columns`` numbers; every complete row ends with one), with a warning."""
    if not text or text.endswith("\n"):
        return text
    head, _, last = text.rpartition("\n")
    try:
        complete = len([float(value) for value in last.split(delimiter)]) == columns
    except ValueError:
        complete = False
    if complete or last.startswith("#"):
        return text
    logger.warning("%s: last line %r is incomplete (the run was cut off while writing it?): ignored", path, last[:60])
    return head + "\n"


def _load_rows(path: Path, columns: int, delimiter: str | None, finite_columns: int | None = None) -> np.ndarray:
    if not path.is_file():
        raise DatasetError(f"{path}: file not found")
    text = _without_cut_last_line(path, path.read_text(encoding="utf-8"), columns, delimiter)
    data_lines = [line for line in text.splitlines()[(0 if delimiter is None else 1):] if line.strip() and not line.startswith("#")]
    if not data_lines:
        return np.zeros((0, columns))
    try:
        rows = np.loadtxt(io.StringIO(text), comments="#", delimiter=delimiter, ndmin=2, skiprows=0 if delimiter is None else 1)
    except ValueError as error:
        raise DatasetError(f"{path}: cannot parse: {error}") from None
    if rows.size == 0:
        return np.zeros((0, columns))
    if rows.shape[1] != columns:
        raise DatasetError(f"{path}: expected {columns} columns per row, got {rows.shape[1]}")
    if not np.all(np.isfinite(rows[:, : finite_columns or columns])):
        raise DatasetError(f"{path}: contains NaN or infinite values")
    repeated = np.flatnonzero(np.diff(rows[:, 0]) <= 0.0)
    if len(repeated):
        index = int(repeated[0])
        raise DatasetError(f"{path}: timestamps not strictly increasing at data row {index + 2} ({rows[index, 0]} then {rows[index + 1, 0]})")
    return rows


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory file (``t x y z qx qy qz qw``; ``#`` lines are comments)."""
    rows = _load_rows(Path(path), 8, None)
    norms = np.linalg.norm(rows[:, 4:8], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > ROTATION_TOLERANCE)
    if len(bad):
        raise DatasetError(f"{path}: data row {int(bad[0]) + 1} (timestamp {rows[bad[0], 0]}): quaternion is not unit length (norm {norms[bad[0]]:.6f})")
    poses = np.array([pose_from_xyz_quat(row[1:]) for row in rows]).reshape(-1, 4, 4)
    return Trajectory(timestamps=rows[:, 0].copy(), poses=poses)


def write_tum(path: str | Path, trajectory: Trajectory) -> None:
    """Write a whole trajectory as a TUM file (for ground truth export and tests)."""
    lines = [TUM_HEADER] + [format_tum_row(t, pose) for t, pose in zip(trajectory.timestamps, trajectory.poses)]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def read_hitch(path: str | Path) -> HitchSeries:
    """Read ``hitch.csv`` (``timestamp,hitch_angle,hitch_sigma``, radians, one header line)."""
    path = Path(path)
    if path.is_file():
        header = path.read_text(encoding="utf-8").split("\n", 1)[0].strip()
        if header.replace(" ", "") != HITCH_HEADER:
            raise DatasetError(f"{path}: expected header {HITCH_HEADER!r}, got {header!r}")
    rows = _load_rows(path, 3, ",", finite_columns=2)  # sigma may be NaN (unknown)
    return HitchSeries(timestamps=rows[:, 0].copy(), angles=rows[:, 1].copy(), sigmas=rows[:, 2].copy())
