"""Mechanical range of the hitch angle: a one-sided (hinge) prior on theta (DESIGN section 3).

A semitrailer's hitch cannot turn beyond its jack-knife stop (the trailer front meets the cab or the
tractor's frame, typically near 90 degrees). The range matters to the estimator because the trailer's
own measurements cannot tell ``theta`` from ``theta + pi`` in straight driving: the Sampson
epipolar residual ignores the sign of the translation (paper eq. (1): ``f'^T [t]x R f`` changes
sign with ``t``) and the non-holonomic constraint holds for a trailer rolling backwards along its
own axis, so a trailer turned around and reversing explains the images as well as the real one.
Residual, radians, zero inside the range:

    e = |theta| - theta_max   if |theta| > theta_max,   else 0;     de/dtheta = sign(theta) or 0
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors._checks import check_finite_scalar, check_key, check_noise_model
from factors._custom import SCALAR, make_error_function


def hitch_limit_error(hitch_angle: float, limit: float, jacobians: bool = False) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (1,) of the module docstring (radians) and, if ``jacobians``, its (1, 1) Jacobian."""
    excess = abs(hitch_angle) - limit
    residual = np.array([excess if excess > 0.0 else 0.0])
    if not jacobians:
        return residual, None
    slope = float(np.sign(hitch_angle)) if excess > 0.0 else 0.0
    return residual, [np.array([[slope]])]


def HitchLimitFactor(key: int, limit: float, noise_model: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """One-sided prior keeping the hitch angle ``key`` (a double) within ``[-limit, limit]`` (radians,
    ``0 < limit < pi``); ``noise_model`` is 1-D (how hard the stop is, radians)."""
    limit = check_finite_scalar(limit, "limit")
    if not 0.0 < limit < np.pi:
        raise ValueError(f"limit must be in (0, pi) radians, got {limit}")
    check_noise_model(noise_model, 1, "HitchLimitFactor")
    keys = [check_key(key)]
    return gtsam.CustomFactor(noise_model, keys, make_error_function(keys, (SCALAR,), lambda theta, jacobians=False: hitch_limit_error(theta, limit, jacobians)))
