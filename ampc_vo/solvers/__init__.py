"""Minimal solvers and robust estimators of the articulated truck's two-view geometry (DESIGN 2).

* :func:`tractor_motion_2pt`: tractor ``(yaw_change, chord)`` from 2 correspondences (Ackermann,
  DESIGN 2.1); :func:`tractor_yaw_1pt`: scale-free yaw for cameras above the axle.
* :func:`hitch_angles_1pt`: both hitch angles from 1 trailer correspondence (DESIGN 2.2).
* :func:`estimate_tractor_motion`, :func:`estimate_hitch_angles`: RANSAC + refinement;
  :func:`refine_joint`: joint refinement over (phi, rho, psi) with both non-holonomic constraints.

All residuals come from :mod:`ampc_vo.epipolar` (the single GEC implementation).
"""
from ampc_vo.solvers.ransac import estimate_hitch_angles, estimate_tractor_motion
from ampc_vo.solvers.refine import refine_joint, refine_tractor, refine_trailer_yaw
from ampc_vo.solvers.status import SolverStatus
from ampc_vo.solvers.tractor import ackermann_motion, tractor_motion_2pt, tractor_motion_2pt_batch, tractor_yaw_1pt
from ampc_vo.solvers.trailer import hitch_angles_1pt, hitch_angles_1pt_batch, positive_depth, trailer_motion_from_yaw
from ampc_vo.solvers.estimates import HitchEstimate, JointEstimate, RansacConfig, TractorMotionEstimate

__all__ = [
    "HitchEstimate",
    "JointEstimate",
    "RansacConfig",
    "SolverStatus",
    "TractorMotionEstimate",
    "ackermann_motion",
    "estimate_hitch_angles",
    "estimate_tractor_motion",
    "hitch_angles_1pt",
    "hitch_angles_1pt_batch",
    "positive_depth",
    "refine_joint",
    "refine_tractor",
    "refine_trailer_yaw",
    "tractor_motion_2pt",
    "tractor_motion_2pt_batch",
    "tractor_yaw_1pt",
    "trailer_motion_from_yaw",
]
