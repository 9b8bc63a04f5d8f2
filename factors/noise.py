"""Noise models for the factors: isotropic Gaussian with optional per-residual Huber weighting.

DESIGN section 3: a vectorised factor stacks N residuals, so the robust kernel must weight each
residual on its own (``ReweightScheme.Scalar``); the default ``Block`` scheme weights the whole
factor by the norm of all N residuals, so one outlier down-weights every inlier of the camera.
"""
from __future__ import annotations

import numbers

import gtsam

from factors._checks import check_positive_scalar

_HUBER = gtsam.noiseModel.mEstimator.Huber
_SCHEME = gtsam.noiseModel.mEstimator.Base.ReweightScheme


def robust_noise(sigma: float, dim: int, huber_k: float | None = 1.345, *, per_residual: bool = True) -> gtsam.noiseModel.Base:
    """``Robust(Huber(huber_k, Scalar), Isotropic(dim, sigma))``, or the Gaussian if ``huber_k`` is None.

    ``sigma`` in residual units (Sampson GEC: pixel sigma / focal length, radians); ``huber_k`` in
    units of sigma (1.345 gives 95% efficiency on Gaussian noise). ``per_residual=False`` selects
    the ``Block`` scheme (for comparison only).
    """
    sigma = check_positive_scalar(sigma, "sigma")
    if isinstance(dim, bool) or not isinstance(dim, numbers.Integral) or dim < 1:
        raise ValueError(f"dim must be a positive integer, got {dim!r}")
    base = gtsam.noiseModel.Isotropic.Sigma(int(dim), sigma)
    if huber_k is None:
        return base
    huber_k = check_positive_scalar(huber_k, "huber_k")
    scheme = _SCHEME.Scalar if per_residual else _SCHEME.Block
    return gtsam.noiseModel.Robust.Create(_HUBER.Create(huber_k, scheme), base)
