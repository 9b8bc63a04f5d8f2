"""KITTI odometry folders read as a rigid two-camera tractor without a trailer (DESIGN sections 5, 8).

A folder holds ``calib.txt`` (the rectified projection matrices P0, P1, as ``P0: ...`` lines or two
bare rows of 12 numbers), ``poses.txt`` (optional: one 3x4 ``[R|t]`` row per frame, the left camera
in the first left-camera frame, camera axes), ``times.txt`` (optional: seconds per frame, else 10 Hz)
and the grey images in ``image_l/`` and ``image_r/`` (KITTI's own names ``image_0/`` and ``image_1/``
are accepted too).

Body frame (DESIGN 1): x forward, y left, z up, origin at a configurable point (default: on the
ground below the left camera, which is 1.65 m high on the KITTI car). The cameras look forward:
``R_body_camera = camera_rotation(0, 0)``; the right camera sits ``baseline`` metres along the left
camera's x axis (to the right, i.e. body -y), from P1. Ground truth becomes ``T_world_tractor`` with
the world frame = the body frame at the first frame (z up, as far as the car's camera is level).
Evaluation compares poses in KITTI's own frame, the left camera (``GroundTruth.T_tractor_reference``).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from ampc_vo.io.frame_images import load_frame_images
from ampc_vo.io.frame_times import check_frame_times
from ampc_vo.errors import DatasetError
from ampc_vo.geometry import ROTATION_TOLERANCE, invert_pose, make_pose, nearest_rotation
from ampc_vo.rig import Body, Camera, Rig, calibration_warnings, camera_rotation, rig_problem

if TYPE_CHECKING:  # evaluation (evo, SciPy) is not imported by the frontend's worker process
    from ampc_vo.io.groundtruth import GroundTruth

logger = logging.getLogger(__name__)

LEFT, RIGHT = "left", "right"
IMAGE_FOLDERS = {LEFT: ("image_l", "image_0"), RIGHT: ("image_r", "image_1")}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm")
DEFAULT_FRAME_RATE_HZ = 10.0
# Left camera height above the road and its position relative to the rear axle on the KITTI car
# (KITTI setup sheet: cameras 1.65 m high, about 0.27 m ahead of the Velodyne, which is about 0.81 m
# ahead of the GPS/IMU mounted over the rear axle). Override with KittiOptions.axle_x, or estimate it
# from ground truth with scripts/estimate_axle_offset.py.
KITTI_CAMERA_HEIGHT_M = 1.65
KITTI_CAMERA_AHEAD_OF_AXLE_M = 1.08
# a stereo baseline outside this range is no car's (KITTI: 0.54 m): a unit or sign mistake in calib.txt
MIN_BASELINE_M, MAX_BASELINE_M = 0.02, 5.0


@dataclass(frozen=True)
class KittiOptions:
    """How to read a KITTI folder as a rig.

    ``left_camera_position``: the left camera centre in the body frame (metres, x fwd, y left, z up);
    it fixes where the body origin is. ``axle_x``: the rear axle midpoint's x in the body frame.
    """

    left_camera_position: tuple[float, float, float] = (0.0, 0.0, KITTI_CAMERA_HEIGHT_M)
    axle_x: float = -KITTI_CAMERA_AHEAD_OF_AXLE_M
    frame_rate_hz: float = DEFAULT_FRAME_RATE_HZ


def is_kitti_folder(path: str | Path) -> bool:
    """True if ``path`` has ``calib.txt`` and a left and a right image folder (KITTI odometry layout)."""
    path = Path(path)
    if not (path / "calib.txt").is_file():
        return False
    return all(any((path / name).is_dir() for name in names) for names in IMAGE_FOLDERS.values())


def incomplete_kitti_folder(path: str | Path) -> str | None:
    """What a folder with some of the KITTI layout (``calib.txt``, an image folder) lacks to be a
    KITTI folder, e.g. ``"no calib.txt"``, or ``None`` when it has none of it or all of it."""
    path = Path(path)
    has_calibration = (path / "calib.txt").is_file()
    present = {camera: any((path / name).is_dir() for name in names) for camera, names in IMAGE_FOLDERS.items()}
    if not has_calibration and not any(present.values()):
        return None
    missing = ([] if has_calibration else ["calib.txt"]) + [f"{' or '.join(IMAGE_FOLDERS[camera])}/" for camera, found in present.items() if not found]
    return None if not missing else "no " + " and no ".join(missing)


# ---------------------------------------------------------------------- file parsing
def read_calibration(path: str | Path) -> dict[str, np.ndarray]:
    """Projection matrices (3, 4) by name (``P0``, ``P1``, ...) from a KITTI ``calib.txt``.

    Lines ``NAME: 12 numbers`` keep their names; bare rows of 12 numbers are named P0, P1, ... in order.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: calibration file not found")
    matrices: dict[str, np.ndarray] = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        name, _, values = line.partition(":") if ":" in line else (f"P{len(matrices)}", "", line)
        try:
            row = np.array([float(value) for value in values.split()])
        except ValueError:
            raise DatasetError(f"{path}:{number}: expected numbers, got {line.strip()[:60]!r}") from None
        if row.size != 12:
            if name.strip().startswith("P"):
                raise DatasetError(f"{path}:{number}: {name.strip()} needs 12 numbers (a 3x4 matrix), got {row.size}")
            continue  # other calibration entries (Tr, ...) are not used
        matrices[name.strip()] = row.reshape(3, 4)
    for name in ("P0", "P1"):
        if name not in matrices:
            raise DatasetError(f"{path}: no {name} projection matrix (found {sorted(matrices)})")
        if not np.all(np.isfinite(matrices[name])) or matrices[name][0, 0] <= 0 or matrices[name][1, 1] <= 0:
            raise DatasetError(f"{path}: {name} is not a valid projection matrix")
    return matrices


