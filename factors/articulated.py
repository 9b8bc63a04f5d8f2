"""Articulated epipolar factor: trailer-camera correspondences on tractor poses and hitch angles.

Residual (paper eq. (6); DESIGN section 2), one Sampson-normalised GEC row per correspondence of
a trailer camera, evaluated on the trailer motion implied by the tractor poses and the two hitch
angles instead of trailer pose variables:

    T_world_trailer_k = T_world_tractor_k (Rz(theta_k), 0),   k = i, j
    R_B = Rz(theta_i)^T R_A Rz(theta_j),   t_B = Rz(theta_i)^T t_A            (paper eqs. (3), (4))

then exactly the residual of :mod:`factors.epipolar` (dimensionless, ~radians) on
``T_trailer_i_j``. Keys: tractor ``Pose3`` i and j, hitch angle ``double`` i and j. Equivalent to
``GeneralizedEpipolarFactor`` on trailer keys plus two ``JointLoopFactor``s with zero noise; it
exists to compare formulations (fewer variables, no joint-loop stiffness).
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors._checks import check_distinct_keys, check_noise_model
from factors._custom import POSE, SCALAR, make_error_function
from factors._lie import trailer_from_tractor
from factors.epipolar import BodyCorrespondences, body_correspondences, epipolar_error


def articulated_epipolar_error(
    T_world_tractor_i: gtsam.Pose3,
    T_world_tractor_j: gtsam.Pose3,
    hitch_angle_i: float,
    hitch_angle_j: float,
    correspondences: BodyCorrespondences,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residuals (N,) of the module docstring and, if ``jacobians``, ``[(N, 6), (N, 6), (N, 1),
    (N, 1)]`` w.r.t. tractor pose i, tractor pose j, hitch angle i, hitch angle j."""
    trailer_i, trailer_i_by_tractor = trailer_from_tractor(T_world_tractor_i, float(hitch_angle_i))
    trailer_j, trailer_j_by_tractor = trailer_from_tractor(T_world_tractor_j, float(hitch_angle_j))
    residual, by_trailer = epipolar_error(trailer_i, trailer_j, correspondences, jacobians)
    if not jacobians:
        return residual, None
    by_trailer_i, by_trailer_j = by_trailer
    # d trailer / d theta = [0, 0, 1, 0, 0, 0] (right perturbation about z)
    return residual, [
        by_trailer_i @ trailer_i_by_tractor,
        by_trailer_j @ trailer_j_by_tractor,
        by_trailer_i[:, 2:3].copy(),
        by_trailer_j[:, 2:3].copy(),
    ]


class ArticulatedEpipolarFactor(gtsam.CustomFactor):
    """Paper eq. (6) for one trailer camera (module docstring).

    ``T_trailer_camera`` (4x4 or ``Pose3``) is the camera's extrinsics on the **trailer**;
    bearings (N, 3) in the camera frame; ``T_trailer_camera_j`` as in ``GeneralizedEpipolarFactor``.
    ``noise_model`` has dimension N.
    """

    def __init__(
        self,
        tractor_key_i: int,
        tractor_key_j: int,
        hitch_key_i: int,
        hitch_key_j: int,
        T_trailer_camera: object,
        bearings_i: object,
        bearings_j: object,
        noise_model: gtsam.noiseModel.Base,
        T_trailer_camera_j: object | None = None,
    ) -> None:
        keys = check_distinct_keys(
            {"tractor_key_i": tractor_key_i, "tractor_key_j": tractor_key_j, "hitch_key_i": hitch_key_i, "hitch_key_j": hitch_key_j}
        )
        correspondences = body_correspondences(T_trailer_camera, bearings_i, bearings_j, T_trailer_camera_j)
        check_noise_model(noise_model, len(correspondences))

        def evaluate(tractor_i, tractor_j, hitch_i, hitch_j, jacobians=False, correspondences=correspondences):
            return articulated_epipolar_error(tractor_i, tractor_j, hitch_i, hitch_j, correspondences, jacobians)

        super().__init__(noise_model, keys, make_error_function(keys, (POSE, POSE, SCALAR, SCALAR), evaluate))
        self.correspondences = correspondences

    def evaluate(
        self,
        T_world_tractor_i: gtsam.Pose3,
        T_world_tractor_j: gtsam.Pose3,
        hitch_angle_i: float,
        hitch_angle_j: float,
        jacobians: bool = False,
    ) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Unwhitened residuals (N,) and optionally the four Jacobians (see :func:`articulated_epipolar_error`)."""
        return articulated_epipolar_error(
            T_world_tractor_i, T_world_tractor_j, hitch_angle_i, hitch_angle_j, self.correspondences, jacobians
        )
