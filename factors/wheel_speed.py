"""Wheel-speed (chord length) factor: an optional metric scale source for the tractor.

Residual (DESIGN section 3, optional ``WheelSpeedFactor``), scalar, metres:

    e = |d| - rho,      d = R m + t - m

with ``(R, t) = T_i_j`` the body motion between keyframes, ``m = (axle_x, 0, 0)`` the rigid axle
midpoint and ``rho`` the measured chord length of the axle midpoint (e.g. wheel odometry arc
length L, which exceeds the chord by about ``L^3 kappa^2 / 24`` on an arc of curvature kappa).
Positive when the estimate moved farther than measured. At standstill (``|d| -> 0``) the direction
of ``d`` is undefined and the Jacobian is set to zero.

With the wheel odometry's scale ``s`` as a variable (issue 15: tyre radius, load and wear make
wheel odometry read a per cent or so long or short, a scale the other metric sources calibrate
online; DESIGN 3), the residual is ``e = s |d| - rho`` (metres): ``rho`` measures ``s`` times the
true chord.

A chord measured at the cameras' capture times (DESIGN 11, "Capture-time chords"): a road point
seen ``delay`` seconds after each keyframe's time (the camera's offset and its row's readout)
measures the path between ``t_j + delay`` and ``t_k + delay``, which differs from the keyframes'
chord by ``delay (v_k - v_j)`` (to first order in the delay; a braking truck's reads short). With
each keyframe's speed the derivative of the parabola through its neighbours' path lengths
(three-point rule: exact under constant acceleration), the measured chord is a weighted sum of
consecutive keyframe chords,

    e = sum_i w_i |d_i| - rho,

over the pairs (h, j), (j, k), (k, l) around the measured pair (j, k) (:func:`capture_chord_weights`;
without a keyframe h before, the speed at j is the one that makes the pair's mean speed the mean of
its ends', also exact under constant acceleration).
"""
from __future__ import annotations

import math

import gtsam
import numpy as np

from factors._checks import check_distinct_keys, check_finite_scalar, check_noise_model
from factors._custom import POSE, SCALAR, make_error_function
from factors._lie import relative_motion
from factors.nonholonomic import axle_displacement, displacement_gradient

_MIN_CHORD = 1e-9  # metres


