"""Metric scale from the ground plane: the tractor axle chord between two keyframes, measured from
road points seen by a tractor camera whose height above the road is known from the rig.

Why: with intra-camera correspondences, metric scale is unobservable in straight driving (DESIGN
2.3). The camera's height above the road is a metric length the images can compare against: the
classic monocular-VO scale source (e.g. Kitt et al., IV 2011; Song and Chandraker, CVPR 2014).

**Derivation** (body frame i, DESIGN 1 conventions). Camera centre ``c`` (``T_body_camera``),
rigid axle midpoint ``m = (axle_x, 0, 0)``, body motion ``T_i_j = (R, t)`` with the rotation
known and the scale unknown. Body-frame bearings ``f = R_body_camera f_i`` (view i) and
``g = R R_body_camera f_j`` (view j, rotated into frame i). The unknown scale is the length ``rho``
of the axle chord, whose direction ``d`` is known from the given motion (the (NH) family of DESIGN
2: ``d ∝ R m + t - m``):

    t(rho) = rho d + m - R m,     b(rho) = R c + t(rho) - c = b0 + rho d,     b0 = (R - I)(c - m)

(``b`` is the camera baseline; for a pure translation ``b0 = 0`` and ``rho`` is a plain scale).
Midpoint triangulation of the rays ``c + lambda f`` and ``c + b + mu g`` (``k = f.g``):

    lambda = (f.b - k g.b) / (1 - k²),     mu = (k f.b - g.b) / (1 - k²),
    X = c + (lambda f + b + mu g) / 2,

is linear in ``b``, so the point's height is ``X_z = c_z + w.b`` with

    w = (e_z + f_z (f - k g) / (1 - k²) + g_z (k f - g) / (1 - k²)) / 2.

A road point has ``X_z = z_g`` (road height in the body frame, camera height ``h = c_z - z_g``):

    rho_k = -(h + w.b0) / (w.d)                                                       (G)

For a pure translation ``rho_k = h / h_unit,k`` with ``h_unit,k = -w.d`` the camera height above
the point triangulated at unit scale: the textbook ratio "known height over unit-scale height".

**Selecting the road.** Every road point gives the same ``rho_k``; a point at height ``z_p``
between the road and the camera gives ``rho_k ≈ rho h / (c_z - z_p) > rho`` (it is read as a
farther road point), points above the camera give no admissible value. Candidates are points below
the horizon in both views (body frame) with enough parallax and positive depths. Their per-point
sigmas come from propagating the bearing noise (``pixel_sigma / focal``) through (G) (numerical
derivatives along the bearings' tangent planes). The road is the consensus set of a 1-D MSAC over
the candidates' ``rho_k`` (every candidate is a hypothesis; residuals normalised by the per-point
sigmas) -- equivalently the dominant horizontal plane below the camera at unit scale. The chord is
the inverse-variance mean of the consensus set (re-selected a few times); its sigma is the formal
one inflated by the Birge ratio (spread of the per-point values vs. their sigmas) and combined with
the camera-height uncertainty (``height_sigma_m``: suspension, road camber), ``sigma_rho / rho =
sigma_h / h``.
"""
from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ampc_vo.geometry import check_bearings
from ampc_vo.rig import Camera

logger = logging.getLogger(__name__)

_E_Z = np.array([0.0, 0.0, 1.0])
_DIFFERENCE_STEP = 1e-6  # radians, bearing perturbation of the numerical sigma propagation


class GroundScaleStatus(str, Enum):
    """Outcome of a ground-plane chord measurement (``OK`` or why there is none)."""

    OK = "ok"
    NO_MOTION_DIRECTION = "no_motion_direction"    # the given motion has no axle displacement
    SMALL_BASELINE = "small_baseline"              # too little parallax (standstill)
    TOO_FEW_GROUND_POINTS = "too_few_ground_points"
    CAMERA_NOT_ABOVE_ROAD = "camera_not_above_road"


