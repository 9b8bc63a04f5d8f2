"""Rig model: bodies, cameras, camera models and the ``rig.yaml`` format (DESIGN sections 1 and 5).

A rig has a ``tractor`` body and optionally a ``trailer`` body. Each body frame has its origin at
the hitch centre (x forward, y left, z up) and a signed ``axle_x``: the x coordinate of the midpoint
of its rigid axle. Cameras follow the OpenCV convention (x right, y down, z forward) and carry
``T_body_camera``. Two camera models are supported:

* ``pinhole``: OpenCV radial-tangential distortion ``(k1, k2, p1, p2[, k3])``;
* ``fisheye``: OpenCV equidistant model ``theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)``.

``Camera.project`` maps camera-frame points to pixels, ``Camera.unproject`` maps pixels to unit
bearing vectors in the camera frame; the two are inverse to 1e-9 over the whole image.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ampc_vo.errors import ConfigError
from ampc_vo.geometry import ROTATION_TOLERANCE, make_pose, quat_xyzw_from_rotation, rot_y, rot_z, rotation_from_quat_xyzw

BODY_NAMES = ("tractor", "trailer")
CAMERA_MODELS = ("pinhole", "fisheye")
CAMERA_KEYS = ("name", "body", "model", "width", "height", "fx", "fy", "cx", "cy", "distortion", "T_body_camera", "readout_time", "topic",
               "vignetting")
RIG_KEYS = ("bodies", "cameras", "hitch_height")
_NEWTON_ITERATIONS = 30
_FISHEYE_MAX_THETA = np.deg2rad(100.0)
# physically possible calibrations (issue 14: nonsense is an error, not a confidently wrong hitch)
PINHOLE_MAX_HALF_FOV_DEG = 80.0  # a pinhole (rectilinear) lens beyond ~160 degrees does not exist
MIN_HALF_FOV_DEG = 0.25  # narrower than a 0.5 degree telephoto: a focal length in the wrong unit
MAX_ASPECT_RATIO = 2.0  # fx / fy: pixels are (nearly) square
MAX_MOUNT_DISTANCE_M = 50.0  # a camera or an axle this far from the hitch: millimetres for metres?
PRINCIPAL_POINT_OFFSET = 0.25  # cx, cy further than this fraction of the size from the centre: a warning

logger = logging.getLogger(__name__)

# Body-frame axes of a camera looking straight ahead: columns are the camera x (right = -y_body),
# y (down = -z_body) and z (forward = +x_body) axes expressed in the body frame.
R_BODY_FORWARD_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera_rotation(yaw: float, pitch_down: float = 0.0) -> np.ndarray:
    """``R_body_camera`` of a camera whose optical axis points at heading ``yaw`` (radians,
    counter-clockwise from the body's x axis) tilted down by ``pitch_down`` (radians)."""
    return rot_z(yaw) @ rot_y(pitch_down) @ R_BODY_FORWARD_CAMERA


@dataclass(frozen=True)
class BodyBox:
    """The outline of a body as a box in its own frame (metres): the trailer's box, which the
    tractor's mirror cameras see (rig.yaml ``bodies.<name>.box``, DESIGN 5)."""

    front_x: float
    rear_x: float
    half_width: float
    bottom_z: float
    top_z: float

    def lower(self) -> np.ndarray:
        return np.array([self.rear_x, -self.half_width, self.bottom_z])

    def upper(self) -> np.ndarray:
        return np.array([self.front_x, self.half_width, self.top_z])


@dataclass(frozen=True)
class Body:
    """A rigid body of the vehicle. ``axle_x`` is the signed x of its rigid axle's midpoint;
    ``box`` its outline, when known (the other body's cameras may see it)."""

    name: str
    axle_x: float
    box: BodyBox | None = None


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera rigidly mounted on one body."""

    name: str
    body: str
    model: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()
    T_body_camera: np.ndarray = field(default_factory=lambda: np.eye(4))
    # rolling shutter: seconds from the first to the last image row (0: global shutter); row r is
    # exposed at the image's capture time + readout_time * r / (height - 1)
    readout_time: float = 0.0
    # where a recording carries this camera's images (ROS topic; None: our dataset folder)
    topic: str | None = None
    # vignetting (photometric calibration): the lens passes 1 - vignetting (1 - cos^4 alpha) of the
    # light at a pixel whose ray is alpha off the optical axis (0: none or not calibrated); the
    # frontend divides it out before tracking (:meth:`relative_illumination`)
    vignetting: float = 0.0

    # ------------------------------------------------------------------ convenience
    @property
    def R_body_camera(self) -> np.ndarray:
        return self.T_body_camera[:3, :3]

    @property
    def center(self) -> np.ndarray:
        """Camera centre in the body frame (``t_body_camera``, the paper's ``t_AC``)."""
        return self.T_body_camera[:3, 3]

    def row_times(self, pixels: np.ndarray) -> np.ndarray:
        """Seconds after the image's capture time at which pixels (N, 2) were exposed (rolling
        shutter: ``readout_time * row / (height - 1)``; 0 for a global shutter)."""
        pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
        if self.readout_time <= 0.0 or self.height < 2:
            return np.zeros(pixels.shape[0])
        return self.readout_time * pixels[:, 1] / (self.height - 1)

    def cos4_off_axis(self, pixels: np.ndarray) -> np.ndarray:
        """``cos^4 alpha`` (N,) of pixels (N, 2), ``alpha`` the angle of each pixel's ray to the
        optical axis: the natural fall-off of :meth:`relative_illumination`."""
        rays = self.unproject(np.asarray(pixels, dtype=float).reshape(-1, 2))
        return np.clip(rays[:, 2] / np.linalg.norm(rays, axis=1), 0.0, 1.0) ** 4

    def relative_illumination(self, step: int = 1) -> np.ndarray:
        """(height, width) float32: the share of the light the lens passes at each pixel,
        ``1 - vignetting (1 - cos^4 alpha)`` with ``alpha`` the angle of the pixel's ray to the
        optical axis (the natural cos^4 fall-off scaled by the calibrated ``vignetting``; Ray,
        *Applied Photographic Optics*, 2002, ch. 17); all ones without vignetting. With ``step`` > 1
        it is computed every ``step`` pixels (and at the last row and column) and interpolated
        bilinearly in between (the fall-off is smooth; un-projecting every pixel of a distorted
        camera takes a few hundred milliseconds)."""
        if self.vignetting <= 0.0:
            return np.ones((self.height, self.width), np.float32)
        sample_columns, sample_rows = _samples(self.width, step), _samples(self.height, step)
        columns, rows = np.meshgrid(sample_columns, sample_rows)
        cos4 = self.cos4_off_axis(np.stack([columns.ravel(), rows.ravel()], axis=1)).reshape(columns.shape)
        sampled = 1.0 - self.vignetting * (1.0 - cos4)
        if step > 1:
            sampled = _linear_weights(self.height, sample_rows) @ sampled @ _linear_weights(self.width, sample_columns).T
        return sampled.astype(np.float32)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def _coefficients(self, count: int) -> np.ndarray:
        coefficients = np.zeros(count)
        values = np.asarray(self.distortion, dtype=float)[:count]
        coefficients[: len(values)] = values
        return coefficients

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        scalars = ("name", "body", "model", "width", "height", "fx", "fy", "cx", "cy", "readout_time", "topic", "vignetting")
        return (
            all(getattr(self, key) == getattr(other, key) for key in scalars)
            and tuple(self.distortion) == tuple(other.distortion)
            and np.array_equal(self.T_body_camera, other.T_body_camera)
        )

    __hash__ = object.__hash__

    # ------------------------------------------------------------------ distortion
    def _distort(self, normalized: np.ndarray) -> np.ndarray:
        """Pinhole: undistorted normalised coordinates (N, 2) -> distorted (N, 2) (the same array
        without distortion coefficients)."""
        if not np.any(self.distortion):
            return normalized
        k1, k2, p1, p2, k3 = self._coefficients(5)
        x, y = normalized[:, 0], normalized[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def _undistort(self, distorted: np.ndarray) -> np.ndarray:
        """Pinhole: invert :meth:`_distort` by vectorised Newton iterations."""
        k1, k2, p1, p2, k3 = self._coefficients(5)
        if not np.any([k1, k2, p1, p2, k3]):
            return distorted.copy()
        point = distorted.copy()
        for _ in range(_NEWTON_ITERATIONS):
            x, y = point[:, 0], point[:, 1]
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
            residual = self._distort(point) - distorted
            j11 = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
            j12 = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
            j21 = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
            j22 = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
            det = j11 * j22 - j12 * j21
            step_x = (j22 * residual[:, 0] - j12 * residual[:, 1]) / det
            step_y = (-j21 * residual[:, 0] + j11 * residual[:, 1]) / det
            point = point - np.stack([step_x, step_y], axis=1)
            if np.max(np.abs(residual)) < 1e-15:
                break
        return point

    def _fisheye_theta_d(self, theta: np.ndarray) -> np.ndarray:
        k1, k2, k3, k4 = self._coefficients(4)
        t2 = theta * theta
        return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def _fisheye_theta(self, theta_d: np.ndarray) -> np.ndarray:
        """Invert the equidistant polynomial by Newton iterations."""
        k1, k2, k3, k4 = self._coefficients(4)
        theta = theta_d.copy()
        if not np.any([k1, k2, k3, k4]):
            return theta
        for _ in range(_NEWTON_ITERATIONS):
            t2 = theta * theta
            value = self._fisheye_theta_d(theta) - theta_d
            slope = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
            theta = theta - value / slope
            if np.max(np.abs(value), initial=0.0) < 1e-15:
                break
        return theta

    # ------------------------------------------------------------------ projection
    def project(self, points_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (N, 3) camera-frame points to pixels.

        Returns ``(pixels (N, 2), valid (N,))``: ``valid`` is true for points in front of the
        camera (pinhole ``z > 0``; fisheye incidence below 100 degrees) that land in the image.
        """
        points = np.atleast_2d(np.asarray(points_camera, dtype=float))
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.model == "pinhole":
                in_front = z > 1e-9
                safe_z = np.where(in_front, z, 1.0)
                distorted = self._distort(np.stack([x / safe_z, y / safe_z], axis=1))
            else:
                radius = np.hypot(x, y)
                theta = np.arctan2(radius, z)
                in_front = theta < _FISHEYE_MAX_THETA
                theta_d = self._fisheye_theta_d(theta)
                scale = np.where(radius > 1e-12, theta_d / np.where(radius > 1e-12, radius, 1.0), 1.0 / np.where(z > 0, z, 1.0))
                distorted = np.stack([x * scale, y * scale], axis=1)
        pixels = np.stack([self.fx * distorted[:, 0] + self.cx, self.fy * distorted[:, 1] + self.cy], axis=1)
        inside = (
            (pixels[:, 0] >= -0.5) & (pixels[:, 0] <= self.width - 0.5)
            & (pixels[:, 1] >= -0.5) & (pixels[:, 1] <= self.height - 0.5)
        )
        valid = in_front & inside & np.all(np.isfinite(pixels), axis=1)
        return pixels, valid

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Unit bearing vectors (N, 3) in the camera frame for (N, 2) pixel coordinates."""
        pixels = np.atleast_2d(np.asarray(pixels, dtype=float))
        distorted = np.stack([(pixels[:, 0] - self.cx) / self.fx, (pixels[:, 1] - self.cy) / self.fy], axis=1)
        if self.model == "pinhole":
            normalized = self._undistort(distorted)
            rays = np.concatenate([normalized, np.ones((len(normalized), 1))], axis=1)
            return rays / np.linalg.norm(rays, axis=1, keepdims=True)
        theta_d = np.linalg.norm(distorted, axis=1)
        theta = self._fisheye_theta(theta_d)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(theta_d > 1e-15, np.sin(theta) / np.where(theta_d > 1e-15, theta_d, 1.0), 1.0)
        return np.stack([distorted[:, 0] * scale, distorted[:, 1] * scale, np.cos(theta)], axis=1)

    def bearings_in_body(self, pixels: np.ndarray) -> np.ndarray:
        """Unit bearings (N, 3) rotated into the body frame (``R_body_camera @ bearing``)."""
        return self.unproject(pixels) @ self.R_body_camera.T


@dataclass(frozen=True)
class Rig:
    """Bodies and cameras of the articulated multi-perspective camera."""

    bodies: dict[str, Body]
    cameras: tuple[Camera, ...]
    # the king-pin's (body origin's) height above the road when standing level, metres: the road
    # plane is z = -hitch_height in both body frames (DESIGN 1)
    hitch_height: float = 0.0

    @property
    def ground_z(self) -> float:
        """z of the road plane in either body frame when standing level (``-hitch_height``)."""
        return -self.hitch_height

    @property
    def camera_names(self) -> list[str]:
        return [camera.name for camera in self.cameras]

    @property
    def has_trailer(self) -> bool:
        return "trailer" in self.bodies

    def camera(self, name: str) -> Camera:
        for camera in self.cameras:
            if camera.name == name:
                return camera
        raise KeyError(f"rig has no camera named {name!r}; cameras: {self.camera_names}")

    def cameras_on(self, body: str) -> list[Camera]:
        return [camera for camera in self.cameras if camera.body == body]

    def axle_x(self, body: str) -> float:
        return self.bodies[body].axle_x


# ---------------------------------------------------------------------- plausibility
def _samples(size: int, step: int) -> np.ndarray:
    """Pixel positions 0, step, 2 step, ... and the last one, ``size - 1`` (float)."""
    return np.unique(np.append(np.arange(0, size, max(int(step), 1)), size - 1)).astype(float)


def _linear_weights(size: int, samples: np.ndarray) -> np.ndarray:
    """(size, len(samples)) weights of linear interpolation from the values at ``samples`` (ascending
    pixel positions spanning 0..size-1) to every pixel 0..size-1."""
    pixels = np.arange(size, dtype=float)
    upper = np.clip(np.searchsorted(samples, pixels, side="right"), 1, len(samples) - 1)
    lower = upper - 1
    share = (pixels - samples[lower]) / (samples[upper] - samples[lower])
    weights = np.zeros((size, len(samples)))
    weights[np.arange(size), lower] = 1.0 - share
    weights[np.arange(size), upper] += share
    return weights


def _radial_function(camera: Camera, radius: np.ndarray) -> np.ndarray:
    """The distorted normalised radius of an undistorted one: pinhole ``r (1 + k1 r^2 + k2 r^4 +
    k3 r^6)`` (r = tan of the incidence angle), fisheye ``theta_d(theta)`` (r = theta)."""
    if camera.model == "fisheye":
        return camera._fisheye_theta_d(radius)
    k1, k2, _, _, k3 = camera._coefficients(5)
    r2 = radius * radius
    return radius * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))


def calibration_problem(camera: Camera) -> str | None:
    """What is physically impossible about a camera's intrinsics, or ``None``: a focal length that
    gives a field of view no lens of that model has (fx = 1e-9, or in metres), non-square pixels
    beyond a factor 2, or a distortion that maps the image outside itself (the radial distortion
    folds back before it reaches the image corners: those pixels are the image of no ray, e.g.
    k1 = -5 for images that are already undistorted; Hartley & Zisserman 2003, section 7.4)."""
    half_width = max(camera.cx, camera.width - camera.cx) / camera.fx
    half_height = max(camera.cy, camera.height - camera.cy) / camera.fy
    if camera.model == "pinhole":
        half_fov = np.degrees(np.arctan(max(half_width, half_height)))
        if half_fov > PINHOLE_MAX_HALF_FOV_DEG:
            return (f"fx = {camera.fx:g}, fy = {camera.fy:g} px give a field of view of {2 * half_fov:.1f} degrees: a pinhole camera cannot "
                    f"see beyond {2 * PINHOLE_MAX_HALF_FOV_DEG:g} (focal length in mm or m instead of pixels? a fisheye lens?)")
    else:
        half_fov = np.degrees(max(half_width, half_height))
        if half_fov >= 180.0:
            return f"fx = {camera.fx:g}, fy = {camera.fy:g} px give a fisheye field of view over 360 degrees (focal length in mm or m instead of pixels?)"
    if np.degrees(np.arctan(min(half_width, half_height))) < MIN_HALF_FOV_DEG:
        return f"fx = {camera.fx:g}, fy = {camera.fy:g} px give a field of view under {2 * MIN_HALF_FOV_DEG:g} degrees (focal length in the wrong unit?)"
    ratio = camera.fx / camera.fy
    if not 1.0 / MAX_ASPECT_RATIO <= ratio <= MAX_ASPECT_RATIO:
        return f"fx / fy = {ratio:.3g}: pixels that are not square by more than a factor {MAX_ASPECT_RATIO:g} (fx and fy of different cameras?)"
    if not any(camera.distortion):
        return None
    corners = np.array([[-0.5, -0.5], [camera.width - 0.5, -0.5], [-0.5, camera.height - 0.5], [camera.width - 0.5, camera.height - 0.5]])
    corner_radius = float(np.max(np.hypot((corners[:, 0] - camera.cx) / camera.fx, (corners[:, 1] - camera.cy) / camera.fy)))
    limit = np.tan(np.radians(89.0)) if camera.model == "pinhole" else np.pi
    radius = np.linspace(0.0, limit, 200_001)
    distorted = _radial_function(camera, radius)
    folds = np.flatnonzero(np.diff(distorted) <= 0.0)
    reachable = float(distorted[folds[0]]) if len(folds) else float(distorted[-1])
    if reachable < corner_radius:
        return (f"distortion {list(camera.distortion)} maps the image outside itself: rays reach at most {reachable * camera.fx:.0f} px from the principal point, "
                f"the image corners are {corner_radius * camera.fx:.0f} px away (distortion of another camera, or images that are already undistorted?)")
    return None


def calibration_warnings(camera: Camera) -> list[str]:
    """What is possible but suspicious about a camera's intrinsics, and what it will do: a
    principal point far from the image centre (swapped cx / cy, or the calibration of a crop) tilts
    every bearing of that camera."""
    warnings = []
    for key, value, size in (("cx", camera.cx, camera.width), ("cy", camera.cy, camera.height)):
        if abs(value - 0.5 * (size - 1)) > PRINCIPAL_POINT_OFFSET * size:
            warnings.append(f"{key} = {value:g} is {abs(value - 0.5 * (size - 1)):.0f} px from the image centre ({size} px): "
                            "cx and cy swapped, or the calibration of a cropped image? every bearing of this camera is tilted by it")
    return warnings


def rig_problem(rig: "Rig") -> str | None:
    """The first physically impossible value of a rig (:func:`calibration_problem` of each camera,
    mounts and axles beyond ``MAX_MOUNT_DISTANCE_M``), as ``"field: problem"``, or ``None``."""
    for index, camera in enumerate(rig.cameras):
        problem = calibration_problem(camera)
        if problem:
            return f"cameras[{index}] ({camera.name}): {problem}"
        distance = float(np.linalg.norm(camera.center))
        if distance > MAX_MOUNT_DISTANCE_M:
            return f"cameras[{index}] ({camera.name}).T_body_camera.translation: {distance:.1f} m from the hitch (millimetres instead of metres?)"
    for name, body in rig.bodies.items():
        if abs(body.axle_x) > MAX_MOUNT_DISTANCE_M:
            return f"bodies.{name}.axle_x: {body.axle_x:g} m from the hitch (millimetres instead of metres?)"
    if rig.hitch_height > 10.0:
        return f"hitch_height: {rig.hitch_height:g} m above the road (millimetres instead of metres?)"
    return None


# ---------------------------------------------------------------------- rig.yaml
def _require(mapping: Any, key: str, where: str, source: str) -> Any:
    if not isinstance(mapping, dict) or key not in mapping or mapping[key] is None:
        raise ConfigError(f"{source}: {where}{key}: missing")
    return mapping[key]


def _number(value: Any, where: str, source: str, positive: bool = False) -> float:
    if isinstance(value, bool):  # YAML true/false would otherwise read as 1.0/0.0
        raise ConfigError(f"{source}: {where}: expected a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: {where}: expected a number, got {value!r}") from None
    if not np.isfinite(number) or (positive and number <= 0.0):
        raise ConfigError(f"{source}: {where}: must be a {'positive ' if positive else ''}finite number, got {value!r}")
    return number


def _check_keys(spec: Any, known: tuple[str, ...], where: str, source: str) -> None:
    """An unknown key (e.g. a misspelt ``distorsion``) is an error, not silently ignored."""
    unknown = sorted(str(key) for key in spec if key not in known) if isinstance(spec, dict) else []
    if unknown:
        raise ConfigError(f"{source}: {where}{unknown[0]}: unknown key (known keys: {', '.join(known)})")


def _vector(value: Any, length: int, where: str, source: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise ConfigError(f"{source}: {where}: expected a list of {length} numbers, got {value!r}")
    return np.array([_number(item, f"{where}[{index}]", source) for index, item in enumerate(value)])


def rig_from_dict(raw: Any, source: str = "rig") -> Rig:
    """Build and validate a :class:`Rig` from the parsed ``rig.yaml`` mapping.

    Every problem raises :class:`ConfigError` naming ``source`` and the field.
    """
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: expected a mapping with 'bodies' and 'cameras'")
    _check_keys(raw, RIG_KEYS, "", source)
    hitch_height = _number(raw.get("hitch_height", 0.0), "hitch_height", source)
    if hitch_height < 0.0:
        raise ConfigError(f"{source}: hitch_height: the king-pin's height above the road must be >= 0 m, got {hitch_height}")
    raw_bodies = _require(raw, "bodies", "", source)
    if not isinstance(raw_bodies, dict):
        raise ConfigError(f"{source}: bodies: expected a mapping of body name to {{axle_x: ...}}")
    bodies: dict[str, Body] = {}
    for name, spec in raw_bodies.items():
        if name not in BODY_NAMES:
            raise ConfigError(f"{source}: bodies.{name}: unknown body (expected one of {BODY_NAMES})")
        _check_keys(spec, ("axle_x", "box"), f"bodies.{name}.", source)
        axle_x = _number(_require(spec, "axle_x", f"bodies.{name}.", source), f"bodies.{name}.axle_x", source)
        bodies[name] = Body(name, axle_x, _body_box(spec.get("box"), f"bodies.{name}.box", source))
    if "tractor" not in bodies:
        raise ConfigError(f"{source}: bodies.tractor: missing")
    if "trailer" in bodies and bodies["trailer"].axle_x >= 0.0:
        raise ConfigError(
            f"{source}: bodies.trailer.axle_x: the trailer axle must lie behind the hitch (axle_x < 0), "
            f"got {bodies['trailer'].axle_x}"
        )
    raw_cameras = _require(raw, "cameras", "", source)
    if not isinstance(raw_cameras, list) or not raw_cameras:
        raise ConfigError(f"{source}: cameras: expected a non-empty list")
    cameras = []
    for index, spec in enumerate(raw_cameras):
        where = f"cameras[{index}]."
        name = str(_require(spec, "name", where, source))
        body = _require(spec, "body", where, source)
        if body not in bodies:
            raise ConfigError(f"{source}: {where}body: unknown body {body!r} (rig has {list(bodies)})")
        model = _require(spec, "model", where, source)
        if model not in CAMERA_MODELS:
            raise ConfigError(f"{source}: {where}model: unknown camera model {model!r} (expected {CAMERA_MODELS})")
        _check_keys(spec, CAMERA_KEYS, where, source)
        intrinsics = {key: _number(_require(spec, key, where, source), where + key, source, positive=key in ("fx", "fy", "width", "height")) for key in ("width", "height", "fx", "fy", "cx", "cy")}
        for key in ("width", "height"):
            if intrinsics[key] != int(intrinsics[key]):
                raise ConfigError(f"{source}: {where}{key}: must be a whole number of pixels, got {spec[key]!r}")
        for key, size in (("cx", "width"), ("cy", "height")):
            if not 0.0 <= intrinsics[key] <= intrinsics[size]:
                raise ConfigError(f"{source}: {where}{key}: principal point must lie in the image [0, {size} = {intrinsics[size]:g}], got {spec[key]!r}")
        distortion = spec.get("distortion") or []
        if not isinstance(distortion, (list, tuple)) or len(distortion) > (5 if model == "pinhole" else 4):
            raise ConfigError(f"{source}: {where}distortion: expected at most {5 if model == 'pinhole' else 4} coefficients for a {model} camera, got {distortion!r}")
        distortion = tuple(_number(value, f"{where}distortion[{k}]", source) for k, value in enumerate(distortion))
        extrinsics = _require(spec, "T_body_camera", where, source)
        _check_keys(extrinsics, ("translation", "quaternion"), where + "T_body_camera.", source)
        translation = _vector(_require(extrinsics, "translation", where + "T_body_camera.", source), 3, where + "T_body_camera.translation", source)
        quaternion = _vector(_require(extrinsics, "quaternion", where + "T_body_camera.", source), 4, where + "T_body_camera.quaternion", source)
        readout_time = _number(spec.get("readout_time", 0.0), where + "readout_time", source)
        if not 0.0 <= readout_time < 1.0:
            raise ConfigError(f"{source}: {where}readout_time: rolling-shutter readout must be in [0, 1) s, got {readout_time}")
        vignetting = _number(spec.get("vignetting", 0.0), where + "vignetting", source)
        if not 0.0 <= vignetting < 1.0:
            raise ConfigError(f"{source}: {where}vignetting: the strength of the cos^4 fall-off must be in [0, 1), got {vignetting}")
        topic = spec.get("topic")
        if topic is not None and (not isinstance(topic, str) or not topic.strip()):
            raise ConfigError(f"{source}: {where}topic: expected a topic name, got {topic!r}")
        if abs(np.linalg.norm(quaternion) - 1.0) > ROTATION_TOLERANCE:  # within: rounded, normalised below
            raise ConfigError(f"{source}: {where}T_body_camera.quaternion: not a unit quaternion (norm {np.linalg.norm(quaternion):.6f}); order is x y z w")
        cameras.append(
            Camera(
                name=name, body=body, model=model,
                width=int(intrinsics["width"]), height=int(intrinsics["height"]),
                fx=intrinsics["fx"], fy=intrinsics["fy"], cx=intrinsics["cx"], cy=intrinsics["cy"],
                distortion=distortion,
                T_body_camera=make_pose(rotation_from_quat_xyzw(quaternion), translation),
                readout_time=readout_time, topic=topic, vignetting=vignetting,
            )
        )
    names = [camera.name for camera in cameras]
    duplicated = sorted({name for name in names if names.count(name) > 1})
    if duplicated:
        raise ConfigError(f"{source}: cameras: duplicate camera names {duplicated}")
    rig = Rig(bodies=bodies, cameras=tuple(cameras), hitch_height=hitch_height)
    problem = rig_problem(rig)
    if problem:
        raise ConfigError(f"{source}: {problem}")
    for index, camera in enumerate(rig.cameras):
        for warning in calibration_warnings(camera):
            logger.warning("%s: cameras[%d] (%s): %s", source, index, camera.name, warning)
    return rig


BOX_KEYS = ("front_x", "rear_x", "half_width", "bottom_z", "top_z")


def _body_box(raw: Any, where: str, source: str) -> BodyBox | None:
    """``bodies.<name>.box`` of rig.yaml: ``{front_x, rear_x, half_width, bottom_z, top_z}`` (m, body frame)."""
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: {where}: expected a mapping with {', '.join(BOX_KEYS)}")
    _check_keys(raw, BOX_KEYS, where + ".", source)
    box = BodyBox(*(_number(_require(raw, key, where + ".", source), f"{where}.{key}", source) for key in BOX_KEYS))
    if not (box.front_x > box.rear_x and box.half_width > 0.0 and box.top_z > box.bottom_z):
        raise ConfigError(f"{source}: {where}: expected front_x > rear_x, half_width > 0 and top_z > bottom_z, got {raw}")
    if max(abs(box.front_x), abs(box.rear_x), box.half_width, abs(box.bottom_z), abs(box.top_z)) > MAX_MOUNT_DISTANCE_M:
        raise ConfigError(f"{source}: {where}: a box over {MAX_MOUNT_DISTANCE_M:g} m from the hitch (millimetres instead of metres?)")
    return box


def rig_to_dict(rig: Rig) -> dict:
    """The ``rig.yaml`` mapping of a rig (inverse of :func:`rig_from_dict`)."""
    cameras = []
    for camera in rig.cameras:
        cameras.append(
            {
                "name": camera.name, "body": camera.body, "model": camera.model,
                "width": camera.width, "height": camera.height,
                "fx": float(camera.fx), "fy": float(camera.fy), "cx": float(camera.cx), "cy": float(camera.cy),
                "distortion": [float(value) for value in camera.distortion],
                "T_body_camera": {
                    "translation": [float(value) for value in camera.center],
                    "quaternion": [float(value) for value in quat_xyzw_from_rotation(camera.R_body_camera)],
                },
            }
        )
        if camera.readout_time:
            cameras[-1]["readout_time"] = float(camera.readout_time)
        if camera.topic is not None:
            cameras[-1]["topic"] = camera.topic
        if camera.vignetting:
            cameras[-1]["vignetting"] = float(camera.vignetting)
    bodies = {}
    for name, body in rig.bodies.items():
        bodies[name] = {"axle_x": float(body.axle_x)}
        if body.box is not None:
            bodies[name]["box"] = {key: float(getattr(body.box, key)) for key in BOX_KEYS}
    return {"hitch_height": float(rig.hitch_height), "bodies": bodies, "cameras": cameras}


def load_rig(path: str | Path) -> Rig:
    """Read and validate ``rig.yaml``; errors name the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: rig file not found")
    try:
        raw = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as error:  # a binary or non-UTF-8 file too
        raise ConfigError(f"{path}: not valid YAML: {error}") from None
    return rig_from_dict(raw, source=str(path))


def save_rig(rig: Rig, path: str | Path) -> None:
    """Write ``rig.yaml``. Values are written with full precision so that a reload is identical."""
    Path(path).write_text(yaml.safe_dump(rig_to_dict(rig), sort_keys=False))


def replace_camera(camera: Camera, **changes: Any) -> Camera:
    """A copy of ``camera`` with some fields changed (dataclasses.replace for the frozen type)."""
    return dataclasses.replace(camera, **changes)
