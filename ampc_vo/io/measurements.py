"""Simulated bearing measurements and their file format ``measurements.npz`` (DESIGN section 5).

One row per (frame, camera, track). Arrays (M rows, sorted by frame then camera):

    frame (M,) int64          frame index (row of frames.csv / trajectory)
    camera_index (M,) int64   index into camera_names
    track_id (M,) int64       unique within a camera; constant while a landmark stays tracked
    landmark_id (M,) int64    index into landmarks (ground truth; also set for outliers)
    pixel (M, 2) float64      measured pixel (noise added; a uniform random pixel for outliers)
    pixel_clean (M, 2)        noise-free projection of the landmark (ground truth)
    is_outlier (M,) bool
    camera_names (C,) str
    landmarks (L, 3) float64  world points (ground truth)
    timestamps (F,) float64   seconds, one per frame
    camera_timestamps (F, C)  optional: capture time of each camera's image (s; rolling shutter: its
                              first row); absent: every camera captures at ``timestamps``
    association_id (M,) int64 optional: cross-camera association a frontend could measure (stereo
                              matches between overlapping cameras, ``sim.associations``), -1 unknown;
                              absent (older files): ``landmark_id`` is used, with a warning (a truth leak)
    landmark_body (L,) int64  optional: -1 for a static landmark (``landmarks`` row in the world frame),
                              b >= 0 for one on moving body b (traffic, the trailer box; its row is in
                              that body's frame: tracks on it are consistent outliers to the static world)

``Measurements.observations(frame)`` turns the rows of one frame into the backend's currency
:class:`ampc_vo.observations.FrameObservations` (bearings = ``camera.unproject(pixel)``,
``landmark_ids`` = ``association_id``, ``timestamp`` per camera from ``camera_timestamps``).
"""
from __future__ import annotations

import logging
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ampc_vo.errors import DatasetError
from ampc_vo.io.frame_times import check_frame_times
from ampc_vo.observations import CameraObservations, FrameObservations
from ampc_vo.rig import Rig

MEASUREMENTS_FILE = "measurements.npz"
LOGGER = logging.getLogger(__name__)
_ROW_ARRAYS = ("frame", "camera_index", "track_id", "landmark_id", "pixel", "pixel_clean", "is_outlier")


@dataclass(frozen=True, eq=False)
class Measurements:
    """Simulated feature tracks of all cameras (module docstring). ``rig`` (not saved) is needed
    to un-project pixels into bearings; pass it here or to :meth:`observations`."""

    frame: np.ndarray
    camera_index: np.ndarray
    track_id: np.ndarray
    landmark_id: np.ndarray
    pixel: np.ndarray
    pixel_clean: np.ndarray
    is_outlier: np.ndarray
    camera_names: tuple[str, ...]
    landmarks: np.ndarray
    timestamps: np.ndarray
    rig: Rig | None = None
    camera_timestamps: np.ndarray | None = None   # (F, C) capture times, None: ``timestamps``
    association_id: np.ndarray | None = None      # (M,) cross-camera associations, None: ``landmark_id``
    landmark_body: np.ndarray | None = None       # (L,) -1 static, else the moving body of the landmark

    def __post_init__(self) -> None:
        order = np.lexsort((self.camera_index, self.frame))
        if np.any(order != np.arange(len(order))):
            for name in _ROW_ARRAYS + (("association_id",) if self.association_id is not None else ()):
                object.__setattr__(self, name, getattr(self, name)[order])
        bounds = np.searchsorted(self.frame, np.arange(self.frame_count + 1))
        object.__setattr__(self, "_bounds", bounds)

    @property
    def frame_count(self) -> int:
        return int(self.timestamps.shape[0])

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    def rows(self, frame: int, camera: str | None = None) -> np.ndarray:
        """Row indices of one frame (and optionally one camera)."""
        if not 0 <= frame < self.frame_count:
            raise IndexError(f"frame {frame} out of range [0, {self.frame_count})")
        start, stop = self._bounds[frame], self._bounds[frame + 1]  # type: ignore[attr-defined]
        rows = np.arange(start, stop)
        if camera is not None:
            rows = rows[self.camera_index[rows] == self.camera_names.index(camera)]
        return rows

    def observations(self, frame: int, rig: Rig | None = None) -> FrameObservations:
        """The measured tracks of ``frame`` as :class:`FrameObservations` (bearings from noisy pixels)."""
        rig = rig if rig is not None else self.rig
        if rig is None:
            raise ValueError("Measurements.observations needs a rig to un-project pixels (pass rig=...)")
        rows = self.rows(frame)
        cameras: dict[str, CameraObservations] = {}
        for index, name in enumerate(self.camera_names):
            selected = rows[self.camera_index[rows] == index]
            pixels = self.pixel[selected]
            bearings = rig.camera(name).unproject(pixels) if len(selected) else np.zeros((0, 3))
            associations = self.landmark_id if self.association_id is None else self.association_id
            timestamp = None if self.camera_timestamps is None else float(self.camera_timestamps[frame, index])
            cameras[name] = CameraObservations(name, self.track_id[selected].copy(), pixels.copy(), bearings, associations[selected].copy(), timestamp)
        return FrameObservations(frame=int(frame), timestamp=float(self.timestamps[frame]), cameras=cameras)

    def frames(self, rig: Rig | None = None) -> Iterator[FrameObservations]:
        """All frames in order."""
        for frame in range(self.frame_count):
            yield self.observations(frame, rig)

    def tracks_per_camera(self) -> dict[str, float]:
        """Mean number of observations per frame for each camera (a summary for reports)."""
        counts = np.bincount(self.camera_index, minlength=len(self.camera_names)) / max(self.frame_count, 1)
        return {name: float(count) for name, count in zip(self.camera_names, counts)}


