"""Non-holonomic (circular-arc, Ackermann) factor of one body between two keyframes.

Residual (DESIGN section 2, (NH)), scalar, metres:

    e = n(phi/2) . d,     d = R m + t - m,     n(a) = (-sin a, cos a, 0)

with ``(R, t) = T_i_j = T_world_i^-1 T_world_j`` the body motion, ``m = (axle_x, 0, 0)`` the
midpoint of the body's rigid axle (signed: tractor usually >= 0, trailer < 0) and ``d`` the axle
midpoint's displacement expressed in body frame i. ``e`` is the lateral offset (left positive)
of the axle displacement from the chord direction ``u(phi/2)``: on an exact circular arc the chord
points at half the yaw change, so ``e = 0``. It is independent of the chord length (e = 0 at
standstill too).

Yaw change for 3-D poses: ``phi = atan2(R10, R00)``, the z-angle of ``R`` in the ZYX (yaw,
pitch, roll) order, which equals the planar yaw change when ``R = Rz(phi)`` and stays smooth for
small roll and pitch; the Jacobian differentiates exactly this definition (``R Exp(omega)``).
Valid for ``|phi| < pi`` (the residual flips sign when phi wraps), far beyond keyframe motion.
Tyre slip breaks the model by up to ~1.5 degrees in hard cornering: use a robust noise model.
"""
from __future__ import annotations

import gtsam
import numpy as np

from ampc_vo.geometry import skew
from factors._checks import check_distinct_keys, check_finite_scalar, check_noise_model
from factors._custom import POSE, make_error_function
from factors._lie import relative_motion, yaw_and_jacobian


def axle_displacement(rotation: np.ndarray, translation: np.ndarray, axle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``d = R m + t - m`` and ``d d / d omega = -R [m]x`` (3, 3); ``d d / d v = R``."""
    return rotation @ axle + translation - axle, -rotation @ skew(axle)


def nonholonomic_error(
    T_world_i: gtsam.Pose3,
    T_world_j: gtsam.Pose3,
    axle_x: float,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (1,) of the module docstring (metres) and, if ``jacobians``, two (1, 6) Jacobians
    w.r.t. ``T_world_i`` and ``T_world_j``."""
    T_i_j, between_i = relative_motion(T_world_i, T_world_j)
    rotation = T_i_j.rotation().matrix()
    axle = np.array([axle_x, 0.0, 0.0])
    displacement, displacement_by_omega = axle_displacement(rotation, T_i_j.translation(), axle)
    yaw_change, yaw_by_omega = yaw_and_jacobian(rotation)
    half = 0.5 * yaw_change
    normal = np.array([-np.sin(half), np.cos(half), 0.0])
    residual = np.array([normal @ displacement])
    if not jacobians:
        return residual, None
    heading = np.array([np.cos(half), np.sin(half), 0.0])  # d n(a) / d a = -u(a)
    jacobian = np.empty((1, 6))
    jacobian[0, :3] = normal @ displacement_by_omega - 0.5 * (heading @ displacement) * yaw_by_omega
    jacobian[0, 3:] = normal @ rotation
    return residual, [jacobian @ between_i, jacobian]


class NonHolonomicFactor(gtsam.CustomFactor):
    """Circular-arc constraint of a body's rigid axle between keyframes i and j (module docstring).

    One class for both bodies: ``axle_x`` is the signed x of the axle midpoint in the body frame
    (tractor ``axle_x`` >= 0 usually, trailer ``axle_x = -s_B`` < 0). Keys: two ``Pose3``
    ``T_world_body``; ``noise_model`` of dimension 1, in metres.
    """

    def __init__(self, key_i: int, key_j: int, axle_x: float, noise_model: gtsam.noiseModel.Base) -> None:
        keys = check_distinct_keys({"key_i": key_i, "key_j": key_j})
        axle_x = check_finite_scalar(axle_x, "axle_x")
        check_noise_model(noise_model, 1)

        def evaluate(T_world_i, T_world_j, jacobians=False, axle_x=axle_x):
            return nonholonomic_error(T_world_i, T_world_j, axle_x, jacobians)

        super().__init__(noise_model, keys, make_error_function(keys, (POSE, POSE), evaluate))
        self.axle_x = axle_x

    def evaluate(
        self, T_world_i: gtsam.Pose3, T_world_j: gtsam.Pose3, jacobians: bool = False
    ) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Unwhitened residual (1,) and optionally its Jacobians (see :func:`nonholonomic_error`)."""
        return nonholonomic_error(T_world_i, T_world_j, self.axle_x, jacobians)
