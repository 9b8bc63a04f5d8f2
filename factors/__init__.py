"""Custom GTSAM factors of the articulated truck (DESIGN section 3), with analytic Jacobians.

Variables: tractor and trailer poses as ``gtsam.Pose3`` ``T_world_body`` (body origin at the hitch,
x forward, y left, z up; right perturbations, tangent ``[omega, v]``) and the hitch angle
``theta`` (``R_tractor_trailer = Rz(theta)``) as a ``double`` value. Every factor is a
``gtsam.CustomFactor`` subclass; each module also exposes its residual as a pure function
(``*_error``) returning ``(residual, jacobians)`` for tests and reuse.

- :class:`GeneralizedEpipolarFactor`: N Sampson GEC residuals of one camera (paper eqs. (1), (2)).
- :class:`StackedEpipolarFactor`: many such blocks (cameras, camera pairs, keyframe pairs) in one factor.
- :class:`StackedFactor`: small residuals (:class:`Term`) of one keyframe in one factor.
- :class:`ArticulatedEpipolarFactor`: the same for a trailer camera on tractor poses and hitch angles (eq. (6)).
- :class:`JointLoopFactor`: ``Log((X (Rz(theta), 0))^-1 Y)`` (eqs. (3)-(5)).
- :class:`NonHolonomicFactor`: circular-arc constraint of a rigid axle (DESIGN (NH)).
- :class:`PlanarMotionFactor`: relative roll, pitch and height near zero.
- :class:`WheelSpeedFactor`: chord length of an axle midpoint (optional scale source), with the
  wheel odometry's scale as an optional variable.
- :func:`robust_noise`: isotropic noise with per-residual Huber weighting.

Nothing here imports from the pipeline; only ``ampc_vo.geometry``, ``ampc_vo.epipolar`` and
``ampc_vo.errors``.
"""
from factors.articulated import ArticulatedEpipolarFactor, articulated_epipolar_error
from factors.epipolar import (
    BodyCorrespondences,
    EpipolarBlock,
    GeneralizedEpipolarFactor,
    StackedEpipolarFactor,
    body_correspondences,
    body_correspondences_per_row,
    epipolar_error,
    stacked_epipolar_error,
)
from factors.joint_loop import JointLoopFactor, joint_loop_error
from factors.noise import robust_noise
from factors.nonholonomic import NonHolonomicFactor, crabbed_nonholonomic_error, nonholonomic_error
from factors.planar import PlanarMotionFactor, planar_motion_error
from factors.stacked import StackedFactor, Term
from factors.wheel_speed import WheelSpeedFactor, capture_chord_error, capture_chord_weights, chord_error, scaled_chord_error

__all__ = [
    "ArticulatedEpipolarFactor",
    "BodyCorrespondences",
    "EpipolarBlock",
    "GeneralizedEpipolarFactor",
    "JointLoopFactor",
    "NonHolonomicFactor",
    "PlanarMotionFactor",
    "StackedEpipolarFactor",
    "StackedFactor",
    "Term",
    "WheelSpeedFactor",
    "articulated_epipolar_error",
    "body_correspondences",
    "body_correspondences_per_row",
    "capture_chord_error",
    "capture_chord_weights",
    "chord_error",
    "epipolar_error",
    "joint_loop_error",
    "nonholonomic_error",
    "crabbed_nonholonomic_error",
    "planar_motion_error",
    "robust_noise",
    "scaled_chord_error",
    "stacked_epipolar_error",
]