def save_measurements(measurements: Measurements, path: str | Path) -> None:
    """Write ``measurements.npz`` (compressed)."""
    np.savez_compressed(
        Path(path),
        frame=measurements.frame.astype(np.int64),
        camera_index=measurements.camera_index.astype(np.int64),
        track_id=measurements.track_id.astype(np.int64),
        landmark_id=measurements.landmark_id.astype(np.int64),
        pixel=measurements.pixel.astype(np.float64),
        pixel_clean=measurements.pixel_clean.astype(np.float64),
        is_outlier=measurements.is_outlier.astype(bool),
        camera_names=np.asarray(measurements.camera_names, dtype=str),
        landmarks=measurements.landmarks.astype(np.float64),
        timestamps=measurements.timestamps.astype(np.float64),
        **({} if measurements.camera_timestamps is None else {"camera_timestamps": measurements.camera_timestamps.astype(np.float64)}),
        **({} if measurements.association_id is None else {"association_id": measurements.association_id.astype(np.int64)}),
        **({} if measurements.landmark_body is None else {"landmark_body": measurements.landmark_body.astype(np.int64)}),
    )


PIXEL_MARGIN = 0.1  # a measured pixel may lie this fraction of the image size outside it (noise)
ROW_ARRAYS = ("frame", "camera_index", "track_id", "landmark_id", "is_outlier")
INTEGER_ARRAYS = ("frame", "camera_index", "track_id", "landmark_id")


