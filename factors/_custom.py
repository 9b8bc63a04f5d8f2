"""The glue between a pure residual function and ``gtsam.CustomFactor``.

Every factor of this package is a ``gtsam.CustomFactor`` subclass whose error function is a
closure over immutable data (never over the factor object itself, which would make a reference
cycle through C++ that Python cannot collect). The closure reads the variables from ``Values``,
calls the residual function and fills GTSAM's Jacobian list with 2-D float64 arrays of shape
(m, dim of key), as GTSAM requires.

Evaluation cache: GTSAM's optimisers evaluate a factor repeatedly at the same values (LM computes
the error at a new point and, once the step is accepted, linearises at that very point; the
marginals linearise at the final estimate, where the error was last computed; the next smoother
update starts by computing the error at it again). With ``cache=True`` (the default) every call
computes residual *and* Jacobians and keeps them with the values they were computed at; a later
call at bitwise identical values returns them without evaluating again. The result is exactly
what an evaluation would give (a pure function of the values), only cheaper: typically one
evaluation per LM iteration instead of two or three.
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
    """``Values.atPose3`` or ``Values.atDouble`` (unbound: ``read(values, key)``, no Python frame between)."""
    if kind == POSE:
        return gtsam.Values.atPose3
    if kind == SCALAR:
        return gtsam.Values.atDouble
    raise ValueError(f"unknown variable kind {kind!r}")


def _same(first: object, second: object) -> bool:
    """Bitwise equality of two variables (``Pose3`` or float)."""
    if isinstance(first, float):
        return first == second
    return first.equals(second, 0.0)


def make_error_function(keys: Sequence[int], kinds: Sequence[str], evaluate: Evaluate, cache: bool = True):
    """Error function ``(this, values, H) -> residual`` for ``gtsam.CustomFactor``.

    ``evaluate(*variables, jacobians=bool)`` returns ``(residual (m,), [H_k (m, dim_k)] or None)``
    with the variables in the order of ``keys`` (``Pose3`` or ``float`` as given by ``kinds``).
    Keys, readers and ``evaluate`` are bound now (no late binding of loop variables). ``cache``:
    the evaluation cache of the module docstring.
    """
    bound = tuple(zip(tuple(int(key) for key in keys), tuple(_reader(kind) for kind in kinds)))
    dims = tuple(_TANGENT_DIM[kind] for kind in kinds)
    last: list = []  # [variables, residual, jacobians] of the last evaluation (the closure's only state)

    def checked(residual: np.ndarray, jacobians: list[np.ndarray]) -> list[np.ndarray]:
        rows = residual.shape[0]
        for index, (jacobian, dim) in enumerate(zip(jacobians, dims)):
            if jacobian.shape != (rows, dim) or jacobian.dtype != np.float64:
                # GTSAM would segfault on a wrong shape: fail loudly in Python instead
                raise ValueError(f"Jacobian {index} has shape {jacobian.shape} ({jacobian.dtype}), expected ({rows}, {dim}) float64")
        return jacobians

    def error_function(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None = None) -> np.ndarray:
        variables = [read(values, key) for key, read in bound]
        if cache:
            if last and all(map(_same, variables, last[0])):
                residual, jacobians = last[1], last[2]
            else:
                residual, jacobians = evaluate(*variables, jacobians=True)
                jacobians = checked(residual, jacobians)
                last[:] = [variables, residual, jacobians]
        elif H is None:
            return evaluate(*variables, jacobians=False)[0]
        else:
            residual, jacobians = evaluate(*variables, jacobians=True)
            jacobians = checked(residual, jacobians)
        if H is not None:
            for index, jacobian in enumerate(jacobians):
                H[index] = jacobian
        return residual

    return error_function
