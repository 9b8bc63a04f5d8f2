"""Our dataset folder format (DESIGN section 5): writer and validating reader.

    rig.yaml           the rig (``ampc_vo.rig``)
    frames.csv         frame, timestamp, then one image path per camera (relative to the folder;
                       empty when the dataset has no images, e.g. bearing measurements only)
    images/<camera>/<frame:06d>.png
    groundtruth.csv    optional: timestamp, tractor_x, tractor_y, tractor_z, tractor_qx, tractor_qy,
                       tractor_qz, tractor_qw, trailer_x, ..., trailer_qw, hitch_angle (radians)
    measurements.npz   optional simulated tracks (``ampc_vo.io.measurements``)

:func:`read_dataset` checks everything up front and raises :class:`DatasetError` naming the file and
the problem: missing files, missing images, (optionally) undecodable images, timestamps not
strictly increasing, image columns that do not match the rig's cameras, ground truth that does not
match the frames.
"""
from __future__ import annotations

import csv
import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ampc_vo.errors import ConfigError, DatasetError
from ampc_vo.geometry import ROTATION_TOLERANCE, pose_from_xyz_quat, pose_to_xyz_quat
from ampc_vo.io.frame_times import check_frame_times
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.io.measurements import MEASUREMENTS_FILE, Measurements, load_measurements, save_measurements
from ampc_vo.rig import Rig, load_rig, save_rig

LOGGER = logging.getLogger(__name__)

RIG_FILE = "rig.yaml"
FRAMES_FILE = "frames.csv"
GROUNDTRUTH_FILE = "groundtruth.csv"
IMAGES_DIR = "images"
POSE_FIELDS = ("x", "y", "z", "qx", "qy", "qz", "qw")
GROUNDTRUTH_COLUMNS = ("timestamp",) + tuple(f"tractor_{name}" for name in POSE_FIELDS) + tuple(f"trailer_{name}" for name in POSE_FIELDS) + ("hitch_angle",)
CAMERA_TIMESTAMP_SUFFIX = "_timestamp"
MAX_CAMERA_OFFSET_S = 0.5  # a camera's capture time this far from the frame's timestamp is an error
TIMESTAMP_TOLERANCE = 1e-6  # seconds: ground truth and frame timestamps must agree to this


def image_relative_path(camera: str, frame: int) -> str:
    """``images/<camera>/<frame:06d>.png`` (relative to the dataset folder)."""
    return f"{IMAGES_DIR}/{camera}/{frame:06d}.png"


# ---------------------------------------------------------------------- writer
def camera_timestamp_column(camera: str) -> str:
    """The frames.csv column of one camera's capture times (DESIGN section 5)."""
    return f"{camera}{CAMERA_TIMESTAMP_SUFFIX}"


def write_frames_csv(path: Path, camera_names: list[str], timestamps: np.ndarray, with_images: bool,
                     camera_timestamps: dict[str, np.ndarray] | None = None) -> None:
    """``frame, timestamp, <camera>..., [<camera>_timestamp...]``: the per-camera capture times only
    for the cameras in ``camera_timestamps`` (the others use ``timestamp``)."""
    stamped = [name for name in camera_names if camera_timestamps and name in camera_timestamps]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["frame", "timestamp", *camera_names, *(camera_timestamp_column(name) for name in stamped)])
        for frame, timestamp in enumerate(timestamps):
            paths = [image_relative_path(name, frame) if with_images else "" for name in camera_names]
            times = [repr(float(camera_timestamps[name][frame])) for name in stamped]
            writer.writerow([frame, repr(float(timestamp)), *paths, *times])


def write_groundtruth_csv(path: Path, trajectory: Trajectory) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(GROUNDTRUTH_COLUMNS)
        for index in range(len(trajectory)):
            row = [trajectory.timestamps[index], *pose_to_xyz_quat(trajectory.T_world_tractor[index]),
                   *pose_to_xyz_quat(trajectory.T_world_trailer[index]), trajectory.hitch_angle[index]]
            writer.writerow([repr(float(value)) for value in row])