def read_poses(path: str | Path) -> np.ndarray:
    """(N, 4, 4) poses from a KITTI ``poses.txt`` (one row of 12 numbers per frame)."""
    path = Path(path)
    try:
        if not path.read_text().strip():
            raise DatasetError(f"{path}: no poses (empty file)")
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as error:
        raise DatasetError(f"{path}: unreadable poses file ({error})") from None
    if rows.shape[1] != 12:
        raise DatasetError(f"{path}: expected 12 numbers per line (3x4 [R|t]), got {rows.shape[1]}")
    if not np.all(np.isfinite(rows)):
        raise DatasetError(f"{path}: poses contain NaN or infinite values")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    orthogonality = np.abs(np.einsum("nji,njk->nik", poses[:, :3, :3], poses[:, :3, :3]) - np.eye(3)).max()
    if orthogonality > ROTATION_TOLERANCE:
        raise DatasetError(f"{path}: rotation parts are not orthonormal (error {orthogonality:.2g})")
    poses[:, :3, :3] = [nearest_rotation(rotation) for rotation in poses[:, :3, :3]]  # KITTI's rows are rounded
    return poses


def _image_files(root: Path, camera: str) -> tuple[Path, list[Path]]:
    for name in IMAGE_FOLDERS[camera]:
        folder = root / name
        if folder.is_dir():
            files = sorted(file for file in folder.iterdir() if file.suffix.lower() in IMAGE_SUFFIXES)
            if not files:
                raise DatasetError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
            return folder, files
    raise DatasetError(f"{root}: no {camera} image folder (expected one of {', '.join(IMAGE_FOLDERS[camera])})")


def _first_image_shape(files: list[Path]) -> tuple[tuple[int, int], Path]:
    """(height, width) of the first readable image and its path (unreadable ones are skipped at
    run time, so one corrupt first image does not stop the run)."""
    for path in files:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is not None:
            return image.shape, path
    raise DatasetError(f"{files[0].parent}: no readable image")


def _intrinsics(projection: np.ndarray) -> tuple[float, float, float, float, np.ndarray]:
    """fx, fy, cx, cy and the camera centre (rectified left-camera axes) of ``P = K [I | t]``."""
    K = projection[:, :3]
    center = -np.linalg.solve(K, projection[:, 3])
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), center


def kitti_rig(calibration: dict[str, np.ndarray], width: int, height: int, options: KittiOptions | None = None) -> Rig:
    """The two-camera tractor rig (cameras ``left`` and ``right``, no trailer) of a KITTI calibration."""
    options = options or KittiOptions()
    R_body_camera = camera_rotation(0.0, 0.0)
    left_position = np.asarray(options.left_camera_position, dtype=float)
    cameras = []
    left_center = _intrinsics(calibration["P0"])[4]
    for name, key in ((LEFT, "P0"), (RIGHT, "P1")):
        fx, fy, cx, cy, center = _intrinsics(calibration[key])
        position = left_position + R_body_camera @ (center - left_center)
        cameras.append(Camera(name, "tractor", "pinhole", width, height, fx, fy, cx, cy, (), make_pose(R_body_camera, position)))
    return Rig(bodies={"tractor": Body("tractor", float(options.axle_x))}, cameras=tuple(cameras))


