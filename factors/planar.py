"""Planar motion factor: relative roll, pitch and height of a body between keyframes near zero.

Residual (DESIGN sections 1, 3: the planar model enforced softly), 3-D:

    e = [roll, pitch, t_z]      (radians, radians, metres)

of the body motion ``(R, t) = T_i_j = T_world_i^-1 T_world_j``, with ``R = Rz(yaw) Ry(pitch)
Rx(roll)`` (ZYX order, as ``gtsam.Rot3.RzRyRx``): ``roll = atan2(R21, R22)``, ``pitch =
atan2(-R20, sqrt(R21^2 + R22^2))``, and ``t_z`` the height change expressed in body frame i. Yaw
and the horizontal translation are free. Valid for ``|pitch| < 90 deg``.
"""
from __future__ import annotations

import math

import gtsam
import numpy as np

from factors._checks import check_distinct_keys, check_noise_model
from factors._custom import POSE, make_error_function
from factors._lie import relative_motion

def planar_motion_error(
    T_world_i: gtsam.Pose3,
    T_world_j: gtsam.Pose3,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (3,) of the module docstring and, if ``jacobians``, two (3, 6) Jacobians w.r.t.
    ``T_world_i`` and ``T_world_j``.

    Scalar arithmetic on the last row ``r2 = (r20, r21, r22)`` of ``R`` (a few numpy calls per
    evaluation instead of dozens on 3-vectors: the smoother's hot path). With ``d r2 / d omega =
    r2 x omega`` (right perturbation ``R Exp(omega)``) and ``h = |(r21, r22)|``::

        d roll / d omega  = (h^2, -r21 r20, -r22 r20) / h^2
        d h / d omega     = (0, r22 r20, -r21 r20) / h
        d pitch / d omega = (0, h r22, -h r21) + r20 d h / d omega     (r20^2 + h^2 = 1)
        d t_z / d v       = r2
    """
    T_i_j, between_i = relative_motion(T_world_i, T_world_j)
    r20, r21, r22 = T_i_j.rotation().matrix()[2].tolist()
    horizontal = math.hypot(r21, r22)
    residual = np.array([math.atan2(r21, r22), math.atan2(-r20, horizontal), T_i_j.z()])
    if not jacobians:
        return residual, None
    squared = horizontal * horizontal
    roll_by_omega = ((r22 * r22 + r21 * r21) / squared, -(r21 * r20) / squared, -(r22 * r20) / squared)
    horizontal_by_omega_1, horizontal_by_omega_2 = r22 * r20 / horizontal, -(r21 * r20) / horizontal
    pitch_by_omega = (0.0, horizontal * r22 + r20 * horizontal_by_omega_1, -(horizontal * r21) + r20 * horizontal_by_omega_2)
    jacobian = np.array([
        [*roll_by_omega, 0.0, 0.0, 0.0],
        [*pitch_by_omega, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, r20, r21, r22],
    ])
    return residual, [jacobian @ between_i, jacobian]


def planar_sigmas(
    lateral_acceleration: float,
    longitudinal_acceleration: float,
    floor: float,
    roll_per_acceleration: float,
    pitch_per_acceleration: float,
    height_sigma: float,
) -> np.ndarray:
    """Sigmas (3,) of the residual ``[roll, pitch, t_z]`` (radians, radians, metres) over a keyframe
    pair as tight as a sprung body allows: a ``floor`` (radians: road unevenness, vibration) and the
    suspension's quasi-static response, roll ``G_roll a_y`` and pitch ``G_pitch a_x`` (gains in
    radians per m/s^2; trucks 0.4-0.9 and 0.1-0.35 degrees per m/s^2, Gillespie, Fundamentals of
    Vehicle Dynamics, ch. 5), added in quadrature: the attitude may change between the keyframes by
    the gain times the acceleration (|m/s^2|) that sets in or ends within the pair."""
    roll = np.hypot(floor, roll_per_acceleration * abs(lateral_acceleration))
    pitch = np.hypot(floor, pitch_per_acceleration * abs(longitudinal_acceleration))
    return np.array([roll, pitch, height_sigma])


class PlanarMotionFactor(gtsam.CustomFactor):
    """Soft planar-motion constraint on two ``Pose3`` keys ``T_world_body`` (module docstring).

    ``noise_model`` has dimension 3 (roll rad, pitch rad, height m), e.g.
    ``gtsam.noiseModel.Diagonal.Sigmas([0.01, 0.01, 0.02])`` for a mildly uneven road.
    """

    def __init__(self, key_i: int, key_j: int, noise_model: gtsam.noiseModel.Base) -> None:
        keys = check_distinct_keys({"key_i": key_i, "key_j": key_j})
        check_noise_model(noise_model, 3)
        super().__init__(noise_model, keys, make_error_function(keys, (POSE, POSE), planar_motion_error))

    @staticmethod
    def evaluate(
        T_world_i: gtsam.Pose3, T_world_j: gtsam.Pose3, jacobians: bool = False
    ) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Unwhitened residual (3,) and optionally its Jacobians (see :func:`planar_motion_error`)."""
        return planar_motion_error(T_world_i, T_world_j, jacobians)
