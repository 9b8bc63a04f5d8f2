"""Small ``Pose3`` helpers shared by the factors (GTSAM right perturbations, tangent ``[omega, v]``).

Conventions (DESIGN sections 1, 3): variables are ``T_world_body`` as ``gtsam.Pose3``; a pose is
perturbed as ``T Exp(xi)``; the relative motion between keyframes is ``T_i_j = T_world_i^-1
T_world_j``. The hitch rotation ``(Rz(theta), 0)`` is perturbed as ``theta + delta``, which is
the right perturbation ``Exp([0, 0, delta, 0, 0, 0])`` of the hitch pose.
"""
from __future__ import annotations

import math
from typing import Sequence

import gtsam
import numpy as np

ZERO_TRANSLATION = np.zeros(3)


def relative_motion(T_world_i: gtsam.Pose3, T_world_j: gtsam.Pose3) -> tuple[gtsam.Pose3, np.ndarray]:
    """``T_i_j = T_world_i^-1 T_world_j`` and its Jacobian (6, 6) w.r.t. ``T_world_i``.

    The Jacobian w.r.t. ``T_world_j`` is the identity (``-Ad(T_i_j^-1)`` w.r.t. ``T_world_i``).
    """
    jacobian_i = np.zeros((6, 6), order="F")
    T_i_j = T_world_i.between(T_world_j, jacobian_i)
    return T_i_j, jacobian_i


def hitch_pose(hitch_angle: float) -> gtsam.Pose3:
    """``T_tractor_trailer = (Rz(theta), 0)``: both body frames have their origin at the hitch."""
    return gtsam.Pose3(gtsam.Rot3.Rz(hitch_angle), ZERO_TRANSLATION)


def trailer_from_tractor(
    T_world_tractor: gtsam.Pose3, hitch_angle: float
) -> tuple[gtsam.Pose3, np.ndarray]:
    """``T_world_trailer = T_world_tractor (Rz(theta), 0)`` (paper eqs. (3)-(5)) and its Jacobian
    (6, 6) w.r.t. the tractor pose (``Ad((Rz(theta), 0)^-1)``); w.r.t. theta it is the unit column
    ``[0, 0, 1, 0, 0, 0]``."""
    jacobian_tractor = np.zeros((6, 6), order="F")
    jacobian_hitch = np.zeros((6, 6), order="F")
    T_world_trailer = T_world_tractor.compose(hitch_pose(hitch_angle), jacobian_tractor, jacobian_hitch)
    return T_world_trailer, jacobian_tractor


def yaw_and_jacobian(rotation: Sequence[Sequence[float]]) -> tuple[float, tuple[float, float, float]]:
    """Yaw ``phi = atan2(R10, R00)`` of a rotation (its z-rotation in the ZYX order) and
    ``d phi / d omega`` (3,) for the right perturbation ``R Exp(omega)``; ``rotation`` indexed
    ``[row][column]`` (array or nested lists; scalar arithmetic).

    ``d R_k0 = (R [omega]x)_k0 = R_k1 omega_z - R_k2 omega_y``; undefined when ``R00 = R10 = 0``
    (pitch of +-90 degrees), which a road vehicle never reaches.
    """
    (r00, r01, r02), (r10, r11, r12) = rotation[0], rotation[1]
    scale = 1.0 / (r00 * r00 + r10 * r10)
    return math.atan2(r10, r00), (0.0, (r10 * r02 - r00 * r12) * scale, (r00 * r11 - r10 * r01) * scale)
