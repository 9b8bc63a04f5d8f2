"""Configuration, correspondence groups and result types of the tractor/trailer estimators."""
from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ampc_vo.errors import BearingError
from ampc_vo.solvers.status import SolverStatus

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RansacConfig:
    """Options of :func:`estimate_tractor_motion` and :func:`estimate_hitch_angles` (radians, metres).

    ``sampson_threshold``: inlier threshold on the Sampson GEC residual (about 3 sigma, sigma =
    pixel noise / focal). ``confidence``, ``min_iterations``, ``max_iterations``, ``batch_size``:
    adaptive sample count (hypotheses are drawn and scored in batches). ``min_inliers``: fewer
    gives ``NO_CONSENSUS``; so does a tractor motion with inliers below ``min_inlier_fraction`` of
    the correspondences (a planar motion that fits a few of them: pitch over a bump, traffic).
    ``max_attitude_change`` (radians; 0: planar only): where the planar motion explains less than
    ``attitude_fraction`` of the correspondences, a pitch and roll change up to this is searched
    (:mod:`ampc_vo.solvers.attitude`: the body pitches over bumps and under braking). ``min_chord``: a tractor displacement below this is a standstill.
    ``standstill_parallax``: median angle between the two bearings of a correspondence below
    which nothing moved (a planar truck cannot rotate in place). ``min_camera_axle_offset``:
    cameras closer than this to the axle in x give no scale (DESIGN 2.1).
    ``chord_direction_sigma``: error of the Ackermann model's chord direction (DESIGN 2: about
    kappa' L^2 / 12 in curvature transitions, more with tyre slip), added to the refined chord's
    sigma as ``chord^2 sigma / (|yaw change| p_x)`` (p_x: the largest camera offset from the axle):
    at small yaw changes the scale hinges on that direction. ``max_relative_chord_sigma``: above
    this relative standard deviation of the refined chord
    (or a chord beyond ``max_chord``, where a flat cost lets the refinement wander), the scale is
    reported unobservable. ``max_hitch_angle``: admissible |theta|, |theta'|. ``prior_gate``:
    hitch hypotheses farther than this from the prior hitch angle are dropped when any hypothesis
    inside the gate exists.

    Refinement (``refine``): ``local_optimizations`` best hypotheses are refined (LO-RANSAC) and
    the lowest MSAC cost after refinement wins; ``chord_seeds``: the best hypothesis is also
    refined from its chord times these factors (the chord is the weakly observed direction). A
    refined basin whose chord differs by more than 3 sigma and whose MSAC cost is within
    ``ambiguity_points`` outliers' worth (``threshold^2`` each) of the best makes the scale
    ambiguous (``SCALE_UNOBSERVABLE``): the chord would hinge on single correspondences.
    ``refine_rounds``: inlier re-selection rounds of the tractor's least-squares refinement and
    reweighting rounds of the trailer's robust (Cauchy) refinement; ``refine_iterations``:
    Levenberg-Marquardt iterations. For speed over robustness use ``local_optimizations=1,
    chord_seeds=()`` (about 2.5x faster, see scripts/benchmark_solvers.py). ``seed``: RNG seed
    used when no generator is passed.
    """

    sampson_threshold: float = 0.004
    confidence: float = 0.999
    min_iterations: int = 16
    max_iterations: int = 500
    batch_size: int = 32
    min_inliers: int = 8
    min_inlier_fraction: float = 0.0
    max_attitude_change: float = 0.0
    attitude_fraction: float = 0.6
    min_chord: float = 0.05
    max_chord: float = 20.0
    standstill_parallax: float = 0.003
    min_camera_axle_offset: float = 0.05
    max_relative_chord_sigma: float = 0.3
    chord_direction_sigma: float = 0.0   # rad: model error of the chord direction (changing curvature, slip)
    max_hitch_angle: float = 0.5 * np.pi
    prior_gate: float = np.deg2rad(15.0)
    refine: bool = True
    refine_rounds: int = 3
    local_optimizations: int = 3
    chord_seeds: tuple[float, ...] = (0.5, 2.0)
    ambiguity_points: float = 1.0
    refine_iterations: int = 15
    seed: int | None = 0