def _check_shapes(path: Path, data: dict[str, np.ndarray]) -> None:
    """Every array has the shape and kind of the module docstring (a 2-D ``frame``, a 0-d
    ``camera_names``, float ids are errors that name the array, not tracebacks later)."""
    for name in ROW_ARRAYS + ("camera_names",) + (("timestamps",) if "timestamps" in data else ()):
        if data[name].ndim != 1:
            raise DatasetError(f"{path}: array {name!r} must be one-dimensional, got shape {data[name].shape}")
    rows = data["frame"].shape[0]
    for name in ROW_ARRAYS[1:] + ("pixel",) + (("pixel_clean",) if "pixel_clean" in data else ()):
        if data[name].shape[0] != rows:
            raise DatasetError(f"{path}: array {name!r} has {data[name].shape[0]} rows, 'frame' has {rows}")
    for name in ("pixel",) + (("pixel_clean",) if "pixel_clean" in data else ()):
        if data[name].ndim != 2 or data[name].shape[1] != 2:
            raise DatasetError(f"{path}: array {name!r} must have shape (M, 2), got {data[name].shape}")
    if data["landmarks"].ndim != 2 or data["landmarks"].shape[1] != 3:
        raise DatasetError(f"{path}: array 'landmarks' must have shape (L, 3), got {data['landmarks'].shape}")
    for name in INTEGER_ARRAYS:
        values = data[name]
        if values.dtype.kind not in "iu" and not (values.dtype.kind in "fb" and np.all(np.isfinite(values)) and np.all(values == np.round(values))):
            raise DatasetError(f"{path}: array {name!r} must hold integers, got {values.dtype} values")
    for name in ("pixel", "landmarks") + (("pixel_clean",) if "pixel_clean" in data else ()) + (("timestamps",) if "timestamps" in data else ()):
        if data[name].dtype.kind not in "iuf":
            raise DatasetError(f"{path}: array {name!r} must hold numbers, got {data[name].dtype}")
    if data["camera_names"].dtype.kind not in "US":
        raise DatasetError(f"{path}: array 'camera_names' must hold strings, got {data['camera_names'].dtype}")


def _check_unique_tracks(path: Path, frame: np.ndarray, camera_index: np.ndarray, track_id: np.ndarray, camera_names: tuple[str, ...]) -> None:
    """A track is seen at most once per frame and camera (a repeated id would be two pixels of one
    feature)."""
    if len(frame) < 2:
        return
    keys = np.stack([frame.astype(np.int64), camera_index.astype(np.int64), track_id.astype(np.int64)], axis=1)
    keys = keys[np.lexsort(keys.T[::-1])]
    repeated = np.flatnonzero(np.all(keys[1:] == keys[:-1], axis=1))
    if len(repeated):
        f, c, t = keys[int(repeated[0])]
        raise DatasetError(f"{path}: track_id {t} appears more than once in frame {f}, camera {camera_names[c]!r} "
                           "(a track is seen at most once per frame and camera)")


def _check_pixels_inside(path: Path, pixel: np.ndarray, camera_index: np.ndarray, camera_names: tuple[str, ...], rig: Rig) -> None:
    """Every measured pixel lies in its camera's image, up to ``PIXEL_MARGIN`` of its size (pixel
    noise at the border): pixels of another resolution, or scaled coordinates, would be unprojected
    into wrong bearings."""
    sizes = np.array([[rig.camera(name).width, rig.camera(name).height] for name in camera_names], dtype=float).reshape(-1, 2)
    if not len(pixel):
        return
    limits = sizes[camera_index]
    outside = np.flatnonzero(np.any((pixel < -PIXEL_MARGIN * limits) | (pixel > (1.0 + PIXEL_MARGIN) * limits), axis=1))
    if len(outside):
        row = int(outside[0])
        camera = rig.camera(camera_names[camera_index[row]])
        raise DatasetError(f"{path}: row {row}: pixel ({pixel[row, 0]:.6g}, {pixel[row, 1]:.6g}) lies outside the "
                           f"{camera.width}x{camera.height} image of camera {camera.name!r} ({len(outside)} rows outside; measurements of another rig?)")


