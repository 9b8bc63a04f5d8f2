"""Generalized epipolar constraint (GEC) residuals, paper eqs. (1), (2); DESIGN section 2.

The one implementation shared by the minimal solvers, RANSAC scoring and the GTSAM factors.

For a body that moves by ``(R, t) = T_i_j`` between views i and j (``p_i = R p_j + t``), a ray
seen in view i from the camera centre ``c_i`` with body-frame bearing ``f`` and the same point
seen in view j from ``c_j`` with body-frame bearing ``f'`` are coplanar:

    r = (f x R f') . (R c_j + t - c_i) = 0                                  (paper eq. (1))

``c_i == c_j`` for intra-camera correspondences; different centres give the Plücker two-camera
form. The Sampson-normalised residual divides by the norm of the gradient of ``r`` projected on
the tangent planes of the two unit bearings; it approximates the angular error in radians.

The residual functions broadcast over hypotheses: ``rotation`` may be (..., 3, 3) and
``translation`` (..., 3); results are then (..., N). :func:`gec_sampson_jacobian` (one hypothesis)
adds the analytic Jacobian w.r.t. the motion for the GTSAM factors; it shares
:func:`_sampson_terms` with :func:`gec_sampson`, so the residual value has one implementation.
"""
from __future__ import annotations

import numpy as np


def _baseline(rotation: np.ndarray, translation: np.ndarray, center_i: np.ndarray, center_j: np.ndarray) -> np.ndarray:
    """``d = R c_j + t - c_i`` with shape (..., 3)."""
    return rotation @ np.asarray(center_j, dtype=float) + translation - center_i


def gec_algebraic(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    center_i: np.ndarray,
    center_j: np.ndarray | None = None,
) -> np.ndarray:
    """Algebraic GEC residual ``(f x R f') . (R c_j + t - c_i)`` for N body-frame bearings (N, 3)."""
    center_j = center_i if center_j is None else center_j
    rotated_j = np.einsum("...ab,nb->...na", rotation, bearings_j)  # g = R f'
    baseline = _baseline(rotation, translation, center_i, center_j)[..., None, :]
    return np.einsum("...na,...na->...n", np.cross(bearings_i, rotated_j), baseline)