@dataclass(frozen=True)
class Group:
    """Valid correspondences of one camera (body-frame unit bearings (N, 3), centre (3,)) and the
    indices ``rows`` (N,) they occupy in the caller's arrays of length ``size``."""

    bearings_i: np.ndarray
    bearings_j: np.ndarray
    center: np.ndarray
    rows: np.ndarray
    size: int

    def __len__(self) -> int:
        return int(self.rows.shape[0])

    def subset(self, mask: np.ndarray) -> "Group":
        return Group(self.bearings_i[mask], self.bearings_j[mask], self.center, self.rows[mask], self.size)

    def full_mask(self, mask: np.ndarray) -> np.ndarray:
        """Scatter a mask over the valid rows back to the caller's length (invalid rows False)."""
        full = np.zeros(self.size, dtype=bool)
        full[self.rows[mask]] = True
        return full


def as_groups(correspondences: Sequence[Any]) -> list[Group]:
    """Validate per-camera correspondences: ``(bearings_i, bearings_j, center)`` tuples or objects
    with ``as_group()``. Rows with NaN/inf/zero bearings are dropped (logged), so degenerate input
    becomes a status later; wrong shapes raise :class:`BearingError`."""
    groups = []
    for index, item in enumerate(correspondences):
        bearings_i, bearings_j, center = item.as_group() if hasattr(item, "as_group") else item
        bearings_i, bearings_j = (np.asarray(b, dtype=float) for b in (bearings_i, bearings_j))
        bearings_i, bearings_j = (b.reshape(0, 3) if b.size == 0 else b for b in (bearings_i, bearings_j))
        center = np.asarray(center, dtype=float)
        if bearings_i.ndim != 2 or bearings_i.shape[1] != 3 or bearings_j.shape != bearings_i.shape:
            raise BearingError(f"group {index}: bearings_i and bearings_j must both have shape (N, 3), got {bearings_i.shape} and {bearings_j.shape}")
        if center.shape != (3,) or not np.all(np.isfinite(center)):
            raise BearingError(f"group {index}: camera centre must be a finite 3-vector, got {center}")
        with np.errstate(invalid="ignore", over="ignore"):
            norm_i = np.linalg.norm(bearings_i, axis=1)
            norm_j = np.linalg.norm(bearings_j, axis=1)
            valid = np.isfinite(norm_i) & np.isfinite(norm_j) & (norm_i > 1e-12) & (norm_j > 1e-12)
        if not np.all(valid):
            logger.debug("group %d: dropped %d invalid bearing rows", index, int(np.sum(~valid)))
        rows = np.flatnonzero(valid)
        groups.append(
            Group(bearings_i[rows] / norm_i[rows, None], bearings_j[rows] / norm_j[rows, None], center, rows, len(bearings_i))
        )
    return groups


def chord_is_observable(chord: float, chord_sigma: float, config: RansacConfig) -> bool:
    """The refined chord is trustworthy: finite, below ``max_chord`` and with relative standard
    deviation below ``max_relative_chord_sigma`` (DESIGN 2.3: scale is weak on gentle curves)."""
    return bool(
        np.isfinite(chord) and np.isfinite(chord_sigma) and abs(chord) <= config.max_chord
        and chord_sigma <= config.max_relative_chord_sigma * max(abs(chord), config.min_chord)
    )


def parallax(group: Group) -> np.ndarray:
    """Angle (radians) between the two body-frame bearings of each correspondence of ``group``."""
    return np.arccos(np.clip(np.sum(group.bearings_i * group.bearings_j, axis=1), -1.0, 1.0))


# median parallax of still points in units of the pixel noise: two noisy observations differ by a
# Rayleigh distance of scale sqrt(2) sigma, median sqrt(2 ln 2) sqrt(2) sigma
STILL_PARALLAX_SIGMAS = 2.0 * float(np.sqrt(np.log(2.0)))  # 1.665


def median_parallax(groups: Sequence[Group]) -> float:
    """Median angle (radians) between the two body-frame bearings of each correspondence."""
    angles = np.concatenate([parallax(group) for group in groups] or [np.zeros(0)])
    return float(np.median(angles)) if angles.size else 0.0


