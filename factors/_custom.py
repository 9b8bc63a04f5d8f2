"""The glue between a pure residual function and ``gtsam.CustomFactor``.

Every factor of this package is a ``gtsam.CustomFactor`` subclass whose error function is a
closure over immutable data (never over the factor object itself, which would make a reference
cycle through C++ that Python cannot collect). The closure reads the variables from ``Values``,
calls the residual function and fills GTSAM's Jacobian list with 2-D float64 arrays of shape
(m, dim of key), as GTSAM requires.
"""
from __future__ import annotations

from typing import Callable, Sequence

import gtsam
import numpy as np

POSE = "pose"
SCALAR = "scalar"

Evaluate = Callable[..., tuple[np.ndarray, list[np.ndarray] | None]]


_TANGENT_DIM = {POSE: 6, SCALAR: 1}


def _reader(kind: str) -> Callable[[gtsam.Values, int], object]:
    if kind == POSE:
        return lambda values, key: values.atPose3(key)
    if kind == SCALAR:
        return lambda values, key: values.atDouble(key)
    raise ValueError(f"unknown variable kind {kind!r}")


def make_error_function(keys: Sequence[int], kinds: Sequence[str], evaluate: Evaluate):
    """Error function ``(this, values, H) -> residual`` for ``gtsam.CustomFactor``.

    ``evaluate(*variables, jacobians=bool)`` returns ``(residual (m,), [H_k (m, dim_k)] or None)``
    with the variables in the order of ``keys`` (``Pose3`` or ``float`` as given by ``kinds``).
    Keys, readers and ``evaluate`` are bound now (no late binding of loop variables).
    """
    bound = tuple(zip(tuple(int(key) for key in keys), tuple(_reader(kind) for kind in kinds)))
    dims = tuple(_TANGENT_DIM[kind] for kind in kinds)

    def error_function(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None = None) -> np.ndarray:
        variables = [read(values, key) for key, read in bound]
        if H is None:
            residual, _ = evaluate(*variables, jacobians=False)
            return residual
        residual, jacobians = evaluate(*variables, jacobians=True)
        rows = residual.shape[0]
        for index, (jacobian, dim) in enumerate(zip(jacobians, dims)):
            if jacobian.shape != (rows, dim) or jacobian.dtype != np.float64:
                # GTSAM would segfault on a wrong shape: fail loudly in Python instead
                raise ValueError(f"Jacobian {index} has shape {jacobian.shape} ({jacobian.dtype}), expected ({rows}, {dim}) float64")
            H[index] = jacobian
        return residual

    return error_function