# Levi-Civita symbol as a (9, 3) matrix: (a x b)_k = sum_ij eps_ijk a_i b_j
_LEVI_CIVITA = np.zeros((9, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI_CIVITA[3 * _i + _j, _k] = 1.0
    _LEVI_CIVITA[3 * _j + _i, _k] = -1.0


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of two (N, 3) arrays (two numpy calls, faster than ``np.cross``)."""
    return (a[:, :, None] * b[:, None, :]).reshape(-1, 9) @ _LEVI_CIVITA


_ONES3 = np.ones(3)


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of broadcastable (..., 3) arrays."""
    return (a * b) @ _ONES3


# _skew(v) = v @ _SKEW_BASIS reshaped: [v]x = sum_k v_k [e_k]x
_SKEW_BASIS = np.array(
    [[0, 0, 0, 0, 0, -1, 0, 1, 0], [0, 0, 1, 0, 0, 0, -1, 0, 0], [0, -1, 0, 1, 0, 0, 0, 0, 0]], dtype=float
)


def _skew(vectors: np.ndarray) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of (..., 3) vectors: ``_skew(v) @ w == v x w``."""
    return (vectors @ _SKEW_BASIS).reshape(vectors.shape[:-1] + (3, 3))


def _sampson_terms(
    bearings_i: np.ndarray, rotated_j: np.ndarray, baseline: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The terms of the Sampson-normalised GEC, shared by :func:`gec_sampson` and its Jacobian.

    With ``f = bearings_i`` (N, 3), ``g = rotated_j = R f'`` (..., N, 3) and the baseline
    ``d = R c_j + t - c_i`` (..., 3) (one per hypothesis, common to the N rows), returns
    ``(r, grad_f, grad_g, norm)``: ``r = f . (g x d)``, ``grad_f = g x d`` (gradient of r w.r.t.
    f), ``grad_g = d x f`` (w.r.t. g) and ``norm = sqrt(|P_f grad_f|^2 + |P_g grad_g|^2)`` with
    ``P_v = I - v v^T``.
    """
    skew_baseline = _skew(baseline)
    grad_f = rotated_j @ skew_baseline  # rows S^T g = g x d
    grad_g = -(bearings_i @ skew_baseline)  # rows S f = d x f
    residual = _rowdot(bearings_i, grad_f)
    tangent_f = grad_f - residual[..., None] * bearings_i
    tangent_g = grad_g - _rowdot(grad_g, rotated_j)[..., None] * rotated_j
    norm = np.sqrt(_rowdot(tangent_f, tangent_f) + _rowdot(tangent_g, tangent_g))
    return residual, grad_f, grad_g, norm


_MIN_SAMPSON_NORM = 1e-12  # below it (zero baseline) the Sampson residual is undefined: residual -> 0


def gec_sampson(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    center_i: np.ndarray,
    center_j: np.ndarray | None = None,
) -> np.ndarray:
    """Sampson-normalised GEC residual (approximately radians), DESIGN section 2.

    ``r / sqrt(|P_f (g x d)|^2 + |P_g (d x f)|^2)`` with ``g = R f'``, ``d = R c_j + t - c_i``
    and ``P_v = I - v v^T`` the tangent-plane projector of the unit vector v.
    """
    center_j = center_i if center_j is None else center_j
    rotated_j = bearings_j @ np.swapaxes(rotation, -1, -2)  # rows R f'
    baseline = _baseline(rotation, translation, center_i, center_j)
    residual, _, _, norm = _sampson_terms(bearings_i, rotated_j, baseline)
    return residual / np.maximum(norm, _MIN_SAMPSON_NORM)


def gec_sampson_jacobian(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    center_i: np.ndarray,
    center_j: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Sampson GEC residuals (N,) of :func:`gec_sampson` and their Jacobian (N, 6) w.r.t. the motion.

    One hypothesis: ``rotation`` (3, 3), ``translation`` (3,) of ``T_i_j``; unit body-frame
    bearings (N, 3). The Jacobian is w.r.t. the right perturbation ``T_i_j Exp(xi)`` with tangent
    order ``xi = [omega, v]`` (GTSAM ``Pose3``): ``R -> R Exp(omega)``, ``t -> t + R v``.

    Derivation (``s = r / norm``, unit f and g, so ``norm^2 = |a|^2 + |b|^2 - 2 r^2`` with
    ``a = g x d``, ``b = d x f``): ``ds = (dr - s dnorm) / norm`` and

        d s / d g = (b - s (|d|^2 g - (d.g) d - 2 r b) / norm) / norm
        d s / d d = (f x g - s (2 d - (g.d) g - (f.d) f - 2 r f x g) / norm) / norm

    with ``dg = R (omega x f')`` and ``dd = R (omega x c_j) + R v``; the g-term of ``d s / d g``
    drops out of ``f' x R^T (d s / d g) = R^T (g x d s / d g)``. Rows whose norm is below the
    clamp of :func:`gec_sampson` (zero baseline) get a zero Jacobian.
    """
    center_i = np.asarray(center_i, dtype=float)
    center_j = center_i if center_j is None else np.asarray(center_j, dtype=float)
    rotation = np.asarray(rotation, dtype=float)
    rotated_j = bearings_j @ np.swapaxes(rotation, -1, -2)  # as in gec_sampson: identical values
    baseline = _baseline(rotation, translation, center_i, center_j)
    residual, grad_f, grad_g, norm = _sampson_terms(bearings_i, rotated_j, baseline)
    clamped = np.maximum(norm, _MIN_SAMPSON_NORM)
    sampson = residual / clamped  # exactly gec_sampson's value
    inv_norm = (norm >= _MIN_SAMPSON_NORM) / clamped  # 0 where the residual is undefined
    s_over_n = sampson * inv_norm
    s_over_n2 = s_over_n * inv_norm
    alpha = (1.0 + 2.0 * s_over_n * residual) * inv_norm
    g_dot_d = rotated_j @ baseline
    f_dot_d = bearings_i @ baseline
    g_dot_f = _rowdot(rotated_j, bearings_i)
    s_g_dot_d = (s_over_n2 * g_dot_d)[:, None]
    gradients = np.empty((residual.shape[0], 6))
    # [:, :3] = g x (d s / d g) = alpha (d (g.f) - f (g.d)) + s/n^2 (g.d) (g x d)
    gradients[:, :3] = (alpha * g_dot_f)[:, None] * baseline - (alpha * g_dot_d)[:, None] * bearings_i + s_g_dot_d * grad_f
    # [:, 3:] = d s / d d = alpha f x g - s/n^2 (2 d - (g.d) g - (f.d) f)
    gradients[:, 3:] = (
        alpha[:, None] * _cross_rows(bearings_i, rotated_j)
        + s_g_dot_d * rotated_j
        + (s_over_n2 * f_dot_d)[:, None] * bearings_i
        - (2.0 * s_over_n2)[:, None] * baseline
    )
    # chain to xi = [omega, v] (row vectors): J_omega = (g x ds/dg) R - (ds/dd) R [c_j]x, J_v = (ds/dd) R
    chain = np.zeros((6, 6))
    chain[:3, :3] = rotation
    chain[3:, :3] = rotation @ _skew(-center_j)
    chain[3:, 3:] = rotation
    return sampson, gradients @ chain


def _gather_rows(pairs: tuple[tuple[int, int], ...], cross: bool) -> tuple[np.ndarray, np.ndarray]:
    """Row indices into ``rows = stack.reshape(3 K, N)``, a component-major stack of K vectors
    (vector k, component c at row ``3 k + c``), such that ``rows[left] * rows[right]`` holds, for each pair (a, b),
    the component products of ``a x b`` (``cross``: first half ``a_{c+1} b_{c+2}``, second half
    ``a_{c+2} b_{c+1}``, in pair order) or of ``a . b`` (``a_c b_c``, grouped by pair)."""
    if not cross:
        left = [3 * a + c for a, _ in pairs for c in range(3)]
        right = [3 * b + c for _, b in pairs for c in range(3)]
        return np.array(left), np.array(right)
    left = [3 * a + (c + 1) % 3 for a, _ in pairs for c in range(3)] + [3 * a + (c + 2) % 3 for a, _ in pairs for c in range(3)]
    right = [3 * b + (c + 2) % 3 for _, b in pairs for c in range(3)] + [3 * b + (c + 1) % 3 for _, b in pairs for c in range(3)]
    return np.array(left), np.array(right)


# component-major stack of gec_sampson_pairs_jacobian: 0 f, 1 g = R f', 2 d, 3 g x d, 4 d x f, 5 f x g
_CROSS_LEFT, _CROSS_RIGHT = _gather_rows(((1, 2), (2, 0), (0, 1)), cross=True)
# dot products f.(g x d), g.(d x f), g.d, f.d, g.f
_DOT_LEFT, _DOT_RIGHT = _gather_rows(((0, 3), (1, 4), (1, 2), (0, 2), (1, 0)), cross=False)
# c_j x (b R) with the stack 0 a R, 1 b R, 2 c_j
_CHAIN_LEFT, _CHAIN_RIGHT = _gather_rows(((2, 1),), cross=True)


def gec_sampson_pairs_jacobian(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    centers_i: np.ndarray,
    centers_j: np.ndarray,
    pair_starts: np.ndarray,
    jacobian: bool = True,
    bearing_jacobian: bool = False,
) -> tuple[np.ndarray, np.ndarray | None] | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Sampson GEC of :func:`gec_sampson` / :func:`gec_sampson_jacobian` for rows of several
    motions and cameras at once: rows are sorted by motion (keyframe pair); motion p is
    ``rotations[p]`` (P, 3, 3), ``translations[p]`` (P, 3) and owns rows ``pair_starts[p]`` up to
    the next start; every row has its own camera centres ``centers_i``, ``centers_j`` (N, 3)
    (Plücker form when they differ). One vectorised call for many cameras, camera pairs and
    keyframe pairs (``factors.epipolar.StackedEpipolarFactor``).

    Same formulas as :func:`gec_sampson_jacobian` (see its derivation) with the baseline
    ``d_n = R c_j,n + t - c_i,n`` per row; returns the residuals (N,) and, with ``jacobian``,
    the (N, 6) Jacobian of each row w.r.t. the right perturbation ``[omega, v]`` of its motion;
    with ``bearing_jacobian`` also the (N, 3) Jacobian w.r.t. a rotation ``f' -> Exp(epsilon) f'`` of
    view j's bearing alone (``g x ds/dg`` chained through R, the first part of ``J_omega``; the camera
    mount rotations of ``factors.epipolar.StackedEpipolarFactor``).

    Computed component-major (vectors as (3, N) blocks of one stack) so that the three cross
    products ``g x d``, ``d x f``, ``f x g`` and the five row-wise dot products are one gather,
    one multiplication and one reduction each: the cost is dominated by the number of numpy
    calls at these N, not by the arithmetic.
    """
    count = bearings_i.shape[0]
    bounds = [int(start) for start in pair_starts] + [count]
    stack = np.empty((6, 3, count))  # f, g, d, g x d, d x f, f x g (component-major)
    stack[0] = bearings_i.T
    for rotation, translation, start, stop in zip(rotations, translations, bounds[:-1], bounds[1:]):
        np.matmul(rotation, bearings_j[start:stop].T, out=stack[1, :, start:stop])  # g = R f'
        block = stack[2, :, start:stop]
        np.matmul(rotation, centers_j[start:stop].T, out=block)  # R c_j
        block += translation[:, None]
    stack[2] -= centers_i.T  # d = R c_j + t - c_i
    rows = stack.reshape(18, count)
    products = rows[_CROSS_LEFT] * rows[_CROSS_RIGHT]
    np.subtract(products[:9], products[9:], out=rows[9:])
    products = (rows[_DOT_LEFT] * rows[_DOT_RIGHT]).reshape(5, 3, count)
    dots = products[:, 0] + products[:, 1]
    dots += products[:, 2]
    residual, g_dot_grad_g, g_dot_d, f_dot_d, g_dot_f = dots
    tangents = stack[3:5] - dots[:2, None] * stack[:2]  # P_f (g x d), P_g (d x f)
    tangents *= tangents
    squares = tangents[:, 0] + tangents[:, 1]
    squares += tangents[:, 2]
    norm = np.sqrt(squares[0] + squares[1])
    clamped = np.maximum(norm, _MIN_SAMPSON_NORM)
    sampson = residual / clamped
    if not jacobian:
        return sampson, None
    inv_norm = (norm >= _MIN_SAMPSON_NORM) / clamped
    s_over_n = sampson * inv_norm
    s_over_n2 = s_over_n * inv_norm
    alpha = (1.0 + 2.0 * s_over_n * residual) * inv_norm
    s_g_dot_d = s_over_n2 * g_dot_d
    f, g, d, grad_f, _, f_cross_g = stack
    gradients = np.empty((2, 3, count))  # a = g x ds/dg, b = ds/dd (component-major)
    np.add((alpha * g_dot_f) * d - (alpha * g_dot_d) * f, s_g_dot_d * grad_f, out=gradients[0])
    np.subtract(alpha * f_cross_g + s_g_dot_d * g + (s_over_n2 * f_dot_d) * f, (2.0 * s_over_n2) * d, out=gradients[1])
    # chain per motion (row vectors): J_omega = a R - b R [c_j]x = a R + c_j x (b R), J_v = b R
    chain = np.empty((3, 3, count))  # a R, b R, c_j (component-major)
    for rotation, start, stop in zip(rotations, bounds[:-1], bounds[1:]):
        np.matmul(rotation.T, gradients[:, :, start:stop], out=chain[:2, :, start:stop])
    chain[2] = centers_j.T
    rows = chain.reshape(9, count)
    products = rows[_CHAIN_LEFT] * rows[_CHAIN_RIGHT]
    result = np.empty((count, 6))
    np.add(chain[0], products[:3] - products[3:], out=result[:, :3].T)
    result[:, 3:] = chain[1].T
    if bearing_jacobian:
        return sampson, result, chain[0].T
    return sampson, result


# ---------------------------------------------------------------------- one central camera
def essential_from_bearings(bearings_i: np.ndarray, bearings_j: np.ndarray) -> np.ndarray:
    """Linear (8-point) essential matrices ``E`` with ``f_i^T E f_j = 0``, projected onto the
    essential manifold (singular values 1, 1, 0).

    ``bearings_i``, ``bearings_j``: (..., M, 3) with M >= 8 unit bearings; returns (..., 3, 3).
    The null vector is the eigenvector of ``A^T A`` (9 x 9) with the smallest eigenvalue.
    """
    design = (bearings_i[..., :, :, None] * bearings_j[..., :, None, :]).reshape(*bearings_i.shape[:-1], 9)
    _, vectors = np.linalg.eigh(np.swapaxes(design, -1, -2) @ design)
    essential = vectors[..., :, 0].reshape(*bearings_i.shape[:-2], 3, 3)
    u, _, vt = np.linalg.svd(essential)
    return u @ (np.array([1.0, 1.0, 0.0])[:, None] * vt)


ESSENTIAL_SAMPLE = 8  # correspondences of the linear essential matrix's minimal sample


def sampled_essentials(bearings_i: np.ndarray, bearings_j: np.ndarray, rng: np.random.Generator, draws: int) -> np.ndarray:
    """``draws`` essential-matrix hypotheses (draws, 3, 3) of :func:`essential_from_bearings` from
    random samples of ``ESSENTIAL_SAMPLE`` distinct correspondences of the N (> 8) unit bearings each
    (the frontend's RANSAC, the solvers' noise measure)."""
    samples = np.argsort(rng.random((draws, len(bearings_i))), axis=1)[:, :ESSENTIAL_SAMPLE]
    return essential_from_bearings(bearings_i[samples], bearings_j[samples])


def motion_from_essential(essential: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One ``(R, t)`` per essential matrix with ``E ~ [t]x R`` (Hartley-Zisserman result 9.19).

    Only one of the four decompositions is returned: the Sampson GEC residual (``gec_sampson``
    with the camera at the origin) has the same magnitude for all four.
    """
    u, _, vt = np.linalg.svd(essential)
    u = u * np.sign(np.linalg.det(u))[..., None, None]
    vt = vt * np.sign(np.linalg.det(vt))[..., None, None]
    w = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return u @ w @ vt, u[..., :, 2]


def essential_sampson(essential: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray) -> np.ndarray:
    """Sampson residual on the sphere of ``f_i^T E f_j`` for (..., 3, 3) hypotheses and (N, 3) bearings.

    ``r / sqrt(|P_fi E f_j|^2 + |P_fj E^T f_i|^2)``: for an essential matrix ``E = -[t]x R`` this is
    exactly ``gec_sampson(f_i, f_j, R, t, 0)`` (paper eq. (1) for one central camera; tested), written
    with matrix products because it scores every RANSAC hypothesis on every track each frame.
    """
    e_fj = bearings_j @ np.swapaxes(essential, -1, -2)   # (..., N, 3) = E f_j
    et_fi = bearings_i @ essential                       # (..., N, 3) = E^T f_i
    residual = _dot3(bearings_i, e_fj)
    squared = _dot3(e_fj, e_fj) + _dot3(et_fi, et_fi) - 2.0 * residual * residual
    return residual / np.sqrt(np.maximum(squared, 1e-24))


def _dot3(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Dot products along the last axis (of length 3) of two broadcastable arrays, summed left to
    right: the bits of ``np.sum(first * second, axis=-1)`` at a fraction of its time (numpy's
    reduction over a short last axis was two thirds of :func:`essential_sampson`)."""
    product = first * second
    return (product[..., 0] + product[..., 1]) + product[..., 2]
