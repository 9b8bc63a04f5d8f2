"""Tractor motion with a change of body attitude between the two views (DESIGN 2.1).

The 2-point solver's motion is planar, ``R = Rz(phi)``. Over a speed bump, under braking or on a
vertical curve the body pitches (and in corners rolls) by up to a degree or two within a pair; a
0.5 degree change already moves every bearing by more than the RANSAC threshold, so no planar motion
fits and the best planar consensus is a few tracks of traffic or the truck itself. Here the motion
is ``R = Rz(phi) Ry(pitch) Rx(roll)`` with the Ackermann translation of ``(phi, rho)`` (paper eq. (3):
the general rotation before its planar form (7)); a grid over the attitude change around seed
motions is scored with the Sampson GEC residual (paper eq. (6)), and the best cell refined by
Levenberg-Marquardt over its inliers in all four parameters (the chord fixed where it is not
observable).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ampc_vo.solvers.estimates import Group
from ampc_vo.solvers.refine import levenberg_marquardt_batch, sampson_residuals
from ampc_vo.solvers.tractor import ackermann_motion
from ampc_vo.solvers.trailer import positive_depth

# grid of the attitude search (radians): pitch and roll changes, yaw offsets around each seed
_PITCH_STEP = float(np.radians(0.5))
_ROLL_STEP = float(np.radians(0.5))
_YAW_OFFSETS = np.radians([-0.3, -0.15, 0.0, 0.15, 0.3])
_CHORD_FACTORS = (0.7, 1.0, 1.4)


@dataclass(frozen=True)
class AttitudeMotion:
    """An Ackermann motion with an attitude change: ``yaw_change`` (phi), ``chord`` (rho, signed),
    ``pitch``, ``roll`` (radians, body j relative to the planar continuation of body i), the
    parameter ``covariance`` (4x4, or 3x3 without the chord when ``chord_fixed``), the ``inliers``
    (M,) over the stacked groups and their MSAC ``cost``."""

    yaw_change: float
    chord: float
    pitch: float
    roll: float
    covariance: np.ndarray
    inliers: np.ndarray
    cost: float
    chord_fixed: bool

    @property
    def chord_sigma(self) -> float:
        return float("inf") if self.chord_fixed else float(np.sqrt(max(self.covariance[1, 1], 0.0)))

    @property
    def yaw_sigma(self) -> float:
        return float(np.sqrt(max(self.covariance[0, 0], 0.0)))


def attitude_rotations(pitch: np.ndarray | float, roll: np.ndarray | float) -> np.ndarray:
    """``Ry(pitch) Rx(roll)`` (..., 3, 3)."""
    pitch, roll = np.broadcast_arrays(np.asarray(pitch, dtype=float), np.asarray(roll, dtype=float))
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    rotation = np.zeros(pitch.shape + (3, 3))
    rotation[..., 0, 0], rotation[..., 0, 1], rotation[..., 0, 2] = cp, sp * sr, sp * cr
    rotation[..., 1, 1], rotation[..., 1, 2] = cr, -sr
    rotation[..., 2, 0], rotation[..., 2, 1], rotation[..., 2, 2] = -sp, cp * sr, cp * cr
    return rotation


def attitude_motion(yaw_change, chord, pitch, roll, axle_x: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``Rz(phi) Ry(pitch) Rx(roll)`` (..., 3, 3) and the Ackermann translation (..., 3)
    of ``(phi, rho)`` (DESIGN 2 (NH)); broadcasting over the parameters."""
    rotation_z, translation = ackermann_motion(yaw_change, chord, axle_x)
    return rotation_z @ attitude_rotations(pitch, roll), translation


def estimate_attitude_motion(
    groups: Sequence[Group], seeds: Sequence[tuple[float, float]], axle_x: float, threshold: float, max_change: float,
    fix_chord: bool = False, iterations: int = 15, rounds: int = 2,
) -> AttitudeMotion | None:
    """The best attitude motion near the ``seeds`` ``(yaw_change, chord)``: a grid of pitch and roll
    changes up to ``max_change`` (radians), yaw offsets and (unless ``fix_chord``) chord factors
    around each seed, scored by the MSAC cost of the Sampson residual at ``threshold``, cheirality
    checked; then Levenberg-Marquardt over the inliers, re-selected ``rounds`` times. None without
    correspondences or seeds."""
    seeds = [(float(yaw), float(chord)) for yaw, chord in seeds if np.isfinite(yaw) and np.isfinite(chord) and chord != 0.0]
    if not seeds or not sum(len(group) for group in groups):
        return None
    pitches = np.arange(-max_change, max_change + 1e-12, _PITCH_STEP)
    rolls = np.arange(-max_change, max_change + 1e-12, _ROLL_STEP)
    factors = (1.0,) if fix_chord else _CHORD_FACTORS
    grid = np.array([(yaw + offset, chord * factor, pitch, roll) for yaw, chord in seeds for offset in _YAW_OFFSETS
                     for factor in factors for pitch in pitches for roll in rolls])
    residual = sampson_residuals(groups, *attitude_motion(grid[:, 0], grid[:, 1], grid[:, 2], grid[:, 3], axle_x))
    inliers = np.abs(residual) < threshold
    cost = np.sum(np.where(inliers, residual**2, threshold**2), axis=1)
    best = int(np.argmin(cost))
    params, mask = grid[best], inliers[best] & _cheiral(groups, grid[best], axle_x)
    chord = params[1]
    free = [0, 2, 3] if fix_chord else [0, 1, 2, 3]

    def residual_batch(rows: np.ndarray) -> np.ndarray:
        full = np.repeat(params[None], len(rows), axis=0)
        full[:, free] = rows
        return sampson_residuals(groups, *attitude_motion(full[:, 0], full[:, 1], full[:, 2], full[:, 3], axle_x))

    covariance = np.full((len(free), len(free)), np.nan)
    for _ in range(max(rounds, 1)):
        if np.count_nonzero(mask) <= len(free):
            return None
        refined, covariances, _, _ = levenberg_marquardt_batch(residual_batch, params[free][None], mask[None].astype(float), iterations)
        params = params.copy()
        params[free] = refined[0]
        covariance = covariances[0]
        values = residual_batch(params[free][None])[0]
        mask = (np.abs(values) < threshold) & _cheiral(groups, params, axle_x)
    if fix_chord:
        params[1] = chord
    return AttitudeMotion(float(params[0]), float(params[1]), float(params[2]), float(params[3]), covariance, mask,
                          float(np.sum(np.where(mask, values**2, threshold**2))), fix_chord)


def _cheiral(groups: Sequence[Group], params: np.ndarray, axle_x: float) -> np.ndarray:
    """Cheirality (M,) of the stacked correspondences under one attitude motion."""
    rotation, translation = attitude_motion(params[0], params[1], params[2], params[3], axle_x)
    parts = [positive_depth(group.bearings_i, group.bearings_j, rotation, translation, group.center) for group in groups if len(group)]
    return np.concatenate(parts) if parts else np.zeros(0, bool)
