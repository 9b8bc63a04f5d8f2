"""Wheel speed (issue 15): the forward speed of the tractor's rear-axle midpoint over time, as a CAN
bus or wheel encoders give it, read from a CSV file ``timestamp,speed`` (seconds, m/s; our dataset
folder's optional ``wheel_speed.csv``) or from a log topic (``geometry_msgs/TwistStamped`` or
``nav_msgs/Odometry``: ``twist.linear.x``, header stamps). It becomes a chord between frame times in
:func:`ampc_vo.scale.wheel.wheel_odometry_from_speed`.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ampc_vo.errors import DatasetError

WHEEL_SPEED_FILE = "wheel_speed.csv"
WHEEL_SPEED_COLUMNS = ("timestamp", "speed")
SPEED_TOPIC_TYPES = ("geometry_msgs/msg/TwistStamped", "nav_msgs/msg/Odometry")


@dataclass(frozen=True)
class WheelSpeed:
    """Samples of the rear-axle speed: ``timestamps`` (N,) s strictly increasing, ``speed`` (N,) m/s."""

    timestamps: np.ndarray
    speed: np.ndarray

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])


def checked_wheel_speed(timestamps: np.ndarray, speed: np.ndarray, where: str) -> WheelSpeed:
    """A :class:`WheelSpeed` sorted by time; :class:`DatasetError` for too few, non-finite or
    repeated samples."""
    timestamps, speed = np.asarray(timestamps, dtype=float), np.asarray(speed, dtype=float)
    if len(timestamps) < 2:
        raise DatasetError(f"{where}: wheel speed needs at least 2 samples, got {len(timestamps)}")
    if not (np.all(np.isfinite(timestamps)) and np.all(np.isfinite(speed))):
        raise DatasetError(f"{where}: wheel speed contains NaN or infinite values")
    order = np.argsort(timestamps, kind="stable")
    timestamps, speed = timestamps[order], speed[order]
    if np.any(np.diff(timestamps) <= 0):
        raise DatasetError(f"{where}: wheel speed has repeated timestamps")
    return WheelSpeed(timestamps, speed)


def write_wheel_speed_csv(path: str | Path, wheel_speed: WheelSpeed) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(WHEEL_SPEED_COLUMNS)
        for timestamp, speed in zip(wheel_speed.timestamps, wheel_speed.speed):
            writer.writerow([repr(float(timestamp)), repr(float(speed))])


def read_wheel_speed_csv(path: str | Path) -> WheelSpeed:
    """``timestamp,speed`` (one header line); errors name the file and the line."""
    from ampc_vo.io.folder import _read_csv

    path = Path(path)
    header, rows = _read_csv(path)
    if tuple(header) != WHEEL_SPEED_COLUMNS:
        raise DatasetError(f"{path}: header must be {','.join(WHEEL_SPEED_COLUMNS)}")
    values = []
    for number, row in enumerate(rows, start=2):
        try:
            if len(row) != 2:
                raise ValueError(f"expected 2 columns, got {len(row)}")
            values.append([float(row[0]), float(row[1])])
        except ValueError as error:
            raise DatasetError(f"{path}: line {number}: {error}") from None
    values = np.array(values, dtype=float).reshape(-1, 2)
    return checked_wheel_speed(values[:, 0], values[:, 1], str(path))


def wheel_speed_from_log(path: str | Path, topic: str) -> WheelSpeed:
    """The forward speed ``twist.linear.x`` of a TwistStamped or Odometry topic, at its header stamps."""
    from ampc_vo.io.bags import topic_messages

    samples = [(stamp, message.twist.linear.x if hasattr(message.twist, "linear") else message.twist.twist.linear.x)
               for stamp, message in topic_messages(path, topic, SPEED_TOPIC_TYPES, "wheel-speed")]
    return checked_wheel_speed(np.array([s for s, _ in samples]), np.array([v for _, v in samples]), f"{path}: {topic}")


def load_wheel_speed(source: str | Path | None, dataset_path: str | Path) -> WheelSpeed | None:
    """The wheel speed named by ``source`` (config ``scale.wheel_speed_source``): a CSV file (an
    existing path or a name ending in ``.csv``, relative to the working directory), else a topic of
    the log at ``dataset_path``; ``None``: the dataset folder's ``wheel_speed.csv`` if present."""
    dataset_path = Path(dataset_path)
    if source is None:
        folder_file = dataset_path / WHEEL_SPEED_FILE
        return read_wheel_speed_csv(folder_file) if dataset_path.is_dir() and folder_file.is_file() else None
    source = str(source)
    if source.endswith(".csv") or Path(source).is_file():
        return read_wheel_speed_csv(source)
    from ampc_vo.io.bags import is_log

    if not is_log(dataset_path):
        raise DatasetError(f"{dataset_path}: wheel-speed source {source!r} is a topic, but the dataset is not a log (give a CSV file)")
    return wheel_speed_from_log(dataset_path, source)
