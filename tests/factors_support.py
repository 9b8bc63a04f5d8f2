"""Shared helpers of the factor tests (tests/test_factors_*.py): random poses, ground truth, checks."""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ampc_vo.geometry import rot_z
from ampc_vo.sim.two_view import TwoViewProblem, make_two_view_problem

JACOBIAN_RTOL = 1e-6


def random_pose(rng: np.random.Generator, rotation_scale: float = 1.0, translation_scale: float = 5.0) -> gtsam.Pose3:
    """A random 3-D pose (rotation vector ~ N(0, rotation_scale), translation ~ N(0, translation_scale))."""
    rotation = gtsam.Rot3.Expmap(rng.normal(0.0, rotation_scale, 3))
    return gtsam.Pose3(rotation, rng.normal(0.0, translation_scale, 3))


def pose3(matrix: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(matrix, dtype=float))


def hitch(angle: float) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(rot_z(angle)), np.zeros(3))


def as_float(value) -> float:
    """``numericalDerivative`` passes a double as a (1,) array."""
    return float(np.squeeze(value))


def assert_jacobian_close(analytic: np.ndarray, numeric: np.ndarray, rtol: float = JACOBIAN_RTOL) -> None:
    """Analytic vs numerical Jacobian: same shape and max deviation <= rtol * max |numeric|."""
    assert analytic.ndim == 2 and analytic.shape == numeric.shape, (analytic.shape, numeric.shape)
    scale = max(float(np.max(np.abs(numeric))), 1e-3)
    deviation = float(np.max(np.abs(analytic - numeric)))
    assert deviation <= rtol * scale, f"Jacobian deviation {deviation:.3g} > {rtol:g} * {scale:.3g}"


@dataclass(frozen=True)
class ArticulatedTruth:
    """World poses of one noise-free articulated two-view problem placed by a random 3-D world pose."""

    problem: TwoViewProblem
    tractor_i: gtsam.Pose3
    tractor_j: gtsam.Pose3
    trailer_i: gtsam.Pose3
    trailer_j: gtsam.Pose3

    @property
    def hitch_i(self) -> float:
        return self.problem.hitch_angle_i

    @property
    def hitch_j(self) -> float:
        return self.problem.hitch_angle_j


def articulated_truth(rng: np.random.Generator, world_rotation_scale: float = 1.0, **problem_options) -> ArticulatedTruth:
    """Noise-free two-view problem (``make_two_view_problem``) in a random world frame: the planar
    motion satisfies both non-holonomic constraints exactly; the world pose need not be planar
    (all factors are invariant to it)."""
    options = dict(n_tractor_cameras=2, n_trailer_cameras=2, points_per_body=40)
    options.update(problem_options)
    problem = make_two_view_problem(rng, **options)
    tractor_i = random_pose(rng, world_rotation_scale)
    tractor_j = tractor_i.compose(pose3(problem.T_i_j))
    trailer_i = tractor_i.compose(hitch(problem.hitch_angle_i))
    trailer_j = tractor_j.compose(hitch(problem.hitch_angle_j))
    return ArticulatedTruth(problem, tractor_i, tractor_j, trailer_i, trailer_j)
