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

A trailer that crabs (tyres drifting down a cross-slope, an axle group set off the centre line) moves
at a steady angle ``beta`` to its own x axis: :func:`crabbed_nonholonomic_error` takes it as a
variable, ``e = n(phi/2 + beta) . d`` (the chord then points at ``phi/2 + beta``), so the trailer's
cameras measure the crab instead of the model asserting zero on every pair alike.
"""
from __future__ import annotations

import math

import gtsam
import numpy as np

from factors._checks import check_distinct_keys, check_finite_scalar, check_noise_model
from factors._custom import POSE, make_error_function
from factors._lie import relative_motion, yaw_and_jacobian


def axle_displacement(T_i_j: gtsam.Pose3, axle_x: float) -> tuple[list[list[float]], tuple[float, float, float]]:
    """The rows of ``R`` and the axle midpoint's displacement ``d = R m + t - m`` (module docstring)
    of the motion ``T_i_j = (R, t)``, ``m = (axle_x, 0, 0)``, as Python floats (scalar arithmetic
    is cheaper than numpy on 3-vectors)."""
    rows = T_i_j.rotation().matrix().tolist()
    t_x, t_y, t_z = T_i_j.translation().tolist()
    return rows, (rows[0][0] * axle_x + t_x - axle_x, rows[1][0] * axle_x + t_y, rows[2][0] * axle_x + t_z)


def displacement_gradient(direction: tuple[float, float, float], rows: list[list[float]], axle_x: float) -> list[float]:
    """``d (u . d) / d [omega, v]`` (6,) for a fixed vector ``u``: ``d d / d omega = -R [m]x`` and
    ``d d / d v = R``, so with ``w = R^T u`` it is ``(0, -m w_z, m w_y, w_x, w_y, w_z)``."""
    u_x, u_y, u_z = direction
    w = [u_x * rows[0][k] + u_y * rows[1][k] + u_z * rows[2][k] for k in range(3)]
    return [0.0, -axle_x * w[2], axle_x * w[1], w[0], w[1], w[2]]


def nonholonomic_error(
    T_world_i: gtsam.Pose3,
    T_world_j: gtsam.Pose3,
    axle_x: float,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (1,) of the module docstring (metres) and, if ``jacobians``, two (1, 6) Jacobians
    w.r.t. ``T_world_i`` and ``T_world_j``: ``d e = n . d(d) - (u . d) / 2 d phi`` (``d n(a) / d a
    = -u(a)``, ``u(a) = (cos a, sin a, 0)``)."""
    return _arc_error(T_world_i, T_world_j, axle_x, 0.0, jacobians)[:2]


def crabbed_nonholonomic_error(
    T_world_i: gtsam.Pose3,
    T_world_j: gtsam.Pose3,
    crab: float,
    axle_x: float,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (1,) ``n(phi/2 + beta) . d`` (metres; module docstring, a crabbing trailer) with the
    crab angle ``beta = crab`` (radians) and, if ``jacobians``, the (1, 6), (1, 6) and (1, 1)
    Jacobians by the two poses and the crab angle (``d e / d beta = -u(phi/2 + beta) . d``)."""
    residual, by_poses, by_crab = _arc_error(T_world_i, T_world_j, axle_x, float(np.ravel(crab)[0]), jacobians)
    if not jacobians:
        return residual, None
    return residual, by_poses + [by_crab]


def _arc_error(T_world_i: gtsam.Pose3, T_world_j: gtsam.Pose3, axle_x: float, crab: float,
               jacobians: bool) -> tuple[np.ndarray, list[np.ndarray] | None, np.ndarray | None]:
    """``n(phi/2 + crab) . d`` and, if ``jacobians``, its Jacobians by the poses and by ``crab``."""
    T_i_j, between_i = relative_motion(T_world_i, T_world_j)
    rows, (d_x, d_y, _) = axle_displacement(T_i_j, axle_x)
    yaw_change, yaw_by_omega = yaw_and_jacobian(rows)
    angle = 0.5 * yaw_change + crab
    sine, cosine = math.sin(angle), math.cos(angle)
    residual = np.array([cosine * d_y - sine * d_x])  # n(phi/2 + crab) . d
    if not jacobians:
        return residual, None, None
    gradient = displacement_gradient((-sine, cosine, 0.0), rows, axle_x)
    along = cosine * d_x + sine * d_y  # u(phi/2 + crab) . d
    gradient[1] -= 0.5 * along * yaw_by_omega[1]
    gradient[2] -= 0.5 * along * yaw_by_omega[2]
    jacobian = np.array([gradient])
    return residual, [jacobian @ between_i, jacobian], np.array([[-along]])


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
