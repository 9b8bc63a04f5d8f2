"""Tests of factors.hitch_limit: zero inside the range, the excess beyond it, Jacobians against
numerical derivatives, and that it keeps a graph out of the theta + pi twin."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import A
from gtsam.utils.numerical_derivative import numericalDerivative11

from factors.hitch_limit import HitchLimitFactor, hitch_limit_error

LIMIT = np.radians(90.0)


def _values(theta: float) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(A(0), float(theta))
    return values


@pytest.mark.parametrize("theta, expected", [(0.0, 0.0), (1.5, 0.0), (-1.5, 0.0), (2.0, 2.0 - LIMIT), (-2.5, 2.5 - LIMIT), (np.pi, np.pi - LIMIT)])
def test_residual_is_the_excess_beyond_the_stop(theta, expected):
    factor = HitchLimitFactor(A(0), LIMIT, gtsam.noiseModel.Isotropic.Sigma(1, 0.01))
    assert factor.unwhitenedError(_values(theta))[0] == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("theta", [-3.0, -1.7, -0.3, 0.4, 1.6, 2.9])
def test_jacobian_matches_numerical(theta):
    factor = HitchLimitFactor(A(0), LIMIT, gtsam.noiseModel.Isotropic.Sigma(1, 1.0))
    jacobian, _ = factor.linearize(_values(theta)).jacobian()
    numerical = numericalDerivative11(lambda value: np.array([hitch_limit_error(value, LIMIT)[0][0]]), theta)
    np.testing.assert_allclose(jacobian, numerical, atol=1e-7)


def test_pulls_a_flipped_hitch_back_into_the_range():
    """Alone with a prior that cannot tell theta from theta + pi (a symmetric double well), the
    optimiser started at the twin ends inside the range."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(HitchLimitFactor(A(0), LIMIT, gtsam.noiseModel.Isotropic.Sigma(1, np.radians(1.0))))
    graph.add(gtsam.PriorFactorDouble(A(0), np.pi - 0.05, gtsam.noiseModel.Isotropic.Sigma(1, 10.0)))
    result = gtsam.LevenbergMarquardtOptimizer(graph, _values(np.pi - 0.05)).optimize()
    assert abs(result.atDouble(A(0))) <= LIMIT + np.radians(0.1)


@pytest.mark.parametrize("limit", [0.0, -1.0, np.pi, float("nan")])
def test_bad_limits_are_refused(limit):
    with pytest.raises(ValueError, match="limit"):
        HitchLimitFactor(A(0), limit, gtsam.noiseModel.Isotropic.Sigma(1, 0.01))
