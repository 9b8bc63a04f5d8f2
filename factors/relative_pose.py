"""Relative-pose prior between two ``Pose3`` keys.

    e = Log( Z^-1 T_world_i^-1 T_world_j )        (tangent [omega, v]: radians, metres)

The same residual as ``gtsam.BetweenFactorPose3`` (``Z.localCoordinates(T_i_j)``, which is this
Logmap in gtsam's Pose3 chart). :func:`between_prior` builds that C++ factor (no Python callback
per evaluation: the smoother's motion priors); ``tests/factors/test_smooth_speed.py`` checks it
against :class:`RelativePoseFactor` (error and whitened Jacobians to 1e-9) down to and at the
identity. This Python factor zeroes the Jacobian buffers it hands to gtsam: an earlier note had
the C++ factor's near-identity Jacobian NaN in gtsam 4.3, which the installed gtsam 4.3.0 does
not reproduce (the test would catch it).
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors._checks import check_distinct_keys, check_noise_model, check_rigid_transform
from factors._custom import POSE, make_error_function


def relative_pose_error(measured: gtsam.Pose3, T_world_i: gtsam.Pose3, T_world_j: gtsam.Pose3, jacobians: bool = False) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (6,) and, if ``jacobians``, the (6, 6) Jacobians w.r.t. ``T_world_i``, ``T_world_j``."""
    if not jacobians:
        return gtsam.Pose3.Logmap(measured.between(T_world_i.between(T_world_j))), None
    H_i, H_j = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
    T_i_j = T_world_i.between(T_world_j, H_i, H_j)
    H_measured, H_relative = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
    error_pose = measured.between(T_i_j, H_measured, H_relative)
    H_log = np.zeros((6, 6), order="F")
    residual = gtsam.Pose3.Logmap(error_pose, H_log)
    chain = H_log @ H_relative
    return residual, [chain @ H_i, chain @ H_j]


def between_prior(key_i: int, key_j: int, measured: gtsam.Pose3, sigmas: np.ndarray) -> gtsam.BetweenFactorPose3:
    """``T_world_i^-1 T_world_j ~ measured`` with diagonal ``sigmas`` (6,) in tangent order
    ``[omega, v]``: :func:`relative_pose_error` as gtsam's C++ ``BetweenFactorPose3``."""
    return gtsam.BetweenFactorPose3(key_i, key_j, measured, gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float)))


class RelativePoseFactor(gtsam.CustomFactor):
    """Prior ``T_world_i^-1 T_world_j ~ measured`` with a 6-D noise model (module docstring)."""

    def __init__(self, key_i: int, key_j: int, measured: object, noise_model: gtsam.noiseModel.Base) -> None:
        keys = check_distinct_keys({"key_i": key_i, "key_j": key_j})
        check_noise_model(noise_model, 6)
        measured_pose = gtsam.Pose3(check_rigid_transform(measured, "measured"))

        def evaluate(T_world_i, T_world_j, jacobians=False, measured_pose=measured_pose):
            return relative_pose_error(measured_pose, T_world_i, T_world_j, jacobians)

        super().__init__(noise_model, keys, make_error_function(keys, (POSE, POSE), evaluate))