def chord_error(
    T_world_i: gtsam.Pose3,
    T_world_j: gtsam.Pose3,
    axle_x: float,
    chord_length: float,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (1,) of the module docstring (metres) and, if ``jacobians``, two (1, 6) Jacobians."""
    T_i_j, between_i = relative_motion(T_world_i, T_world_j)
    rows, (d_x, d_y, d_z) = axle_displacement(T_i_j, axle_x)
    length = math.sqrt(d_x * d_x + d_y * d_y + d_z * d_z)
    residual = np.array([length - chord_length])
    if not jacobians:
        return residual, None
    if length > _MIN_CHORD:  # d |d| = (d / |d|) . d(d)
        jacobian = np.array([displacement_gradient((d_x / length, d_y / length, d_z / length), rows, axle_x)])
    else:
        jacobian = np.zeros((1, 6))
    return residual, [jacobian @ between_i, jacobian]


def scaled_chord_error(
    T_world_i: gtsam.Pose3,
    T_world_j: gtsam.Pose3,
    wheel_scale: float,
    axle_x: float,
    chord_length: float,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (1,) ``s |d| - rho`` of the module docstring (metres) and, if ``jacobians``, the
    (1, 6), (1, 6) and (1, 1) Jacobians by the two poses and the wheel scale ``s``."""
    length, by_poses = chord_error(T_world_i, T_world_j, axle_x, 0.0, jacobians)
    residual = np.array([wheel_scale * length[0] - chord_length])
    if not jacobians:
        return residual, None
    return residual, [wheel_scale * by_poses[0], wheel_scale * by_poses[1], length.reshape(1, 1)]


def capture_chord_weights(delay_s: float, dt_before_s: float | None, dt_s: float, dt_after_s: float) -> tuple[float, ...]:
    """The weights ``w_i`` of :func:`capture_chord_error` (module docstring) for the pair (j, k)
    measured ``delay_s`` after the keyframe times: ``(w_hj, w_jk, w_kl)`` over the intervals
    ``dt_before_s`` (h-j), ``dt_s`` (j-k) and ``dt_after_s`` (k-l), seconds; ``(w_jk, w_kl)`` when
    ``dt_before_s`` is None (no keyframe before j: ``v_j = 2 L_jk / dt - v_k``). Three-point speeds,
    ``v_k = (L_jk dt_after / dt + L_kl dt / dt_after) / (dt + dt_after)``, and
    ``rho = L_jk + delay (v_k - v_j)``."""
    intervals = [value for value in (dt_before_s, dt_s, dt_after_s) if value is not None]
    if not all(np.isfinite(value) and value > 0.0 for value in intervals) or not np.isfinite(delay_s):
        raise ValueError(f"capture chord: keyframe intervals {intervals} s must be positive, the delay {delay_s} s finite")
    # v_k = a_jk L_jk + a_kl L_kl
    a_jk, a_kl = dt_after_s / dt_s / (dt_s + dt_after_s), dt_s / dt_after_s / (dt_s + dt_after_s)
    if dt_before_s is None:  # the pair's mean speed is that of its ends: v_j = 2 L_jk / dt - v_k
        return 1.0 + 2.0 * delay_s * (a_jk - 1.0 / dt_s), 2.0 * delay_s * a_kl
    b_hj, b_jk = dt_s / dt_before_s / (dt_before_s + dt_s), dt_before_s / dt_s / (dt_before_s + dt_s)  # v_j = b_hj L_hj + b_jk L_jk
    return -delay_s * b_hj, 1.0 + delay_s * (a_jk - b_jk), delay_s * a_kl


def capture_chord_error(
    *T_world: gtsam.Pose3,
    axle_x: float,
    chord_length: float,
    weights: tuple[float, ...],
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (1,) ``sum_i w_i |d_i| - rho`` (metres) of the module docstring over consecutive
    keyframe poses ``T_world`` (one more than ``weights``: the chord ``d_i`` is that from pose i
    to pose i + 1) and, if ``jacobians``, one (1, 6) Jacobian per pose."""
    if len(T_world) != len(weights) + 1:
        raise ValueError(f"capture chord: {len(weights)} weights need {len(weights) + 1} poses, got {len(T_world)}")
    residual = -chord_length
    jacobian_list = [np.zeros((1, 6)) for _ in T_world] if jacobians else None
    for index, weight in enumerate(weights):
        length, by_poses = chord_error(T_world[index], T_world[index + 1], axle_x, 0.0, jacobians)
        residual += weight * length[0]
        if jacobians:
            jacobian_list[index] += weight * by_poses[0]
            jacobian_list[index + 1] += weight * by_poses[1]
    return np.array([residual]), jacobian_list


class WheelSpeedFactor(gtsam.CustomFactor):
    """Chord length of a body's axle midpoint between keyframes i and j (module docstring).

    ``axle_x``: signed axle x in the body frame; ``chord_length`` (m, >= 0); ``noise_model`` of
    dimension 1 in metres; ``scale_key``: a double variable, the wheel odometry's scale ``s``
    (:func:`scaled_chord_error`; None: the wheel is taken as exact, :func:`chord_error`).
    """

    def __init__(self, key_i: int, key_j: int, axle_x: float, chord_length: float, noise_model: gtsam.noiseModel.Base,
                 scale_key: int | None = None) -> None:
        named = {"key_i": key_i, "key_j": key_j} | ({} if scale_key is None else {"scale_key": scale_key})
        keys = check_distinct_keys(named)
        axle_x = check_finite_scalar(axle_x, "axle_x")
        chord_length = check_finite_scalar(chord_length, "chord_length")
        if chord_length < 0.0:
            raise ValueError(f"chord_length must be >= 0, got {chord_length}")
        check_noise_model(noise_model, 1)
        self.axle_x = axle_x
        self.chord_length = chord_length
        self.scaled = scale_key is not None

        if self.scaled:
            def evaluate(T_world_i, T_world_j, wheel_scale, jacobians=False, axle_x=axle_x, chord_length=chord_length):
                return scaled_chord_error(T_world_i, T_world_j, wheel_scale, axle_x, chord_length, jacobians)
            kinds = (POSE, POSE, SCALAR)
        else:
            def evaluate(T_world_i, T_world_j, jacobians=False, axle_x=axle_x, chord_length=chord_length):
                return chord_error(T_world_i, T_world_j, axle_x, chord_length, jacobians)
            kinds = (POSE, POSE)
        super().__init__(noise_model, keys, make_error_function(keys, kinds, evaluate))

    def evaluate(
        self, T_world_i: gtsam.Pose3, T_world_j: gtsam.Pose3, wheel_scale: float | None = None, jacobians: bool = False
    ) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Unwhitened residual (1,) and optionally its Jacobians (:func:`chord_error`, or
        :func:`scaled_chord_error` with ``wheel_scale``)."""
        if wheel_scale is None:
            return chord_error(T_world_i, T_world_j, self.axle_x, self.chord_length, jacobians)
        return scaled_chord_error(T_world_i, T_world_j, wheel_scale, self.axle_x, self.chord_length, jacobians)
