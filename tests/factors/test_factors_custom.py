"""Tests of factors._custom: the CustomFactor glue refuses Jacobians of the wrong shape."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import gtsam
import numpy as np
import pytest

from factors._custom import POSE, SCALAR, make_error_function

REPOSITORY_ROOT = Path(__file__).resolve().parents[2]


def _values():
    values = gtsam.Values()
    values.insert(0, gtsam.Pose3())
    values.insert(1, 0.5)
    return values


def test_wrong_jacobian_shape_raises_instead_of_crashing():
    """GTSAM segfaults on a wrong Jacobian shape; the guard raises first. Run in a subprocess so a
    regression shows as a failed test, not as a crashed test session."""
    code = textwrap.dedent(
        """
        import gtsam, numpy as np
        from factors._custom import make_error_function, POSE, SCALAR
        def evaluate(pose, angle, jacobians=False):
            return np.zeros(3), ([np.zeros((3, 6)), np.zeros((3, 6))] if jacobians else None)
        factor = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [0, 1], make_error_function([0, 1], (POSE, SCALAR), evaluate))
        values = gtsam.Values(); values.insert(0, gtsam.Pose3()); values.insert(1, 0.5)
        try:
            factor.linearize(values)
        except ValueError as error:
            print("raised:", error)
        """
    )
    environment = dict(os.environ, PYTHONPATH=str(REPOSITORY_ROOT))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "raised: Jacobian 1 has shape (3, 6)" in result.stdout


def test_error_function_fills_jacobians_in_key_order():
    def evaluate(pose, angle, jacobians=False):
        residual = np.array([angle, 2.0 * angle])
        return residual, ([np.ones((2, 6)), np.full((2, 1), 2.0)] if jacobians else None)

    factor = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [0, 1], make_error_function([0, 1], (POSE, SCALAR), evaluate))
    matrix, rhs = factor.linearize(_values()).jacobian()
    np.testing.assert_array_equal(matrix, np.hstack([np.ones((2, 6)), np.full((2, 1), 2.0)]))
    np.testing.assert_array_equal(rhs, [-0.5, -1.0])
    with pytest.raises(ValueError, match="unknown variable kind"):
        make_error_function([0], ("rot2",), evaluate)
