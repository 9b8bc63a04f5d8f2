"""Several small residuals of one keyframe in one ``CustomFactor`` (the smoother's speed, issue 5).

GTSAM calls a Python ``CustomFactor`` once per factor and evaluation, and each call costs tens of
microseconds before any numpy work; a keyframe brings half a dozen small factors (planar,
non-holonomic of both bodies, motion prior, joint loop, scale chord) that LM evaluates several
times per update. :class:`StackedFactor` evaluates them in one call.

Each :class:`Term` is a pure residual function of this package (``planar_motion_error``,
``nonholonomic_error``, ...) with its keys, per-row sigmas and an optional Huber threshold. The
factor whitens each term by its sigmas and applies Huber per row (:func:`factors.epipolar.huber_rows`:
``|r~|^2 / 2`` is exactly the robust cost and its gradient is Huber's), so the noise model of the
stacked factor is ``Unit``; the error is the sum of the terms' errors, the information and gradient
that of the terms as separate Gaussian factors (Huber rows: same gradient as gtsam's per-residual
Huber, Gauss-Newton weight ``k^2 / (2 k |z| - k^2)`` beyond k).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import gtsam
import numpy as np

from factors._checks import check_key
from factors._custom import _TANGENT_DIM, make_error_function
from factors.epipolar import huber_rows


@dataclass(frozen=True)
class Term:
    """One residual of a :class:`StackedFactor`.

    ``evaluate(*variables, jacobians=bool) -> (residual (m,), [H (m, dim_k)] or None)`` with the
    variables of ``keys`` (``kinds``: ``"pose"`` or ``"scalar"``, see :mod:`factors._custom`);
    ``sigmas`` (m,) in the residual's units; ``huber_k`` in sigmas or None (Gaussian).
    """

    keys: tuple[int, ...]
    kinds: tuple[str, ...]
    evaluate: Callable[..., tuple[np.ndarray, list[np.ndarray] | None]]
    sigmas: np.ndarray
    huber_k: float | None = None


class StackedFactor(gtsam.CustomFactor):
    """The terms of the module docstring as one factor on the union of their keys (first-appearance order).

    One evaluation calls each term once, then whitens the stacked residual by the per-row inverse
    sigmas and applies Huber per row (:func:`factors.epipolar.huber_rows` with a per-row threshold,
    infinite for Gaussian rows) in one pass: the same values as term by term, fewer numpy calls.
    """

    def __init__(self, terms: Sequence[Term]) -> None:
        if not terms:
            raise ValueError("StackedFactor needs at least one term")
        keys: list[int] = []
        kinds: list[str] = []
        prepared = []
        inverse_sigmas: list[np.ndarray] = []
        thresholds: list[np.ndarray] = []
        offset = 0
        for term in terms:
            sigmas = _checked_sigmas(term)
            positions = tuple(_position(key, kind, keys, kinds) for key, kind in zip(term.keys, term.kinds))
            prepared.append((term.evaluate, positions, slice(offset, offset + sigmas.size), (sigmas.size,)))
            offset += sigmas.size
            inverse_sigmas.append(1.0 / sigmas)
            thresholds.append(np.full(sigmas.size, np.inf if term.huber_k is None else float(term.huber_k)))
        evaluate = _stacked_evaluate(
            tuple(prepared), tuple(_TANGENT_DIM[kind] for kind in kinds), offset, np.concatenate(inverse_sigmas), np.concatenate(thresholds)
        )
        super().__init__(gtsam.noiseModel.Unit.Create(offset), keys, make_error_function(keys, kinds, evaluate))
        self.terms = tuple(terms)


def _checked_sigmas(term: Term) -> np.ndarray:
    """The term's sigmas as a flat float array, after checking its keys, kinds, sigmas and ``huber_k``."""
    if len(term.keys) != len(term.kinds) or len(set(term.keys)) != len(term.keys):
        raise ValueError(f"term keys {term.keys} and kinds {term.kinds} must match and be distinct")
    sigmas = np.asarray(term.sigmas, dtype=float).reshape(-1)
    if sigmas.size == 0 or not np.all(np.isfinite(sigmas) & (sigmas > 0)):
        raise ValueError(f"term sigmas must be positive and finite, got {term.sigmas!r}")
    if term.huber_k is not None and not term.huber_k > 0:
        raise ValueError(f"huber_k must be positive or None, got {term.huber_k!r}")
    return sigmas


def _position(key: int, kind: str, keys: list[int], kinds: list[str]) -> int:
    """Index of ``key`` among the factor's variables, appending it (with ``kind``) on first appearance."""
    key = check_key(key)
    if key not in keys:
        keys.append(key)
        kinds.append(kind)
    elif kinds[keys.index(key)] != kind:
        raise ValueError(f"key {key} is used as {kinds[keys.index(key)]!r} and as {kind!r}")
    return keys.index(key)


def _stacked_evaluate(prepared: tuple, dims: tuple[int, ...], total: int, inverse_sigmas: np.ndarray, thresholds: np.ndarray) -> Callable:
    """``evaluate(*variables, jacobians)`` of a :class:`StackedFactor`: the terms' raw residuals and
    Jacobians in their rows, then ``z~ = huber(r / sigma)`` and ``H~ = (dz~/dz / sigma) H`` on all
    rows at once (module docstring)."""
    robust = bool(np.any(np.isfinite(thresholds)))
    threshold = thresholds if robust else None

    def evaluate(*variables, jacobians=False):
        residual = np.empty(total)
        blocks = [np.zeros((total, dim)) for dim in dims]
        for term_evaluate, positions, rows, shape in prepared:
            term_residual, term_jacobians = term_evaluate(*[variables[position] for position in positions], jacobians=True)
            if term_residual.shape != shape:
                raise ValueError(f"a term returned {term_residual.shape[0]} residuals, its sigmas have {shape[0]}")
            residual[rows] = term_residual
            for position, jacobian in zip(positions, term_jacobians):
                blocks[position][rows] = jacobian
        whitened, scale = huber_rows(residual * inverse_sigmas, threshold)
        weight = (scale * inverse_sigmas)[:, None]
        for block in blocks:
            block *= weight
        return whitened, (blocks if jacobians else None)

    return evaluate
