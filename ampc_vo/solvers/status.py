"""Outcome codes of the solvers and estimators: degenerate input gives a status, never garbage."""
from __future__ import annotations

from enum import Enum


class SolverStatus(str, Enum):
    """Why an estimate is (or is not) trustworthy.

    ``OK``: estimate valid. ``STANDSTILL``: the vehicle did not move (no parallax, ``|t| ~ 0``);
    motion is zero and the hitch angle is unobservable (held at the prior).
    ``TOO_FEW_POINTS``: fewer valid correspondences than the minimal sample (or than
    ``min_inliers``). ``SCALE_UNOBSERVABLE``: the yaw change and the translation direction are
    valid but the chord length is not (straight driving, or every camera above the axle,
    ``p_x = 0``, DESIGN 2.1). ``NO_CONSENSUS``: no hypothesis reached ``min_inliers``.
    ``NO_MOTION_PRIOR``: the trailer estimator was given an invalid tractor motion.
    """

    OK = "ok"
    STANDSTILL = "standstill"
    TOO_FEW_POINTS = "too_few_points"
    SCALE_UNOBSERVABLE = "scale_unobservable"
    NO_CONSENSUS = "no_consensus"
    NO_MOTION_PRIOR = "no_motion_prior"

    @property
    def usable(self) -> bool:
        """True when the rotation/yaw part of the estimate can be used."""
        return self in (SolverStatus.OK, SolverStatus.SCALE_UNOBSERVABLE)