def attitude_compensated_parallax(groups: Sequence[Group], rounds: int = 3) -> np.ndarray:
    """Each correspondence's parallax (radians, the groups' correspondences stacked) left after the
    pitch and roll change that best explains the pair as a pure rotation: a truck at rest whose body
    pitches or rolls on its suspension (braking to rest, the rebound after a stop) moves every
    bearing, but not as a translation does. Small-angle least squares ``b_i = b_j + w x b_j`` with
    ``w = (roll, pitch, 0)`` (no yaw: a truck cannot turn on the spot), refitted ``rounds`` times on
    the better half of the correspondences (tracks on traffic, outliers). The bearings are the
    body frame's from each camera's centre: a camera ``c`` off the body origin keeps ``|w x c| /
    depth`` of a body rotation ``w`` (a fraction of a pixel at road depths)."""
    bearings_i = np.concatenate([group.bearings_i for group in groups] or [np.zeros((0, 3))])
    bearings_j = np.concatenate([group.bearings_j for group in groups] or [np.zeros((0, 3))])
    if len(bearings_i) < 2:
        return np.concatenate([parallax(group) for group in groups] or [np.zeros(0)])
    difference = bearings_i - bearings_j
    # b_i - b_j = w x b_j = -[b_j]x w: the roll (x) and pitch (y) columns of [b_j]x (w's sign is the fit's)
    x, y, z = bearings_j.T
    zero = np.zeros_like(x)
    jacobian = np.stack([np.column_stack([zero, z, -y]), np.column_stack([-z, zero, x])], axis=2)  # (N, 3, 2)
    used = np.ones(len(bearings_i), dtype=bool)
    residual = np.linalg.norm(difference, axis=1)
    for _ in range(max(rounds, 1)):
        rotation, *_ = np.linalg.lstsq(jacobian[used].reshape(-1, 2), difference[used].reshape(-1), rcond=None)
        residual = np.linalg.norm(difference - jacobian @ rotation, axis=1)
        used = residual <= np.median(residual)
    return residual


@dataclass
class TractorMotionEstimate:
    """Result of :func:`estimate_tractor_motion`.

    ``yaw_change`` (phi) and ``chord`` (rho) of the Ackermann arc (DESIGN 2 (NH)), ``T_i_j`` the
    tractor motion (None when not usable or when the chord is unknown), ``inlier_masks`` one bool
    array per input group (length of that group's input), ``yaw_sigma``/``chord_sigma`` standard
    deviations from the refinement (NaN if not computed).
    """

    status: SolverStatus
    yaw_change: float = float("nan")
    chord: float = float("nan")
    T_i_j: np.ndarray | None = None
    inlier_masks: list[np.ndarray] = field(default_factory=list)
    num_inliers: int = 0
    num_hypotheses: int = 0
    yaw_sigma: float = float("nan")
    chord_sigma: float = float("nan")
    chord_sign: float = 1.0
    rms_residual: float = float("nan")
    attitude: tuple[float, float] = (0.0, 0.0)  # pitch, roll change (radians) in T_i_j beyond the planar motion
    # a standstill the pair's own noise explains: the median parallax (radians) below which it is one
    # (ransac._noise_standstill; NaN where the configured standstill_parallax decided)
    noise_still_parallax: float = float("nan")

    @property
    def ok(self) -> bool:
        return self.status is SolverStatus.OK

    @property
    def translation(self) -> np.ndarray | None:
        return None if self.T_i_j is None else self.T_i_j[:3, 3].copy()


@dataclass
class HitchEstimate:
    """Result of :func:`estimate_hitch_angles`: hitch angles before/after (``theta``, ``theta'``),
    trailer yaw change ``psi`` and motion ``T_trailer_i_j`` (paper eqs. (3), (4)), the sign of the
    trailer chord, per-group inlier masks and the standard deviation of ``theta``."""

    status: SolverStatus
    hitch_angle_i: float = float("nan")
    hitch_angle_j: float = float("nan")
    trailer_yaw_change: float = float("nan")
    chord_sign: float = 1.0
    T_trailer_i_j: np.ndarray | None = None
    inlier_masks: list[np.ndarray] = field(default_factory=list)
    num_inliers: int = 0
    num_hypotheses: int = 0
    hitch_angle_sigma: float = float("nan")
    rms_residual: float = float("nan")

    @property
    def ok(self) -> bool:
        return self.status is SolverStatus.OK


@dataclass
class JointEstimate:
    """Result of :func:`refine_joint` over (phi, rho, psi) (or (phi, rho, theta, theta') without
    the trailer non-holonomic constraint). ``covariance`` is over those parameters."""

    status: SolverStatus
    yaw_change: float
    chord: float
    hitch_angle_i: float
    hitch_angle_j: float
    trailer_yaw_change: float
    T_i_j: np.ndarray
    T_trailer_i_j: np.ndarray
    covariance: np.ndarray
    rms_residual: float
    trailer_nonholonomic: bool = True

    @property
    def ok(self) -> bool:
        return self.status is SolverStatus.OK
