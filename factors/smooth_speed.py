"""Smooth-speed prior between three consecutive keyframes of one body (a metric-scale aid).

Trucks accelerate slowly, so the mean speed of the body origin over consecutive keyframe
intervals changes little (issue 5, DESIGN 2.3: scale is weakly observable in straight driving).
For poses ``T_a, T_b, T_c`` (``Pose3`` keys, T_world_body) at times ``t_a < t_b < t_c``:

    r = s(b, c) / (t_c - t_b) - s(a, b) / (t_b - t_a)          [m/s]
    s(i, j) = sign(x_i . (p_j - p_i)) |p_j - p_i|              (signed chord, m)

with ``x_i`` the earlier body's forward axis (first column of ``R_i``): the signed speed of the
body origin, negative reversing. A velocity changes smoothly through a stop, so a reversal costs
what its change of velocity costs; the unsigned magnitude made a chord of the wrong sign at the
previous speed free (the realistic stop_and_go: -0.95 m where the truck braked 0.14 m forward,
the GEC being nearly blind to the chord's sign). The sign is piecewise constant: it only switches
where the chord is perpendicular to the body, which a non-holonomic body does only at rest.

Analytic Jacobians (right perturbation, tangent order ``[omega, v]``, so ``dp = R dv``):
``d s(b, c) / dxi_c = sign [0, u^T R_c]`` with ``u`` the unit chord direction, and so on. Near a
standstill (chord < 1e-6 m) the direction is undefined and that chord's Jacobian is set to zero.
"""
from __future__ import annotations

import math
from functools import partial

import gtsam
import numpy as np

from factors._checks import check_distinct_keys
from factors._custom import POSE, make_error_function

_MIN_CHORD_M = 1e-6


def _chord_and_gradients(T_from: gtsam.Pose3, T_to: gtsam.Pose3) -> tuple[float, np.ndarray, np.ndarray]:
    """The signed chord ``s(from, to)`` (module docstring, m) and its (1, 6) Jacobians w.r.t.
    ``T_from`` and ``T_to`` (``u^T R`` is ``R.unrotate(u)``: one gtsam call instead of numpy on
    3-vectors)."""
    delta = T_to.translation() - T_from.translation()
    length = math.sqrt(float(delta @ delta))
    H_from, H_to = np.zeros((1, 6)), np.zeros((1, 6))
    if length <= _MIN_CHORD_M:
        return length, H_from, H_to
    direction = delta / length
    forward_from = T_from.rotation().unrotate(direction)  # the chord's direction in the earlier body's frame
    sign = 1.0 if forward_from[0] >= 0.0 else -1.0
    H_to[0, 3:] = sign * T_to.rotation().unrotate(direction)
    H_from[0, 3:] = -sign * forward_from
    return sign * length, H_from, H_to


def smooth_speed_error(
    T_a: gtsam.Pose3, T_b: gtsam.Pose3, T_c: gtsam.Pose3, dt_first: float, dt_second: float, jacobians: bool = False
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (1,) of the module docstring (m/s) and, if ``jacobians``, three (1, 6) Jacobians."""
    chord_first, H_first_a, H_first_b = _chord_and_gradients(T_a, T_b)
    chord_second, H_second_b, H_second_c = _chord_and_gradients(T_b, T_c)
    residual = np.array([chord_second / dt_second - chord_first / dt_first])
    if not jacobians:
        return residual, None
    return residual, [-H_first_a / dt_first, H_second_b / dt_second - H_first_b / dt_first, H_second_c / dt_second]


def SmoothSpeedFactor(key_a: int, key_b: int, key_c: int, dt_first: float, dt_second: float, noise_model: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """Prior that the signed speed over ``(a, b)`` (``dt_first`` s) equals the one over ``(b, c)``
    (``dt_second`` s); ``noise_model`` is 1-D, in m/s (e.g. acceleration sigma times the mean dt)."""
    if not (dt_first > 0.0 and dt_second > 0.0):
        raise ValueError(f"SmoothSpeedFactor needs positive intervals, got {dt_first}, {dt_second}")
    if noise_model.dim() != 1:
        raise ValueError(f"SmoothSpeedFactor needs a 1-D noise model, got dimension {noise_model.dim()}")
    keys = check_distinct_keys({"key_a": key_a, "key_b": key_b, "key_c": key_c})
    evaluate = partial(smooth_speed_error, dt_first=float(dt_first), dt_second=float(dt_second))
    return gtsam.CustomFactor(noise_model, keys, make_error_function(keys, (POSE, POSE, POSE), evaluate))
