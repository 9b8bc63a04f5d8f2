"""Generalized epipolar factor: all correspondences of one camera between two keyframes of one body.

Residual (paper eqs. (1), (2); DESIGN section 2), one row per correspondence k:

    s_k = r_k / sqrt(|P_f grad_f r_k|^2 + |P_g grad_g r_k|^2),   r_k = (f_k x R f'_k) . (R c_j + t - c_i)

with ``(R, t) = T_i_j = T_world_i^-1 T_world_j`` the body motion (``p_i = R p_j + t``), ``f_k``,
``f'_k`` the unit bearings rotated into the body frame (``R_body_camera @ bearing``) and ``c_i``,
``c_j`` the camera centres in the body frame (equal for one camera; different for the Plücker
two-camera form). ``s_k`` is dimensionless and approximately the angular error in radians; its
sign is that of the triple product ``r_k``. Its noise sigma is pixel sigma / focal length (use
:func:`factors.robust_noise` for per-residual Huber weighting). The value is
:func:`ampc_vo.epipolar.gec_sampson` (the one implementation); the analytic Jacobian comes from
:func:`ampc_vo.epipolar.gec_sampson_jacobian` chained through ``Pose3.between``.

The Sampson residual is scale-free in the baseline ``d = R c_j + t - c_i``: at standstill with a
single camera (``d = 0``) it is undefined (returned as 0 with a zero Jacobian), so do not add this
factor between keyframes that did not move.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ampc_vo.epipolar import gec_sampson, gec_sampson_jacobian
from factors._checks import check_bearing_pair, check_distinct_keys, check_noise_model, check_rigid_transform
from factors._custom import POSE, make_error_function
from factors._lie import relative_motion


@dataclass(frozen=True)
class BodyCorrespondences:
    """Correspondences of one factor in the body frame (read-only arrays).

    ``bearings_i``/``bearings_j`` (N, 3): unit bearings ``R_body_camera @ bearing`` of views i and
    j; ``center_i``/``center_j`` (3,): camera centres in the body frame (metres).
    """

    bearings_i: np.ndarray
    bearings_j: np.ndarray
    center_i: np.ndarray
    center_j: np.ndarray

    def __len__(self) -> int:
        return int(self.bearings_i.shape[0])


def _read_only(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array, dtype=float)
    array.flags.writeable = False
    return array


def body_correspondences(
    T_body_camera: object,
    bearings_i: object,
    bearings_j: object,
    T_body_camera_j: object | None = None,
) -> BodyCorrespondences:
    """Validate camera-frame bearings (N, 3) and extrinsics, and express them in the body frame.

    ``T_body_camera`` (4x4 array or ``Pose3``) is the camera of view i; ``T_body_camera_j`` the
    camera of view j (default: the same camera). Raises ``ValueError`` (``BearingError`` for
    bearings of the wrong shape, mismatched counts, NaN or zero length).
    """
    T_body_camera_i = check_rigid_transform(T_body_camera, "T_body_camera")
    T_body_camera_j = T_body_camera_i if T_body_camera_j is None else check_rigid_transform(T_body_camera_j, "T_body_camera_j")
    unit_i, unit_j = check_bearing_pair(bearings_i, bearings_j)
    return BodyCorrespondences(
        bearings_i=_read_only(unit_i @ T_body_camera_i[:3, :3].T),
        bearings_j=_read_only(unit_j @ T_body_camera_j[:3, :3].T),
        center_i=_read_only(T_body_camera_i[:3, 3]),
        center_j=_read_only(T_body_camera_j[:3, 3]),
    )


def epipolar_error(
    T_world_i: gtsam.Pose3,
    T_world_j: gtsam.Pose3,
    correspondences: BodyCorrespondences,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Sampson GEC residuals (N,) of one body between two keyframes (module docstring) and, if
    ``jacobians``, ``[d s / d T_world_i, d s / d T_world_j]``, each (N, 6)."""
    T_i_j, between_i = relative_motion(T_world_i, T_world_j)
    rotation = T_i_j.rotation().matrix()
    translation = T_i_j.translation()
    c = correspondences
    if not jacobians:
        return gec_sampson(c.bearings_i, c.bearings_j, rotation, translation, c.center_i, c.center_j), None
    residual, jacobian = gec_sampson_jacobian(c.bearings_i, c.bearings_j, rotation, translation, c.center_i, c.center_j)
    return residual, [jacobian @ between_i, jacobian]


class GeneralizedEpipolarFactor(gtsam.CustomFactor):
    """All N correspondences of one camera (or one camera pair) of a body between keyframes i, j.

    One vectorised ``CustomFactor`` with N Sampson-normalised GEC residuals (module docstring) on
    two ``Pose3`` keys ``T_world_body`` (tractor X keys for tractor cameras, trailer Y keys for
    trailer cameras). ``bearings_i``/``bearings_j`` are (N, 3) camera-frame bearings (OpenCV axes,
    any length > 0). With ``T_body_camera_j`` the bearings of view j come from that second camera
    of the same body (Plücker form, e.g. overlapping views). ``noise_model`` must have dimension N,
    e.g. ``robust_noise(pixel_sigma / focal, N, huber_k)``.
    """

    def __init__(
        self,
        key_i: int,
        key_j: int,
        T_body_camera: object,
        bearings_i: object,
        bearings_j: object,
        noise_model: gtsam.noiseModel.Base,
        T_body_camera_j: object | None = None,
    ) -> None:
        keys = check_distinct_keys({"key_i": key_i, "key_j": key_j})
        correspondences = body_correspondences(T_body_camera, bearings_i, bearings_j, T_body_camera_j)
        check_noise_model(noise_model, len(correspondences))

        def evaluate(T_world_i, T_world_j, jacobians=False, correspondences=correspondences):
            return epipolar_error(T_world_i, T_world_j, correspondences, jacobians)

        super().__init__(noise_model, keys, make_error_function(keys, (POSE, POSE), evaluate))
        self.correspondences = correspondences

    def evaluate(
        self, T_world_i: gtsam.Pose3, T_world_j: gtsam.Pose3, jacobians: bool = False
    ) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Unwhitened residuals (N,) and optionally the two (N, 6) Jacobians (see :func:`epipolar_error`)."""
        return epipolar_error(T_world_i, T_world_j, self.correspondences, jacobians)
