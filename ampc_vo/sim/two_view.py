"""Synthetic two-view problems of the articulated truck for tests and benchmarks (DESIGN section 2).

:func:`make_two_view_problem` draws (or takes) a rig, an articulated planar motion that satisfies
both non-holonomic constraints exactly, and per-camera intra-camera correspondences:

* tractor motion (Ackermann at the tractor axle ``m = (axle_x, 0, 0)``, DESIGN 2 (NH)):
  ``R = Rz(phi)``, ``t = rho u(phi/2) + (I - Rz(phi)) m``;
* hitch angles: ``w = Rz(-theta) t``, ``psi = 2 atan2(w_y, w_x + 2 s_B)``, ``theta' = theta + psi - phi``
  (closed-form trailer constraint, DESIGN 2);
* trailer motion (paper eqs. (3), (4)): ``R_B = Rz(theta)^T R Rz(theta')``, ``t_B = Rz(theta)^T t``.

Points are drawn in front of each camera (pixel uniform in the image, distance 3-40 m along the
ray), projected into both views, perturbed by Gaussian pixel noise and unprojected to unit bearings.
A fraction of correspondences is replaced by outliers (a random pixel in view j).

Pure numpy; the generator is deterministic given the ``numpy.random.Generator``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Union

import numpy as np

from ampc_vo.geometry import invert_pose, make_pose, rot_z, transform_points, unit_heading
from ampc_vo.rig import Body, Camera, Rig, camera_rotation

FloatOrRange = Union[float, tuple[float, float]]

_MIN_CAMERA_AXLE_OFFSET = 0.5  # |p_x| of random cameras, metres: keeps metric scale observable


@dataclass(frozen=True)
class CameraCorrespondences:
    """Correspondences of one camera between views i and j.

    ``bearings_i``/``bearings_j`` (N, 3): unit bearings in the camera frame (OpenCV axes);
    ``body_bearings_i``/``body_bearings_j`` (N, 3): the same rotated into the body frame
    (``R_body_camera @ bearing``); ``center`` (3,): camera centre in the body frame;
    ``inliers`` (N,) bool: False for synthetic outliers; ``points_i`` (N, 3): true points in the
    camera frame of view i (outliers keep the point whose view-j observation was replaced).
    """

    camera: Camera
    bearings_i: np.ndarray
    bearings_j: np.ndarray
    body_bearings_i: np.ndarray
    body_bearings_j: np.ndarray
    inliers: np.ndarray
    points_i: np.ndarray

    @property
    def body(self) -> str:
        return self.camera.body

    @property
    def center(self) -> np.ndarray:
        return self.camera.center

    def as_group(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(body_bearings_i, body_bearings_j, center)``: the per-camera group the solvers take."""
        return self.body_bearings_i, self.body_bearings_j, self.camera.center

    def __len__(self) -> int:
        return int(self.bearings_i.shape[0])