@dataclass(frozen=True)
class GroundScaleOptions:
    """Options of :func:`ground_plane_chord` (radians, metres).

    ``ground_z``: z of the road surface in the body frame (the simulator puts the body origin on the
    road, DESIGN 6; a real truck's hitch is ~1.2 m above it). ``pixel_sigma``: bearing noise in
    pixels, divided by each camera's focal length. ``height_sigma_m``: uncertainty of the camera
    height above the road. ``min_depression``: both bearings at least this far below the body's
    horizontal plane. ``min_parallax``: median parallax below this is a standstill; single points
    need ``2 * bearing sigma``. ``consensus_sigmas``: inlier threshold in per-point sigmas.
    ``max_relative_point_sigma``: points whose chord is more uncertain than this (relative to the
    consensus) are ignored. ``min_points``: fewer road inliers give no measurement.
    """

    ground_z: float = 0.0
    pixel_sigma: float = 1.0
    height_sigma_m: float = 0.02
    min_depression: float = np.deg2rad(2.0)
    min_parallax: float = 0.003
    consensus_sigmas: float = 3.0
    max_relative_point_sigma: float = 0.3
    min_points: int = 8
    refine_rounds: int = 3


@dataclass(frozen=True)
class PointChords:
    """Per-correspondence chord values (G) of one camera: ``chord`` (N,), ``sigma`` (N,) and the
    ``candidate`` mask (N,) (below the horizon, parallax, positive depths, finite)."""

    chord: np.ndarray
    sigma: np.ndarray
    candidate: np.ndarray
    parallax: np.ndarray


@dataclass(frozen=True)
class GroundChord:
    """Result of :func:`ground_plane_chord`: the metric chord of the tractor axle midpoint and its
    1-sigma (metres), or ``None`` with the ``status`` saying why. ``inliers``: per camera, the mask
    of the correspondences taken as road points; ``candidates``: candidate count."""

    status: GroundScaleStatus
    chord: float | None = None
    sigma: float | None = None
    inliers: tuple[np.ndarray, ...] = ()
    candidates: int = 0

    @property
    def ok(self) -> bool:
        return self.status is GroundScaleStatus.OK

    @property
    def inlier_count(self) -> int:
        return int(sum(int(np.count_nonzero(mask)) for mask in self.inliers))

    def as_scale_chord(self) -> tuple[float, float] | None:
        """``(chord, sigma)`` for :class:`ampc_vo.smoother.MotionInit.scale_chord`, or ``None``."""
        return (float(self.chord), float(self.sigma)) if self.ok else None