def check_stereo_calibration(path: Path, rig: Rig) -> None:
    """:class:`DatasetError` for a calibration no stereo rig can have (issue 14): impossible
    intrinsics (:func:`ampc_vo.rig.rig_problem`), a right camera that is not to the right of the left
    one (P1's sign flipped: KITTI's ``P1[0, 3] = -fx * baseline`` is negative), a baseline outside
    [``MIN_BASELINE_M``, ``MAX_BASELINE_M``] (a unit mistake); a pair that is not side by side
    (rectified cameras differ along x only) is a warning."""
    left, right = rig.camera(LEFT), rig.camera(RIGHT)
    offset = left.R_body_camera.T @ (right.center - left.center)  # in the left camera's axes: x right
    if offset[0] <= 0.0:
        raise DatasetError(f"{path}: P1 puts the right camera {abs(offset[0]):.3f} m to the left of the left camera "
                           "(sign of P1[0, 3] flipped? it is -fx * baseline, negative, in KITTI's calib.txt)")
    if not MIN_BASELINE_M <= offset[0] <= MAX_BASELINE_M:
        raise DatasetError(f"{path}: stereo baseline {offset[0]:.4g} m is outside [{MIN_BASELINE_M}, {MAX_BASELINE_M}] m "
                           "(P1[0, 3] = -fx * baseline in pixels times metres: a unit mistake?)")
    problem = rig_problem(rig)
    if problem:
        raise DatasetError(f"{path}: {problem}")
    for camera in rig.cameras:
        for warning in calibration_warnings(camera):
            logger.warning("%s: camera %s: %s", path, camera.name, warning)
    if np.hypot(offset[1], offset[2]) > 0.1 * offset[0]:
        logger.warning("%s: the right camera is %.3f m off the left camera's x axis (rectified pairs differ along x only): stereo matching will fail",
                       path, float(np.hypot(offset[1], offset[2])))


# ---------------------------------------------------------------------- the dataset
@dataclass
class KittiDataset:
    """A KITTI odometry folder: rig, timestamps, image paths and ground truth (if ``poses.txt``).

    Same access methods as :class:`ampc_vo.io.folder.Dataset` (``len``, ``camera_names``,
    ``frames``, ``timestamps``, ``image_path(frame, camera)``, ``load_image(frame, camera)``), plus
    :meth:`images` (missing images as ``None``) and :attr:`truth` for the evaluation. ``groundtruth``
    and ``measurements`` are ``None``: there is no trailer truth and no simulated bearings.
    """

    root: Path
    rig: Rig
    timestamps: np.ndarray
    image_paths: dict[str, list[Path]]
    T_world_tractor: np.ndarray | None = None          # (N, 4, 4) ground truth of the body
    T_world_left_camera: np.ndarray | None = None      # (N, 4, 4) KITTI's own ground truth (poses.txt)
    options: KittiOptions = field(default_factory=KittiOptions)

    groundtruth: None = None
    measurements: None = None

    @property
    def camera_names(self) -> tuple[str, ...]:
        return (LEFT, RIGHT)

    @property
    def frames(self) -> np.ndarray:
        return np.arange(len(self))

    @property
    def has_images(self) -> bool:
        return True

    def __len__(self) -> int:
        return int(len(self.timestamps))

    @property
    def T_body_left_camera(self) -> np.ndarray:
        return self.rig.camera(LEFT).T_body_camera

    @property
    def truth(self) -> GroundTruth | None:
        """Ground truth for :func:`ampc_vo.tools.evaluation.evaluate` (tractor only), or ``None``; poses are
        compared in the frame of KITTI's ground truth, the left camera (``T_tractor_reference``)."""
        if self.T_world_tractor is None:
            return None
        from ampc_vo.io.groundtruth import GroundTruth

        return GroundTruth(timestamps=self.timestamps.copy(), T_world_tractor=self.T_world_tractor.copy(), T_tractor_reference=self.T_body_left_camera.copy())

    def image_path(self, frame: int, camera: str) -> Path:
        if camera not in self.image_paths:
            raise DatasetError(f"{self.root}: no camera {camera!r} (cameras: {list(self.camera_names)})")
        paths = self.image_paths[camera]
        if not 0 <= frame < len(paths):
            raise DatasetError(f"{self.root}: camera {camera} has {len(paths)} images, no frame {frame}")
        return paths[frame]

    def load_image(self, frame: int, camera: str) -> np.ndarray:
        """The grey uint8 image of ``camera`` at ``frame``; :class:`DatasetError` if missing or corrupt."""
        path = self.image_path(frame, camera)
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise DatasetError(f"{path}: missing or unreadable image")
        calibrated = self.rig.camera(camera)
        if image.shape != (calibrated.height, calibrated.width):
            raise DatasetError(f"{path}: image is {image.shape[1]}x{image.shape[0]}, expected {calibrated.width}x{calibrated.height}")
        return image

    def images(self, frame: int) -> dict[str, np.ndarray | None]:
        """All cameras' images at ``frame``; a missing or corrupt one is ``None`` with a warning
        (the frontend then re-initialises that camera instead of stopping the run)."""
        return load_frame_images(self, frame)