@dataclass(frozen=True)
class TwoViewProblem:
    """Ground truth and correspondences of one articulated two-view problem.

    ``T_i_j`` is the tractor motion (``p_i = R p_j + t``, paper ``R_AA'``, ``t_AA'``),
    ``T_trailer_i_j`` the trailer motion, ``hitch_angle_i``/``hitch_angle_j`` the hitch angles
    (``R_tractor_trailer = Rz(theta)``) in views i and j. ``trailer_yaw_change`` is
    ``psi = phi + theta' - theta`` and ``trailer_chord`` the chord of the trailer axle.
    """

    rig: Rig
    yaw_change: float
    chord: float
    T_i_j: np.ndarray
    hitch_angle_i: float
    hitch_angle_j: float
    trailer_yaw_change: float
    trailer_chord: float
    T_trailer_i_j: np.ndarray
    correspondences: tuple[CameraCorrespondences, ...]

    @property
    def tractor_axle_x(self) -> float:
        return self.rig.axle_x("tractor")

    @property
    def trailer_axle_x(self) -> float:
        return self.rig.axle_x("trailer")

    @property
    def hitch_translation(self) -> np.ndarray:
        """The tractor translation ``t`` (hitch centre displacement seen from tractor view i)."""
        return self.T_i_j[:3, 3]

    def on(self, body: str) -> list[CameraCorrespondences]:
        """Correspondences of the cameras on ``body`` ('tractor' or 'trailer')."""
        return [group for group in self.correspondences if group.body == body]

    def groups(self, body: str) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``[(body_bearings_i, body_bearings_j, center), ...]`` of the cameras on ``body``."""
        return [group.as_group() for group in self.on(body)]


# ---------------------------------------------------------------------- motion model
def ackermann_translation(yaw_change: float, chord: float, axle_x: float) -> np.ndarray:
    """Body translation of a planar arc with the axle midpoint moving on a circle (DESIGN 2 (NH)):
    ``t = rho u(phi/2) + (I - Rz(phi)) m`` with ``m = (axle_x, 0, 0)``."""
    axle = np.array([axle_x, 0.0, 0.0])
    return chord * unit_heading(0.5 * yaw_change) + axle - rot_z(yaw_change) @ axle


def trailer_yaw_change(hitch_angle_i: float, hitch_translation: np.ndarray, trailer_axle_x: float) -> float:
    """Closed-form trailer yaw change (DESIGN 2): ``w = Rz(-theta) t``, ``psi = 2 atan2(w_y, w_x + 2 s_B)``."""
    s_b = -trailer_axle_x
    w = rot_z(-hitch_angle_i) @ np.asarray(hitch_translation, dtype=float)
    return float(2.0 * np.arctan2(w[1], w[0] + 2.0 * s_b))


def articulated_motion(
    yaw_change: float, chord: float, hitch_angle_i: float, tractor_axle_x: float, trailer_axle_x: float
) -> dict[str, np.ndarray | float]:
    """Tractor and trailer motion consistent with both non-holonomic constraints.

    Returns ``T_i_j``, ``T_trailer_i_j``, ``hitch_angle_j``, ``trailer_yaw_change``, ``trailer_chord``.
    """
    translation = ackermann_translation(yaw_change, chord, tractor_axle_x)
    T_i_j = make_pose(rot_z(yaw_change), translation)
    psi = trailer_yaw_change(hitch_angle_i, translation, trailer_axle_x)
    hitch_angle_j = hitch_angle_i + psi - yaw_change
    # paper eqs. (3), (4): R_B = Q^T R Q', t_B = Q^T t
    R_trailer = rot_z(hitch_angle_i).T @ T_i_j[:3, :3] @ rot_z(hitch_angle_j)
    t_trailer = rot_z(hitch_angle_i).T @ translation
    axle = np.array([trailer_axle_x, 0.0, 0.0])
    displacement = R_trailer @ axle + t_trailer - axle
    trailer_chord = float(np.dot(unit_heading(0.5 * psi), displacement))
    return {
        "T_i_j": T_i_j,
        "T_trailer_i_j": make_pose(R_trailer, t_trailer),
        "hitch_angle_j": float(hitch_angle_j),
        "trailer_yaw_change": psi,
        "trailer_chord": trailer_chord,
    }


# ---------------------------------------------------------------------- rigs
def _pinhole(name: str, body: str, focal_px: float, image_size: tuple[int, int], T_body_camera: np.ndarray) -> Camera:
    width, height = image_size
    return Camera(
        name=name, body=body, model="pinhole", width=int(width), height=int(height),
        fx=float(focal_px), fy=float(focal_px), cx=0.5 * width - 0.5, cy=0.5 * height - 0.5,
        distortion=(), T_body_camera=T_body_camera,
    )


def _offset_x(rng: np.random.Generator, low: float, high: float, axle_x: float) -> float:
    """Uniform x in [low, high] at least ``_MIN_CAMERA_AXLE_OFFSET`` away from the axle."""
    for _ in range(100):
        x = float(rng.uniform(low, high))
        if abs(x - axle_x) >= _MIN_CAMERA_AXLE_OFFSET:
            return x
    return axle_x + _MIN_CAMERA_AXLE_OFFSET * (1.0 if high > axle_x else -1.0)


def random_rig(
    rng: np.random.Generator,
    *,
    n_tractor_cameras: int = 1,
    n_trailer_cameras: int = 1,
    focal_px: float = 700.0,
    image_size: tuple[int, int] = (640, 480),
    tractor_axle_x: FloatOrRange = (0.0, 1.0),
    trailer_axle_x: FloatOrRange = (-10.0, -6.0),
) -> Rig:
    """A random truck rig: tractor cameras front then side, trailer cameras rear then side.

    Camera positions are random with ``|c_x - axle_x| >= 0.5 m`` (metric scale observable,
    DESIGN 2.1); orientations point roughly forward/sideways/backward with a random downward pitch.
    """
    tractor_axle = _draw(rng, tractor_axle_x)
    trailer_axle = _draw(rng, trailer_axle_x)
    cameras: list[Camera] = []
    side = float(rng.choice([-1.0, 1.0]))
    for index in range(n_tractor_cameras):
        pitch = rng.uniform(0.0, 0.3)
        if index == 0:  # front
            center = [_offset_x(rng, 2.0, 6.0, tractor_axle), rng.uniform(-1.0, 1.0), rng.uniform(1.5, 3.0)]
            yaw = rng.uniform(-0.3, 0.3)
        else:  # sides, alternating
            side = -side
            center = [_offset_x(rng, 1.0, 5.0, tractor_axle), 1.3 * side, rng.uniform(1.5, 3.0)]
            yaw = side * np.pi / 2 + rng.uniform(-0.3, 0.3)
        cameras.append(_pinhole(f"tractor_{index}", "tractor", focal_px, image_size, make_pose(camera_rotation(yaw, pitch), np.array(center))))
    for index in range(n_trailer_cameras):
        pitch = rng.uniform(0.0, 0.3)
        if index == 0:  # rear
            center = [trailer_axle - rng.uniform(1.0, 6.0), rng.uniform(-1.0, 1.0), rng.uniform(2.0, 3.5)]
            yaw = np.pi + rng.uniform(-0.3, 0.3)
        else:
            side = -side
            center = [_offset_x(rng, trailer_axle - 3.0, -2.0, trailer_axle), 1.3 * side, rng.uniform(2.0, 3.5)]
            yaw = side * np.pi / 2 + rng.uniform(-0.3, 0.3)
        cameras.append(_pinhole(f"trailer_{index}", "trailer", focal_px, image_size, make_pose(camera_rotation(yaw, pitch), np.array(center))))
    bodies = {"tractor": Body("tractor", tractor_axle), "trailer": Body("trailer", trailer_axle)}
    return Rig(bodies=bodies, cameras=tuple(cameras))


def reference_rig(focal_px: float = 700.0, image_size: tuple[int, int] = (640, 480)) -> Rig:
    """The DESIGN 2.3 setting: one front camera (5 m ahead of the tractor axle at 0.5 m), a trailer
    with ``s_B = 8 m`` and a rear camera 12.5 m behind the hitch."""
    front = _pinhole("front", "tractor", focal_px, image_size, make_pose(camera_rotation(0.0, 0.1), np.array([5.5, 0.0, 2.5])))
    rear = _pinhole("rear", "trailer", focal_px, image_size, make_pose(camera_rotation(np.pi, 0.1), np.array([-12.5, 0.0, 3.0])))
    return Rig(bodies={"tractor": Body("tractor", 0.5), "trailer": Body("trailer", -8.0)}, cameras=(front, rear))


# ---------------------------------------------------------------------- correspondences
def _draw(rng: np.random.Generator, value: FloatOrRange) -> float:
    """A fixed value, or a uniform draw from a ``(low, high)`` range."""
    if isinstance(value, (tuple, list)):
        return float(rng.uniform(value[0], value[1]))
    return float(value)


def _random_pixels(rng: np.random.Generator, camera: Camera, count: int) -> np.ndarray:
    return np.stack([rng.uniform(0.0, camera.width - 1.0, count), rng.uniform(0.0, camera.height - 1.0, count)], axis=1)


def _camera_correspondences(
    rng: np.random.Generator,
    camera: Camera,
    T_body_i_j: np.ndarray,
    count: int,
    depth_range: tuple[float, float],
    pixel_noise_px: float,
    outlier_fraction: float,
) -> CameraCorrespondences:
    """Points visible in both views of one camera on a body moving by ``T_body_i_j``."""
    T_camj_cami = invert_pose(camera.T_body_camera) @ invert_pose(T_body_i_j) @ camera.T_body_camera
    points = np.zeros((0, 3))
    pixels_i = np.zeros((0, 2))
    pixels_j = np.zeros((0, 2))
    for _ in range(50):
        if len(points) >= count:
            break
        draw = max(2 * (count - len(points)), 8)
        candidate_pixels = _random_pixels(rng, camera, draw)
        distance = rng.uniform(depth_range[0], depth_range[1], draw)
        candidates = camera.unproject(candidate_pixels) * distance[:, None]
        projected_j, valid = camera.project(transform_points(T_camj_cami, candidates))
        points = np.concatenate([points, candidates[valid]])
        pixels_i = np.concatenate([pixels_i, candidate_pixels[valid]])
        pixels_j = np.concatenate([pixels_j, projected_j[valid]])
    points, pixels_i, pixels_j = points[:count], pixels_i[:count], pixels_j[:count]
    count = len(points)
    inliers = np.ones(count, dtype=bool)
    n_outliers = int(round(outlier_fraction * count))
    if n_outliers > 0:
        outlier_index = rng.choice(count, n_outliers, replace=False)
        inliers[outlier_index] = False
        pixels_j[outlier_index] = _random_pixels(rng, camera, n_outliers)
    if pixel_noise_px > 0.0:
        pixels_i = pixels_i + rng.normal(0.0, pixel_noise_px, pixels_i.shape)
        pixels_j = pixels_j + rng.normal(0.0, pixel_noise_px, pixels_j.shape)
    bearings_i = camera.unproject(pixels_i) if count else np.zeros((0, 3))
    bearings_j = camera.unproject(pixels_j) if count else np.zeros((0, 3))
    if pixel_noise_px == 0.0 and count:  # exact bearings (no round trip through pixels)
        bearings_i = points / np.linalg.norm(points, axis=1, keepdims=True)
        exact_j = transform_points(T_camj_cami, points)
        exact_j /= np.linalg.norm(exact_j, axis=1, keepdims=True)
        bearings_j = np.where(inliers[:, None], exact_j, bearings_j)
    rotation = camera.R_body_camera
    return CameraCorrespondences(
        camera=camera,
        bearings_i=bearings_i,
        bearings_j=bearings_j,
        body_bearings_i=bearings_i @ rotation.T,
        body_bearings_j=bearings_j @ rotation.T,
        inliers=inliers,
        points_i=points,
    )


def make_two_view_problem(
    rng: np.random.Generator,
    *,
    rig: Rig | None = None,
    n_tractor_cameras: int = 1,
    n_trailer_cameras: int = 1,
    hitch_angle: FloatOrRange = (-np.deg2rad(60.0), np.deg2rad(60.0)),
    yaw_change: FloatOrRange = (-0.15, 0.15),
    chord: FloatOrRange = (0.5, 2.0),
    points_per_body: int = 100,
    pixel_noise_px: float = 0.0,
    focal_px: float = 700.0,
    image_size: tuple[int, int] = (640, 480),
    outlier_fraction: float = 0.0,
    depth_range: tuple[float, float] = (3.0, 40.0),
) -> TwoViewProblem:
    """Draw one articulated two-view problem (angles in radians, lengths in metres).

    ``hitch_angle`` (view i), ``yaw_change`` (tractor, phi) and ``chord`` (tractor axle, rho) are
    fixed values or ``(low, high)`` uniform ranges. With ``rig=None`` a :func:`random_rig` with
    ``n_tractor_cameras`` and ``n_trailer_cameras`` pinhole cameras of ``focal_px`` is drawn.
    ``points_per_body`` correspondences are split evenly over the cameras of each body. With
    ``pixel_noise_px == 0`` inlier bearings are exact. ``outlier_fraction`` of each camera's
    correspondences get a random view-j pixel (``inliers`` False).
    """
    if rig is None:
        rig = random_rig(rng, n_tractor_cameras=n_tractor_cameras, n_trailer_cameras=n_trailer_cameras, focal_px=focal_px, image_size=image_size)
    phi = _draw(rng, yaw_change)
    rho = _draw(rng, chord)
    theta = _draw(rng, hitch_angle)
    trailer_axle_x = rig.axle_x("trailer") if rig.has_trailer else -8.0
    motion = articulated_motion(phi, rho, theta, rig.axle_x("tractor"), trailer_axle_x)
    correspondences = []
    for body, T_body_i_j in (("tractor", motion["T_i_j"]), ("trailer", motion["T_trailer_i_j"])):
        cameras = rig.cameras_on(body)
        if not cameras:
            continue
        counts = np.full(len(cameras), points_per_body // len(cameras))
        counts[: points_per_body % len(cameras)] += 1
        for camera, count in zip(cameras, counts):
            correspondences.append(
                _camera_correspondences(rng, camera, T_body_i_j, int(count), depth_range, pixel_noise_px, outlier_fraction)
            )
    return TwoViewProblem(
        rig=rig,
        yaw_change=phi,
        chord=rho,
        T_i_j=motion["T_i_j"],
        hitch_angle_i=theta,
        hitch_angle_j=motion["hitch_angle_j"],
        trailer_yaw_change=motion["trailer_yaw_change"],
        trailer_chord=motion["trailer_chord"],
        T_trailer_i_j=motion["T_trailer_i_j"],
        correspondences=tuple(correspondences),
    )