def load_measurements(path: str | Path, rig: Rig | None = None) -> Measurements:
    """Read ``measurements.npz``; a missing, corrupt or inconsistent file raises :class:`DatasetError`.

    ``pixel_clean``, ``timestamps``, ``camera_timestamps`` and ``association_id`` are optional in the
    file (defaults: ``pixel``, frame indices, the frame times, ``landmark_id`` with a warning).
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: measurements file not found")
    if not zipfile.is_zipfile(path):
        raise DatasetError(f"{path}: not a readable .npz file (not a zip archive of arrays)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            data = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise DatasetError(f"{path}: not a readable .npz file ({error})") from None
    required = ("frame", "camera_index", "track_id", "landmark_id", "pixel", "is_outlier", "camera_names", "landmarks")
    missing = [name for name in required if name not in data]
    if missing:
        raise DatasetError(f"{path}: missing array(s) {missing}")
    _check_shapes(path, data)
    rows = data["frame"].shape[0]
    camera_names = tuple(str(name) for name in data["camera_names"])
    landmarks = data["landmarks"]
    if rows and (data["camera_index"].min() < 0 or data["camera_index"].max() >= len(camera_names)):
        raise DatasetError(f"{path}: camera_index out of range for {len(camera_names)} cameras")
    if rows and (data["landmark_id"].min() < 0 or data["landmark_id"].max() >= len(landmarks)):
        raise DatasetError(f"{path}: landmark_id out of range for {len(landmarks)} landmarks")
    if rows and data["frame"].min() < 0:
        raise DatasetError(f"{path}: negative frame index")
    if "timestamps" in data:
        timestamps = data["timestamps"].astype(float)
        if not np.all(np.isfinite(timestamps)):
            raise DatasetError(f"{path}: array 'timestamps' contains NaN or infinite values (frame {int(np.flatnonzero(~np.isfinite(timestamps))[0])})")
        if np.any(np.diff(timestamps) <= 0.0):
            frame = int(np.flatnonzero(np.diff(timestamps) <= 0.0)[0]) + 1
            raise DatasetError(f"{path}: array 'timestamps' not strictly increasing at frame {frame} ({timestamps[frame - 1]} then {timestamps[frame]})")
        check_frame_times(timestamps, f"{path}: timestamps")
        if rows and data["frame"].max() >= len(timestamps):
            raise DatasetError(f"{path}: frame index {data['frame'].max()} beyond {len(timestamps)} timestamps")
    else:
        timestamps = np.arange(int(data["frame"].max()) + 1 if rows else 0, dtype=float)
    for name in ("pixel", "landmarks") + (("pixel_clean",) if "pixel_clean" in data else ()):
        if not np.all(np.isfinite(data[name])):
            raise DatasetError(f"{path}: array {name!r} contains NaN or infinite values")
    _check_unique_tracks(path, data["frame"], data["camera_index"], data["track_id"], camera_names)
    camera_timestamps = data.get("camera_timestamps")
    if camera_timestamps is not None:
        if camera_timestamps.shape != (len(timestamps), len(camera_names)):
            raise DatasetError(f"{path}: array 'camera_timestamps' must have shape (frames, cameras) = "
                               f"{(len(timestamps), len(camera_names))}, got {camera_timestamps.shape}")
        if not np.all(np.isfinite(camera_timestamps)):
            raise DatasetError(f"{path}: array 'camera_timestamps' contains NaN or infinite values")
        camera_timestamps = camera_timestamps.astype(float)
    association_id = data.get("association_id")
    if association_id is None:
        LOGGER.warning("%s: no 'association_id' array: ground-truth landmark ids serve as cross-camera associations "
                       "(a truth leak of older simulations; re-simulate)", path)
    elif association_id.shape != (rows,):
        raise DatasetError(f"{path}: array 'association_id' has shape {association_id.shape}, expected ({rows},)")
    else:
        association_id = association_id.astype(np.int64)
    landmark_body = data.get("landmark_body")
    if landmark_body is not None and landmark_body.shape != (len(landmarks),):
        raise DatasetError(f"{path}: array 'landmark_body' has shape {landmark_body.shape}, expected ({len(landmarks)},)")
    if rig is not None:
        unknown = [name for name in camera_names if name not in rig.camera_names]
        if unknown:
            raise DatasetError(f"{path}: camera(s) {unknown} not in the rig (rig cameras: {rig.camera_names})")
        _check_pixels_inside(path, data["pixel"], data["camera_index"], camera_names, rig)
    return Measurements(
        frame=data["frame"].astype(np.int64),
        camera_index=data["camera_index"].astype(np.int64),
        track_id=data["track_id"].astype(np.int64),
        landmark_id=data["landmark_id"].astype(np.int64),
        pixel=data["pixel"].astype(float),
        pixel_clean=data.get("pixel_clean", data["pixel"]).astype(float),
        is_outlier=data["is_outlier"].astype(bool),
        camera_names=camera_names,
        landmarks=landmarks.astype(float),
        timestamps=timestamps,
        rig=rig,
        camera_timestamps=camera_timestamps,
        association_id=association_id,
        landmark_body=None if landmark_body is None else landmark_body.astype(np.int64),
    )