def write_dataset(
    root: str | Path,
    rig: Rig,
    timestamps: np.ndarray,
    groundtruth: Trajectory | None = None,
    measurements: Measurements | None = None,
    with_images: bool = False,
    camera_timestamps: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write ``rig.yaml``, ``frames.csv`` and, if given, ``groundtruth.csv`` and ``measurements.npz``.

    With ``with_images`` the frames table lists ``images/<camera>/<frame:06d>.png`` (the images
    themselves are written by the renderer or the caller); otherwise the image columns are empty.
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    timestamps = np.asarray(timestamps, dtype=float)
    save_rig(rig, root / RIG_FILE)
    if groundtruth is not None:
        if len(groundtruth) != len(timestamps):
            raise DatasetError(f"{root / GROUNDTRUTH_FILE}: ground truth has {len(groundtruth)} rows but there are {len(timestamps)} frames")
        write_groundtruth_csv(root / GROUNDTRUTH_FILE, groundtruth)
    if measurements is not None:
        save_measurements(measurements, root / MEASUREMENTS_FILE)
    write_frames_csv(root / FRAMES_FILE, rig.camera_names, timestamps, with_images, camera_timestamps)
    return root


# ---------------------------------------------------------------------- reader
@dataclass(frozen=True)
class Dataset:
    """A validated dataset folder. ``image_paths`` is (F, C) of relative paths ('' when none)."""

    root: Path
    rig: Rig
    frames: np.ndarray
    timestamps: np.ndarray
    camera_names: tuple[str, ...]
    image_paths: np.ndarray
    groundtruth: Trajectory | None
    measurements: Measurements | None
    # capture time of each camera's image per frame (F,), from the ``<camera>_timestamp`` columns;
    # a camera without its column uses ``timestamps``
    camera_timestamps: dict[str, np.ndarray] = field(default_factory=dict)

    def camera_timestamp(self, frame: int, camera: str) -> float:
        """When ``camera``'s image of ``frame`` was captured (seconds)."""
        times = self.camera_timestamps.get(camera)
        return float(self.timestamps[frame] if times is None else times[frame])

    @property
    def has_images(self) -> bool:
        return bool(self.image_paths.size) and bool(np.all(self.image_paths != ""))

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def image_path(self, frame: int, camera: str) -> Path:
        """Absolute path of one image; :class:`DatasetError` if the dataset has no images."""
        if camera not in self.camera_names:
            raise DatasetError(f"{self.root / FRAMES_FILE}: no camera named {camera!r} (cameras: {list(self.camera_names)})")
        if not 0 <= frame < len(self):
            raise DatasetError(f"{self.root / FRAMES_FILE}: frame {frame} out of range [0, {len(self)})")
        relative = self.image_paths[frame, self.camera_names.index(camera)]
        if not relative:
            raise DatasetError(f"{self.root / FRAMES_FILE}: dataset has no image for frame {frame}, camera {camera!r}")
        return self.root / relative

    def load_image(self, frame: int, camera: str) -> np.ndarray:
        """The grey ``uint8`` image of one camera at one frame; :class:`DatasetError` if unreadable
        or if its size differs from the rig's ``width`` x ``height`` for that camera."""
        path = self.image_path(frame, camera)
        image = decode_image(path)
        _check_size(path, image, self.rig.camera(camera))
        return image


def _check_size(path: Path, image: np.ndarray, camera) -> None:
    if image.shape[:2] != (camera.height, camera.width):
        raise DatasetError(f"{path}: image is {image.shape[1]}x{image.shape[0]} but rig.yaml says camera {camera.name!r} is {camera.width}x{camera.height}")


def _check_first_images(root: Path, rig: Rig, camera_names: tuple[str, ...], image_paths: np.ndarray) -> None:
    """The first readable image of each camera (decoded once, as stored) must have the rig's size:
    a whole camera of the wrong size (another rig.yaml, resized images) is an error up front, not a
    warning at every frame; a low bit depth is a warning (:func:`_warn_if_low_bit_depth`). Missing
    or corrupt images are left to the run (it skips them)."""
    import cv2

    for column, name in enumerate(camera_names):
        for relative in image_paths[:, column]:
            stored = cv2.imread(str(root / relative), cv2.IMREAD_UNCHANGED)
            if stored is None or stored.size == 0:
                continue
            _check_size(root / relative, stored, rig.camera(name))
            _warn_if_low_bit_depth(root / relative, stored)
            break


def _warn_if_low_bit_depth(path: Path, stored: np.ndarray) -> None:
    """A 16-bit image holding 8 to 12 bit data (machine-vision cameras) keeps only its top byte when
    read as 8 bit: at most 16 grey levels, tracking degrades without an error. Say so once."""
    if stored.dtype == np.uint16 and 0 < int(stored.max()) < 4096:
        LOGGER.warning("%s: 16-bit image whose values stay below 4096 (12-bit data?): read as 8 bit it keeps at most "
                       "16 grey levels; store 8-bit images (value / 16 for 12-bit data)", path)


def decode_image(path: Path) -> np.ndarray:
    """Read an image as grey ``uint8``; a missing or undecodable file raises :class:`DatasetError`."""
    import cv2

    if not path.is_file():
        raise DatasetError(f"{path}: image file missing")
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None or image.size == 0:
        raise DatasetError(f"{path}: image cannot be decoded (corrupt or not an image)")
    return image


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    if not path.is_file():
        raise DatasetError(f"{path}: file missing")
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:  # -sig: a byte-order mark (spreadsheet export) is not part of the header
            rows = [row for row in csv.reader(handle) if row]
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise DatasetError(f"{path}: cannot read CSV ({error})") from None
    if not rows:
        raise DatasetError(f"{path}: empty file (expected a header line)")
    return [name.strip() for name in rows[0]], rows[1:]


def _floats(path: Path, rows: list[list[str]], columns: slice, line_offset: int = 2) -> np.ndarray:
    try:
        return np.array([[float(value) for value in row[columns]] for row in rows], dtype=float).reshape(len(rows), -1)
    except ValueError as error:
        for number, row in enumerate(rows):
            try:
                [float(value) for value in row[columns]]
            except ValueError:
                raise DatasetError(f"{path}: line {number + line_offset}: not a number ({error})") from None
        raise DatasetError(f"{path}: not a number ({error})") from None


def _check_inside(path: Path, image_paths: np.ndarray, camera_names: tuple[str, ...]) -> None:
    """Image paths are relative to the dataset folder and stay inside it (no absolute path, no
    ``..`` out of it): a frames.csv must not make the odometry open other files."""
    for (row, column), relative in np.ndenumerate(image_paths):
        if not relative:
            continue
        parts = Path(relative).parts
        depth = 0
        for part in parts:
            depth += -1 if part == ".." else (0 if part == "." else 1)
            if depth < 0:
                break
        if Path(relative).is_absolute() or relative.startswith(("/", "\\")) or (len(relative) > 1 and relative[1] == ":") or depth < 0:
            raise DatasetError(f"{path}: line {row + 2}: image path {relative!r} of camera {camera_names[column]!r} leaves the dataset folder "
                               "(image paths are relative to it, without '..' above it)")


def _read_frames(path: Path, rig: Rig) -> tuple[np.ndarray, np.ndarray, tuple[str, ...], np.ndarray, dict[str, np.ndarray]]:
    header, rows = _read_csv(path)
    if header[:2] != ["frame", "timestamp"]:
        raise DatasetError(f"{path}: header must start with 'frame,timestamp', got {','.join(header[:2])!r}")
    time_columns = {name.removesuffix(CAMERA_TIMESTAMP_SUFFIX): index for index, name in enumerate(header)
                    if index >= 2 and name.endswith(CAMERA_TIMESTAMP_SUFFIX) and name.removesuffix(CAMERA_TIMESTAMP_SUFFIX) in rig.camera_names}
    image_columns = [index for index in range(2, len(header)) if index not in time_columns.values()]
    camera_names = tuple(header[index] for index in image_columns)
    if sorted(camera_names) != sorted(rig.camera_names) or len(set(camera_names)) != len(camera_names):
        raise DatasetError(f"{path}: camera columns {list(camera_names)} do not match the rig's cameras {rig.camera_names}"
                           f" (optional capture-time columns: <camera>{CAMERA_TIMESTAMP_SUFFIX})")
    if not rows:
        raise DatasetError(f"{path}: no frames")
    for number, row in enumerate(rows):
        if len(row) != len(header):
            raise DatasetError(f"{path}: line {number + 2}: expected {len(header)} columns, got {len(row)}")
    values = _floats(path, rows, slice(0, 2))
    frames = values[:, 0]
    wrong = np.flatnonzero(frames != np.arange(len(frames)))
    if len(wrong):  # the frame number is the row: measurements.npz, --start/--stop and outputs refer to it
        index = int(wrong[0])
        raise DatasetError(f"{path}: line {index + 2}: frame {values[index, 0]:g}, expected {index} (frames are numbered 0, 1, 2, ... in row order; "
                           f"{'a duplicate' if values[index, 0] in frames[:index] else 'a gap or reordering'})")
    timestamps = values[:, 1]
    if not np.all(np.isfinite(timestamps)):
        raise DatasetError(f"{path}: timestamps must be finite")
    decreasing = np.flatnonzero(np.diff(timestamps) <= 0.0)
    if len(decreasing):
        line = int(decreasing[0]) + 3
        raise DatasetError(f"{path}: timestamps not strictly increasing at line {line} ({timestamps[decreasing[0]]} then {timestamps[decreasing[0] + 1]})")
    check_frame_times(timestamps, f"{path}: timestamp", line_offset=2)
    image_paths = np.array([[row[index].strip() for index in image_columns] for row in rows], dtype=object).reshape(len(rows), len(camera_names))
    _check_inside(path, image_paths, camera_names)
    camera_timestamps = {}
    for camera, index in time_columns.items():
        times = _floats(path, rows, slice(index, index + 1))[:, 0]
        column = header[index]
        if not np.all(np.isfinite(times)):
            raise DatasetError(f"{path}: {column}: capture times must be finite")
        offset = np.abs(times - timestamps)
        if np.any(offset > MAX_CAMERA_OFFSET_S):
            line = int(np.argmax(offset)) + 2
            raise DatasetError(f"{path}: line {line}: {column} is {offset.max():.3f} s from the frame's timestamp "
                               f"(more than {MAX_CAMERA_OFFSET_S} s: wrong unit or clock?)")
        if np.any(np.diff(times) <= 0.0):
            raise DatasetError(f"{path}: {column}: capture times not strictly increasing")
        camera_timestamps[camera] = times
    return frames.astype(np.int64), timestamps, camera_names, image_paths, camera_timestamps


def _read_groundtruth(path: Path, timestamps: np.ndarray) -> Trajectory:
    header, rows = _read_csv(path)
    if tuple(header) != GROUNDTRUTH_COLUMNS:
        raise DatasetError(f"{path}: header must be {','.join(GROUNDTRUTH_COLUMNS)}; got {','.join(header)}")
    for number, row in enumerate(rows):
        if len(row) != len(GROUNDTRUTH_COLUMNS):
            raise DatasetError(f"{path}: line {number + 2}: expected {len(GROUNDTRUTH_COLUMNS)} columns, got {len(row)}")
    values = _floats(path, rows, slice(None))
    if len(values) != len(timestamps):
        raise DatasetError(f"{path}: {len(values)} rows but frames.csv has {len(timestamps)} frames (they must match one to one)")
    mismatch = np.flatnonzero(np.abs(values[:, 0] - timestamps) > TIMESTAMP_TOLERANCE)
    if len(mismatch):
        index = int(mismatch[0])
        raise DatasetError(f"{path}: line {index + 2}: timestamp {values[index, 0]} does not match frames.csv timestamp {timestamps[index]}")
    if not np.all(np.isfinite(values)):
        raise DatasetError(f"{path}: contains NaN or infinite values")
    for body, start in (("tractor", 4), ("trailer", 11)):
        norms = np.linalg.norm(values[:, start:start + 4], axis=1)
        bad = np.flatnonzero(np.abs(norms - 1.0) > ROTATION_TOLERANCE)
        if len(bad):
            raise DatasetError(f"{path}: line {int(bad[0]) + 2}: {body} quaternion is not unit length (norm {norms[bad[0]]:.6f})")
    T_world_tractor = np.stack([pose_from_xyz_quat(row[1:8]) for row in values])
    T_world_trailer = np.stack([pose_from_xyz_quat(row[8:15]) for row in values])
    return Trajectory(values[:, 0].copy(), T_world_tractor, T_world_trailer, values[:, 15].copy())


def _with_frame_timestamps(path: Path, measurements: Measurements, timestamps: np.ndarray) -> Measurements:
    """The measurements with frames.csv's timestamps (the bearing source runs on the measurements'
    own ones): taken over when the file has none (frame indices by default), else they must agree."""
    mismatch = np.flatnonzero(np.abs(measurements.timestamps - timestamps) > TIMESTAMP_TOLERANCE)
    if not len(mismatch):
        return measurements
    if np.array_equal(measurements.timestamps, np.arange(len(timestamps), dtype=float)):
        LOGGER.info("%s: no timestamps in the file: using those of %s", path, FRAMES_FILE)
        return dataclasses.replace(measurements, timestamps=timestamps.copy())
    index = int(mismatch[0])
    raise DatasetError(f"{path}: frame {index}: timestamp {measurements.timestamps[index]} does not match {FRAMES_FILE} timestamp {timestamps[index]} "
                       f"({len(mismatch)} frames differ)")


def read_dataset(root: str | Path, check_images: bool = False, load_measurements_file: bool = True, allow_missing_images: bool = False,
                 image_files: bool = True) -> Dataset:
    """Open and validate a dataset folder (module docstring).

    Always checks that every listed image exists: a missing one is an error, or with
    ``allow_missing_images`` a warning (the odometry then logs and skips that camera at that frame;
    more than half of them missing is still an error). With ``check_images`` also decodes every image
    and checks its size against the rig (slow on long sequences); without, only the first readable
    image of each camera. A dataset whose image columns are all empty, or whose ``images/``
    folder is absent, has no images (``has_images`` is False, e.g. bearing measurements only);
    partially empty image columns are an error. With ``image_files=False`` the image files are not
    looked at at all (for readers of the ground truth only, e.g. the evaluation of a run that skipped
    a missing image).
    """
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder not found")
    rig_path = root / RIG_FILE
    if not rig_path.is_file():
        from ampc_vo.io.kitti import incomplete_kitti_folder

        kitti_problem = incomplete_kitti_folder(root)
        if kitti_problem:
            raise DatasetError(f"{root}: looks like a KITTI odometry folder but has {kitti_problem} (a KITTI folder needs calib.txt, "
                               "image_l/ and image_r/ or image_0/ and image_1/; a dataset folder needs rig.yaml)")
        raise DatasetError(f"{rig_path}: file missing (every dataset needs a rig.yaml)")
    try:
        rig = load_rig(rig_path)
    except ConfigError as error:
        raise DatasetError(str(error)) from None
    frames_path = root / FRAMES_FILE
    frames, timestamps, camera_names, image_paths, camera_timestamps = _read_frames(frames_path, rig)
    empty = image_paths == ""
    if image_files and not np.all(empty) and not (root / IMAGES_DIR).is_dir():
        LOGGER.warning("%s: frames.csv lists images but %s/ is absent: reading as a dataset without images", root, IMAGES_DIR)
        image_paths = np.full(image_paths.shape, "", dtype=object)
        empty = image_paths == ""
    if np.any(empty) and not np.all(empty):
        frame, column = np.argwhere(empty)[0]
        raise DatasetError(f"{frames_path}: line {frame + 2}: image path for camera {camera_names[column]!r} is empty while other frames have images")
    if image_files and not np.all(empty):
        missing = [path for path in image_paths.ravel() if not (root / path).is_file()]
        if missing:
            message = f"{root / missing[0]}: image file missing (listed in {frames_path}; {len(missing)} missing in total)"
            if not allow_missing_images or len(missing) > image_paths.size // 2:
                raise DatasetError(message)
            LOGGER.warning("%s: those cameras are skipped at those frames", message)
        if check_images:
            for row in image_paths:
                for name, path in zip(camera_names, row):
                    _check_size(root / path, decode_image(root / path), rig.camera(name))
        else:
            _check_first_images(root, rig, camera_names, image_paths)
    groundtruth_path = root / GROUNDTRUTH_FILE
    groundtruth = _read_groundtruth(groundtruth_path, timestamps) if groundtruth_path.is_file() else None
    measurements = None
    measurements_path = root / MEASUREMENTS_FILE
    if load_measurements_file and measurements_path.is_file():
        measurements = load_measurements(measurements_path, rig)
        if measurements.frame_count != len(timestamps):
            raise DatasetError(f"{measurements_path}: {measurements.frame_count} frames but frames.csv has {len(timestamps)}")
        measurements = _with_frame_timestamps(measurements_path, measurements, timestamps)
    LOGGER.info("dataset %s: %d frames, cameras %s, images %s", root, len(timestamps), list(camera_names), not np.all(empty))
    return Dataset(root, rig, frames, timestamps, camera_names, image_paths, groundtruth, measurements, camera_timestamps)