def axle_chord_direction(T_i_j: np.ndarray, axle_x: float) -> np.ndarray | None:
    """Unit direction ``d`` of the axle displacement ``R m + t - m`` of a motion (DESIGN 2 (NH)),
    or ``None`` when the motion does not move the axle."""
    axle = np.array([axle_x, 0.0, 0.0])
    displacement = T_i_j[:3, :3] @ axle + T_i_j[:3, 3] - axle
    norm = float(np.linalg.norm(displacement))
    return displacement / norm if norm > 1e-9 and np.isfinite(norm) else None


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _chord_of_rays(f: np.ndarray, g: np.ndarray, center: np.ndarray, height: float, baseline0: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Equation (G) for body-frame rays ``f`` (view i) and ``g`` (view j in frame i), shapes (..., 3):
    ``(rho, w.d)``; ``rho`` is NaN where the rays are parallel."""
    k = _rowdot(f, g)
    denominator = 1.0 - k * k
    safe = np.where(denominator > 1e-15, denominator, np.nan)
    w = 0.5 * (_E_Z + (f[..., 2] / safe)[..., None] * (f - k[..., None] * g) + (g[..., 2] / safe)[..., None] * (k[..., None] * f - g))
    slope = _rowdot(w, direction)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = -(height + _rowdot(w, baseline0)) / slope
    return rho, slope


def _tangent_basis(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) orthogonal to each unit vector and to each other."""
    helper = np.where(np.abs(vectors[:, :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    first = np.cross(vectors, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    return first, np.cross(vectors, first)


def point_chords(camera: Camera, bearings_i: np.ndarray, bearings_j: np.ndarray, T_i_j: np.ndarray, axle_x: float,
                 options: GroundScaleOptions = GroundScaleOptions()) -> PointChords:
    """Equation (G) and its propagated sigma for every correspondence of one camera (module docstring).

    ``bearings_i``, ``bearings_j``: (N, 3) camera-frame bearings of the same points in keyframes i
    and j; ``T_i_j``: body motion (rotation trusted, translation only for the chord direction).
    Raises :class:`ampc_vo.errors.BearingError` for malformed bearings.
    """
    bearings_i = check_bearings(bearings_i, "bearings_i")
    bearings_j = check_bearings(bearings_j, "bearings_j", count=bearings_i.shape[0])
    count = bearings_i.shape[0]
    direction = axle_chord_direction(T_i_j, axle_x)
    if direction is None or count == 0:
        return PointChords(np.full(count, np.nan), np.full(count, np.inf), np.zeros(count, bool), np.zeros(count))
    rotation, R_body_camera = T_i_j[:3, :3], camera.R_body_camera
    center = camera.center
    height = float(center[2] - options.ground_z)
    if height <= 0.0:  # a camera at or below the road sees no road from above
        return PointChords(np.full(count, np.nan), np.full(count, np.inf), np.zeros(count, bool), np.zeros(count))
    baseline0 = (rotation - np.eye(3)) @ (center - np.array([axle_x, 0.0, 0.0]))
    f = bearings_i @ R_body_camera.T
    g = bearings_j @ (rotation @ R_body_camera).T
    rho, slope = _chord_of_rays(f, g, center, height, baseline0, direction)
    parallax = np.arccos(np.clip(_rowdot(f, g), -1.0, 1.0))
    # sigma of rho from the bearing noise, numerically along both tangent directions of both bearings
    bearing_sigma = options.pixel_sigma / (0.5 * (camera.fx + camera.fy))
    variance = np.zeros(count)
    for index, vectors in enumerate((f, g)):
        for tangent in _tangent_basis(vectors):
            moved = vectors + _DIFFERENCE_STEP * tangent
            moved /= np.linalg.norm(moved, axis=1, keepdims=True)
            shifted, _ = _chord_of_rays(moved, g, center, height, baseline0, direction) if index == 0 else _chord_of_rays(f, moved, center, height, baseline0, direction)
            variance += ((shifted - rho) / _DIFFERENCE_STEP) ** 2
    sigma = bearing_sigma * np.sqrt(variance)
    # positive depths on both rays at the point's own chord
    baseline = baseline0 + rho[:, None] * direction
    k = _rowdot(f, g)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_i = (_rowdot(f, baseline) - k * _rowdot(g, baseline)) / (1.0 - k * k)
        depth_j = (k * _rowdot(f, baseline) - _rowdot(g, baseline)) / (1.0 - k * k)
    below = np.sin(options.min_depression)
    candidate = (
        (f[:, 2] < -below) & (g[:, 2] < -below) & (parallax > 2.0 * bearing_sigma)
        & np.isfinite(rho) & (rho > 0.0) & np.isfinite(sigma) & (depth_i > 0.0) & (depth_j > 0.0)
    )
    return PointChords(rho, sigma, candidate, parallax)


def robust_chord(chords: np.ndarray, sigmas: np.ndarray, options: GroundScaleOptions = GroundScaleOptions()) -> tuple[float, float, np.ndarray] | None:
    """1-D MSAC consensus over per-point chords (N,) with sigmas (N,) (module docstring):
    ``(chord, statistical sigma, inlier mask)`` or ``None`` with fewer than ``min_points`` inliers.
    Every point is a hypothesis; the cost of hypothesis h is ``sum min((rho_k - rho_h)^2 /
    sigma_k^2, T^2)`` with ``T = consensus_sigmas`` (vectorised, N x N)."""
    count = chords.shape[0]
    if count < options.min_points:
        return None
    threshold = options.consensus_sigmas
    normalized = (chords[None, :] - chords[:, None]) / sigmas[None, :]
    cost = np.minimum(normalized**2, threshold**2).sum(axis=1)
    estimate = float(chords[int(np.argmin(cost))])
    inliers = np.zeros(count, bool)
    for _ in range(options.refine_rounds):
        inliers = (np.abs(chords - estimate) < threshold * sigmas) & (sigmas < options.max_relative_point_sigma * estimate)
        if np.count_nonzero(inliers) < options.min_points:
            return None
        weights = 1.0 / sigmas[inliers] ** 2
        estimate = float(np.sum(weights * chords[inliers]) / np.sum(weights))
    inliers = (np.abs(chords - estimate) < threshold * sigmas) & (sigmas < options.max_relative_point_sigma * estimate)
    used = int(np.count_nonzero(inliers))
    if used < options.min_points:
        return None
    weights = 1.0 / sigmas[inliers] ** 2
    formal = 1.0 / np.sqrt(np.sum(weights))
    birge = np.sqrt(np.sum(weights * (chords[inliers] - estimate) ** 2) / max(used - 1, 1))
    return estimate, float(formal * max(1.0, birge)), inliers


def ground_plane_chord(
    correspondences: Sequence[tuple[Camera, np.ndarray, np.ndarray]],
    T_i_j: np.ndarray,
    axle_x: float,
    options: GroundScaleOptions = GroundScaleOptions(),
) -> GroundChord:
    """Metric chord of the axle midpoint (``axle_x``) between keyframes i and j from road points.

    ``correspondences``: per camera of the body, ``(camera, bearings_i, bearings_j)`` with (N, 3)
    camera-frame bearings of the same points in both keyframes. ``T_i_j``: the body motion
    estimated up to scale (rotation, and the direction of the axle chord). All cameras' road points
    vote on the same chord. Returns a :class:`GroundChord` (``chord``/``sigma`` ``None`` and a
    status when there are too few road points, no motion direction, or too little parallax).
    """
    T_i_j = np.asarray(T_i_j, dtype=float)
    if axle_chord_direction(T_i_j, axle_x) is None:
        return GroundChord(GroundScaleStatus.NO_MOTION_DIRECTION)
    heights = np.array([float(camera.center[2] - options.ground_z) for camera, _, _ in correspondences])
    if heights.size and np.all(heights <= 0.0):
        return GroundChord(GroundScaleStatus.CAMERA_NOT_ABOVE_ROAD)
    per_camera = [point_chords(camera, bearings_i, bearings_j, T_i_j, axle_x, options) for camera, bearings_i, bearings_j in correspondences]
    if sum(points.chord.size for points in per_camera) == 0:
        return GroundChord(GroundScaleStatus.TOO_FEW_GROUND_POINTS)
    parallax = np.concatenate([points.parallax for points in per_camera])
    if parallax.size and float(np.median(parallax)) < options.min_parallax:
        return GroundChord(GroundScaleStatus.SMALL_BASELINE)
    chords = np.concatenate([points.chord[points.candidate] for points in per_camera])
    sigmas = np.concatenate([points.sigma[points.candidate] for points in per_camera])
    consensus = robust_chord(chords, sigmas, options)
    if consensus is None:
        return GroundChord(GroundScaleStatus.TOO_FEW_GROUND_POINTS, candidates=int(chords.size))
    chord, statistical_sigma, inliers = consensus
    masks = []
    offsets = np.cumsum([0] + [int(np.count_nonzero(points.candidate)) for points in per_camera])
    for index, points in enumerate(per_camera):
        mask = np.zeros(points.chord.shape[0], bool)
        mask[np.flatnonzero(points.candidate)] = inliers[offsets[index]:offsets[index + 1]]
        masks.append(mask)
    height_relative = options.height_sigma_m / float(np.mean(heights[heights > 0.0]))
    sigma = float(np.hypot(statistical_sigma, chord * height_relative))
    return GroundChord(GroundScaleStatus.OK, chord, sigma, tuple(masks), int(chords.size))
