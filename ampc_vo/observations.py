"""Per-frame feature observations: the one currency between measurement sources and the backend.

Two sources produce the same type (DESIGN section 4): the image frontend (``frontend``) tracks
features in images, and the simulator's bearing measurements (the simulator) replay
``measurements.npz``. The backend consumes :class:`FrameObservations` and does not know which.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class CameraObservations:
    """Tracked features of one camera in one frame.

    ``track_ids`` (K,) int64 are unique within the camera: the same id in two frames of the same
    camera is the same physical point. ``pixels`` (K, 2); ``bearings`` (K, 3) unit vectors in the
    camera frame (OpenCV axes).

    ``landmark_ids`` (K,) int64 or None: optional association *across* cameras of one rig: equal
    values in two cameras (at any frames) are the same physical point, -1 means unknown. Sources:
    the simulator's ground-truth landmark index (an ideal appearance matcher) and the frontend's
    stereo matches (KITTI left/right). The backend uses them for cross-camera (two-camera form)
    epipolar correspondences, which make metric scale observable in straight driving.
    """

    camera: str
    track_ids: np.ndarray
    pixels: np.ndarray
    bearings: np.ndarray
    landmark_ids: np.ndarray | None = None
    # capture time of this camera's image (seconds; frames.csv ``<camera>_timestamp``); None: the
    # frame's timestamp. With rolling shutter it is the time of the first image row.
    timestamp: float | None = None

    def __len__(self) -> int:
        return int(self.track_ids.shape[0])

    @staticmethod
    def empty(camera: str) -> "CameraObservations":
        return CameraObservations(camera, np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)))


@dataclass(frozen=True)
class FrameObservations:
    """All cameras' observations at one frame (``frame`` index, ``timestamp`` in seconds)."""

    frame: int
    timestamp: float
    cameras: dict[str, CameraObservations] = field(default_factory=dict)

    def camera_timestamp(self, camera: str) -> float:
        """When ``camera``'s observations were captured (its own time, else the frame's)."""
        observations = self.cameras.get(camera)
        return self.timestamp if observations is None or observations.timestamp is None else float(observations.timestamp)


def match_tracks(first: CameraObservations, second: CameraObservations) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(index_first, index_second)`` of the track ids both observations share."""
    _, index_first, index_second = np.intersect1d(first.track_ids, second.track_ids, assume_unique=True, return_indices=True)
    return index_first, index_second


def match_landmarks(first: CameraObservations, second: CameraObservations) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(index_first, index_second)`` of the observations of two *different* cameras that
    see the same landmark (equal ``landmark_ids`` >= 0; ids seen twice in one camera are ambiguous
    and dropped). Empty when either camera has no landmark ids."""
    empty = np.zeros(0, dtype=np.int64)
    if first.landmark_ids is None or second.landmark_ids is None:
        return empty, empty
    usable_first, usable_second = usable_landmarks(first.landmark_ids), usable_landmarks(second.landmark_ids)
    _, index_first, index_second = np.intersect1d(first.landmark_ids[usable_first], second.landmark_ids[usable_second], assume_unique=True, return_indices=True)
    return usable_first[index_first], usable_second[index_second]


def usable_landmarks(landmark_ids: np.ndarray) -> np.ndarray:
    """Indices of the known (>= 0) landmark ids that occur once."""
    ids = np.asarray(landmark_ids, dtype=np.int64)
    values, counts = np.unique(ids, return_counts=True)
    return np.flatnonzero((ids >= 0) & ~np.isin(ids, values[counts > 1]))
