"""Joint loop factor: tractor pose, trailer pose and hitch angle of one keyframe are consistent.

Residual (paper eqs. (3)-(5); DESIGN sections 1, 3), 6-D in GTSAM tangent order ``[omega, v]``:

    e = Log( (T_world_tractor (Rz(theta), 0))^-1 T_world_trailer )      (radians, metres)

Both body frames have their origin at the hitch centre, so ``T_tractor_trailer = (Rz(theta), 0)``
and ``e = 0`` exactly when the trailer pose follows from the tractor pose and the hitch angle
(``theta = yaw_trailer - yaw_tractor``, positive counter-clockwise seen from above). ``e`` is the
trailer's pose error expressed in the trailer frame (right perturbation): ``e[2]`` > 0 when the
trailer is rotated counter-clockwise beyond ``theta``, ``e[3:]`` the hitch separation in metres.
Variables: two ``Pose3`` (``T_world_tractor``, ``T_world_trailer``) and the hitch angle
``theta`` as a ``double`` value (radians).
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors._checks import check_distinct_keys, check_noise_model
from factors._custom import POSE, SCALAR, make_error_function
from factors._lie import trailer_from_tractor


def joint_loop_error(
    T_world_tractor: gtsam.Pose3,
    T_world_trailer: gtsam.Pose3,
    hitch_angle: float,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (6,) of the module docstring and, if ``jacobians``, ``[(6, 6), (6, 6), (6, 1)]``
    w.r.t. the tractor pose, the trailer pose and the hitch angle."""
    predicted_trailer, predicted_from_tractor = trailer_from_tractor(T_world_tractor, float(hitch_angle))
    if not jacobians:
        return gtsam.Pose3.Logmap(predicted_trailer.between(T_world_trailer)), None
    between_predicted = np.zeros((6, 6), order="F")
    error_pose = predicted_trailer.between(T_world_trailer, between_predicted)  # by T_world_trailer: the identity
    # zeros, not empty: gtsam 4.3 Pose3.Logmap leaves part of H unwritten for near-identity poses (NaN garbage)
    log_jacobian = np.zeros((6, 6), order="F")
    residual = gtsam.Pose3.Logmap(error_pose, log_jacobian)
    by_predicted = log_jacobian @ between_predicted
    # d predicted / d theta = [0, 0, 1, 0, 0, 0] (right perturbation of (Rz(theta), 0) about z)
    return residual, [by_predicted @ predicted_from_tractor, log_jacobian, by_predicted[:, 2:3].copy()]


def _rz(angle: float) -> tuple[np.ndarray, np.ndarray]:
    """``Rz(angle)`` and its derivative by ``angle`` (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array([[-s, -c, 0.0], [c, -s, 0.0], [0.0, 0.0, 0.0]])


def fifth_wheel_error(
    T_world_tractor: gtsam.Pose3,
    T_world_trailer: gtsam.Pose3,
    hitch_angle: float,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """The joint loop residual expressed in the tractor's axes, ``blockdiag(Rz(theta), Rz(theta)) e``
    (6,), so that each component is one degree of freedom of a fifth wheel: ``[0]`` roll about the
    tractor's x axis (rigid), ``[1]`` pitch of the plate about the tractor's y axis (free: a noise
    model with a wide sigma there), ``[2]`` yaw beyond ``theta``, ``[3:]`` king-pin separation (m).
    With ``R_tractor_trailer = Ry(beta) Rz(theta)`` (the plate pitched by ``beta``, the trailer
    turned by ``theta`` on it; paper eqs. (3)-(5) with the general joint rotation ``Q``),
    ``e_rot = Rz(-theta) beta e_y`` and this residual is exactly ``(0, beta, 0)``.
    Jacobians: ``B J`` for the poses and ``B J_theta + dB/dtheta e`` for ``theta``."""
    residual, parts = joint_loop_error(T_world_tractor, T_world_trailer, hitch_angle, jacobians)
    rotation, derivative = _rz(float(hitch_angle))
    halves = residual.reshape(2, 3)  # rotation and translation part of e
    turned = (halves @ rotation.T).reshape(6)
    if not jacobians:
        return turned, None
    columns = np.concatenate(parts, axis=1).reshape(2, 3, 13)  # [J_tractor | J_trailer | J_theta] by halves
    jacobian = (rotation @ columns).reshape(6, 13)
    jacobian[:, 12] += (halves @ derivative.T).reshape(6)
    return turned, [jacobian[:, :6], jacobian[:, 6:12], jacobian[:, 12:]]


class JointLoopFactor(gtsam.CustomFactor):
    """``Log((T_world_tractor (Rz(theta), 0))^-1 T_world_trailer)`` on keys (Pose3, Pose3, double).

    ``noise_model`` has dimension 6 (tangent order ``[omega, v]``: radians then metres); the joint
    is rigid, so a tight diagonal model (e.g. 1e-3 rad, 1e-3 m) is typical.
    """

    def __init__(self, tractor_key: int, trailer_key: int, hitch_key: int, noise_model: gtsam.noiseModel.Base) -> None:
        keys = check_distinct_keys({"tractor_key": tractor_key, "trailer_key": trailer_key, "hitch_key": hitch_key})
        check_noise_model(noise_model, 6)
        super().__init__(noise_model, keys, make_error_function(keys, (POSE, POSE, SCALAR), joint_loop_error))

    @staticmethod
    def evaluate(
        T_world_tractor: gtsam.Pose3, T_world_trailer: gtsam.Pose3, hitch_angle: float, jacobians: bool = False
    ) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Unwhitened residual (6,) and optionally its Jacobians (see :func:`joint_loop_error`)."""
        return joint_loop_error(T_world_tractor, T_world_trailer, hitch_angle, jacobians)