def camera_poses(T_world_body: np.ndarray, T_body_camera: np.ndarray) -> np.ndarray:
    """Poses of a camera (N, 4, 4) from body poses: ``T_world_camera = T_world_body T_body_camera``
    (evaluation in KITTI's left-camera frame after an SE(3) alignment)."""
    return np.asarray(T_world_body) @ T_body_camera


def body_poses_from_camera(T_camera0_camera: np.ndarray, T_body_camera: np.ndarray) -> np.ndarray:
    """Body poses in the world = first body frame from camera poses in the first camera frame:
    ``T_world_body_k = T_body_camera T_camera0_camera_k T_camera_body``."""
    return T_body_camera @ np.asarray(T_camera0_camera) @ invert_pose(T_body_camera)


def load_kitti_truth(path: str | Path, options: KittiOptions | None = None) -> GroundTruth:
    """Ground truth (``T_world_tractor`` of the body) of a KITTI folder; :class:`DatasetError` without ``poses.txt``."""
    truth = load_kitti(path, options).truth
    if truth is None:
        raise DatasetError(f"{path}: KITTI folder has no poses.txt (no ground truth)")
    return truth


def load_kitti(path: str | Path, options: KittiOptions | None = None) -> KittiDataset:
    """Open a KITTI odometry folder (see the module docstring); :class:`DatasetError` if malformed."""
    root = Path(path)
    options = options or KittiOptions()
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder not found")
    calibration = read_calibration(root / "calib.txt")
    image_paths = {camera: _image_files(root, camera)[1] for camera in (LEFT, RIGHT)}
    counts = {camera: len(paths) for camera, paths in image_paths.items()}
    frames = max(counts.values())
    if len(set(counts.values())) > 1:
        logger.warning("%s: cameras have different numbers of images %s; missing frames are skipped for that camera", root, counts)
    (height, width), left_path = _first_image_shape(image_paths[LEFT])
    (right_height, right_width), right_path = _first_image_shape(image_paths[RIGHT])
    if (right_height, right_width) != (height, width):
        raise DatasetError(f"{right_path}: image is {right_width}x{right_height} but {left_path} is {width}x{height} (a rectified stereo pair has one size)")
    rig = kitti_rig(calibration, width, height, options)
    check_stereo_calibration(root / "calib.txt", rig)

    times_path = root / "times.txt"
    if times_path.is_file():
        try:
            timestamps = np.loadtxt(times_path, ndmin=1).astype(float)
        except ValueError as error:
            raise DatasetError(f"{times_path}: unreadable ({error})") from None
        if timestamps.ndim != 1:
            raise DatasetError(f"{times_path}: expected one time (seconds) per line, got {timestamps.shape[1]} numbers per line")
        if len(timestamps) != frames:
            raise DatasetError(f"{times_path}: {len(timestamps)} times for {frames} frames (the image folders)")
        bad = np.flatnonzero(~np.isfinite(timestamps[1:]) | ~(np.diff(timestamps) > 0)) + 1
        if not np.isfinite(timestamps[0]) or len(bad):
            line = 1 if not np.isfinite(timestamps[0]) else int(bad[0]) + 1
            raise DatasetError(f"{times_path}: line {line}: times must be finite and strictly increasing, got {timestamps[line - 1]}")
        check_frame_times(timestamps, str(times_path), line_offset=1)
    else:
        timestamps = np.arange(frames) / options.frame_rate_hz

    T_world_tractor = T_world_left = None
    poses_path = root / "poses.txt"
    if poses_path.is_file():
        T_world_left = read_poses(poses_path)
        if len(T_world_left) != frames:
            raise DatasetError(f"{poses_path}: {len(T_world_left)} poses for {frames} frames")
        T_world_tractor = body_poses_from_camera(T_world_left, rig.camera(LEFT).T_body_camera)
    dataset = KittiDataset(root, rig, timestamps, image_paths, T_world_tractor, T_world_left, options)
    logger.info("%s: KITTI folder, %d frames, baseline %.3f m", root, frames, float(np.linalg.norm(rig.camera(RIGHT).center - rig.camera(LEFT).center)))
    return dataset
