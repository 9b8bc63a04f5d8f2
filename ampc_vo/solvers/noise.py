"""The noise of a pair's correspondences measured from themselves (DESIGN 11: the standstill test).

:func:`correspondence_noise` fits each camera's relative motion as an essential matrix (5 degrees of
freedom: any rotation, pitch and roll on the suspension included, and a translation direction) by
least median of squares over 8-point samples (Rousseeuw's LMedS), refits it on the correspondences
within 2.5 robust sigmas, and returns the sigma of the normal core of every correspondence's Sampson
residual under its camera's fit (:func:`robust_sigma`). The Sampson residual spreads a
correspondence's error over its two bearings: bearings with noise of sigma (radians) each give it a
sigma of sigma (DESIGN 2), so the result is the bearings' own noise, whatever the body's motion,
with up to half the correspondences on traffic or mismatched.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ampc_vo.epipolar import ESSENTIAL_SAMPLE, essential_from_bearings, essential_sampson, sampled_essentials
from ampc_vo.solvers.estimates import Group

MAD_TO_SIGMA = 1.4826  # a normal distribution's sigma over its median absolute deviation
_INLIER_SIGMAS = 2.5   # the refit's correspondences: within this many robust sigmas of the best sample's fit
_REFITS = 3           # refits of a camera's essential matrix on its inliers
_CUT_NORMAL_SIGMA = float(np.sqrt(1.0 - 2.0 * _INLIER_SIGMAS * np.exp(-0.5 * _INLIER_SIGMAS**2) / np.sqrt(2.0 * np.pi)
                                  / math.erf(_INLIER_SIGMAS / np.sqrt(2.0))))  # sd of a unit normal cut at +-2.5: 0.955


def correspondence_noise(groups: Sequence[Group], rng: np.random.Generator, samples: int = 256) -> float:
    """Robust sigma (radians) of the correspondences' Sampson residuals under each camera's own
    essential matrix (module docstring); NaN when no camera has more than 2 x 8 correspondences.
    ``samples``: 8-point samples per camera (with 30 % outliers one in 18 is clean; a minimal
    sample's fit under noise is rough, so the best of many: 64 missed at times)."""
    residuals = [_camera_residuals(group, rng, samples) for group in groups if len(group) > 2 * ESSENTIAL_SAMPLE]
    if not residuals:
        return float("nan")
    return robust_sigma(np.concatenate(residuals))


def robust_sigma(residuals: np.ndarray, rounds: int = 3) -> float:
    """Sigma of the normal core of ``residuals`` among outliers: from the median absolute value,
    then ``rounds`` times the root mean square of those within ``_INLIER_SIGMAS`` sigmas over that
    of a normal distribution cut there (the median alone reads 30 % of outliers 1.6 times too high)."""
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(residuals)))
    for _ in range(rounds):
        inside = np.abs(residuals) <= _INLIER_SIGMAS * sigma
        if not inside.any():
            break
        sigma = float(np.sqrt(np.mean(residuals[inside] ** 2))) / _CUT_NORMAL_SIGMA
    return sigma


def _camera_residuals(group: Group, rng: np.random.Generator, samples: int) -> np.ndarray:
    """Sampson residuals (N,) of one camera's correspondences under its LMedS essential matrix,
    refitted up to ``_REFITS`` times on those within ``_INLIER_SIGMAS`` robust sigmas while that
    lowers the robust sigma (a minimal sample's fit is poor under noise: from one, the median alone
    kept outliers in; the linear refit minimises the algebraic error, and once, at a 2.5 m
    chord, went 5 times wide)."""
    essentials = sampled_essentials(group.bearings_i, group.bearings_j, rng, samples)
    residuals = essential_sampson(essentials, group.bearings_i, group.bearings_j)  # (H, N)
    residuals = residuals[int(np.argmin(np.median(np.abs(residuals), axis=1)))]
    sigma = robust_sigma(residuals)
    for _ in range(_REFITS):
        kept = np.abs(residuals) <= _INLIER_SIGMAS * sigma
        if kept.sum() < 2 * ESSENTIAL_SAMPLE:
            break
        refitted = essential_sampson(essential_from_bearings(group.bearings_i[kept], group.bearings_j[kept]), group.bearings_i, group.bearings_j)
        refitted_sigma = robust_sigma(refitted)
        if not refitted_sigma < sigma:  # the linear refit minimises the algebraic error: kept only where it fits better
            break
        residuals, sigma = refitted, refitted_sigma
    return residuals
