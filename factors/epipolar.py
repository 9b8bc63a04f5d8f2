"""Generalized epipolar factor: all correspondences of one camera between two keyframes of one body.

Residual (paper eqs. (1), (2); DESIGN section 2), one row per correspondence k:

    s_k = r_k / sqrt(|P_f grad_f r_k|^2 + |P_g grad_g r_k|^2),   r_k = (f_k x R f'_k) . (R c_j + t - c_i)

with ``(R, t) = T_i_j = T_world_i^-1 T_world_j`` the body motion (``p_i = R p_j + t``), ``f_k``,
``f'_k`` the unit bearings rotated into the body frame (``R_body_camera @ bearing``) and ``c_i``,
``c_j`` the camera centres in the body frame (equal for one camera; different for the Plücker
two-camera form). ``s_k`` is dimensionless and approximately the angular error in radians; its
sign is that of the triple product ``r_k``. Its noise sigma is pixel sigma / focal length (use
:func:`factors.robust_noise` for per-residual Huber weighting). The value is
:func:`ampc_vo.epipolar.gec_sampson` (the one implementation); the analytic Jacobian comes from
:func:`ampc_vo.epipolar.gec_sampson_jacobian` chained through ``Pose3.between``.

The Sampson residual is scale-free in the baseline ``d = R c_j + t - c_i``: at standstill with a
single camera (``d = 0``) it is undefined (returned as 0 with a zero Jacobian), so do not add this
factor between keyframes that did not move.

:class:`StackedEpipolarFactor` (the smoother's) stacks many such blocks and can marginalise a small
rotation of each block's camera relative to its body (``mount_sigmas``; DESIGN 11, "Camera mounts").
"""
from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from ampc_vo.epipolar import gec_sampson, gec_sampson_jacobian, gec_sampson_pairs_jacobian
from factors._checks import check_bearing_pair, check_distinct_keys, check_noise_model, check_rigid_transform
from factors._custom import POSE, make_error_function
from factors._lie import relative_motion


@dataclass(frozen=True)
class BodyCorrespondences:
    """Correspondences of one factor in the body frame (read-only arrays).

    ``bearings_i``/``bearings_j`` (N, 3): unit bearings ``R_body_camera @ bearing`` of views i and
    j; ``center_i``/``center_j`` (3,): camera centres in the body frame (metres), or (N, 3): one
    per correspondence (:func:`body_correspondences_per_row`, rolling-shutter rows; only
    :class:`StackedEpipolarFactor` takes those).
    """

    bearings_i: np.ndarray
    bearings_j: np.ndarray
    center_i: np.ndarray
    center_j: np.ndarray

    def __len__(self) -> int:
        return int(self.bearings_i.shape[0])


def _read_only(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array, dtype=float)
    array.flags.writeable = False
    return array


def body_correspondences(
    T_body_camera: object,
    bearings_i: object,
    bearings_j: object,
    T_body_camera_j: object | None = None,
) -> BodyCorrespondences:
    """Validate camera-frame bearings (N, 3) and extrinsics, and express them in the body frame.

    ``T_body_camera`` (4x4 array or ``Pose3``) is the camera of view i; ``T_body_camera_j`` the
    camera of view j (default: the same camera). Raises ``ValueError`` (``BearingError`` for
    bearings of the wrong shape, mismatched counts, NaN or zero length).
    """
    T_body_camera_i = check_rigid_transform(T_body_camera, "T_body_camera")
    T_body_camera_j = T_body_camera_i if T_body_camera_j is None else check_rigid_transform(T_body_camera_j, "T_body_camera_j")
    unit_i, unit_j = check_bearing_pair(bearings_i, bearings_j)
    return BodyCorrespondences(
        bearings_i=_read_only(unit_i @ T_body_camera_i[:3, :3].T),
        bearings_j=_read_only(unit_j @ T_body_camera_j[:3, :3].T),
        center_i=_read_only(T_body_camera_i[:3, 3]),
        center_j=_read_only(T_body_camera_j[:3, 3]),
    )


def body_correspondences_per_row(
    rotations_i: np.ndarray,
    centers_i: np.ndarray,
    bearings_i: object,
    rotations_j: np.ndarray,
    centers_j: np.ndarray,
    bearings_j: object,
) -> BodyCorrespondences:
    """:func:`body_correspondences` with one extrinsic per correspondence: ``rotations_*`` (N, 3, 3)
    ``R_body_camera`` and ``centers_*`` (N, 3) of the camera when that observation was exposed (a
    rolling-shutter row exposed after the image's first row, on a moving body; DESIGN 11). The
    paper's GEC (eqs. (1), (2)) holds per ray: each Plücker line has its own centre. ``ValueError``
    for shapes that do not match the bearings or values that are not finite."""
    unit_i, unit_j = check_bearing_pair(bearings_i, bearings_j)
    count = unit_i.shape[0]
    arrays = {"rotations_i": rotations_i, "rotations_j": rotations_j, "centers_i": centers_i, "centers_j": centers_j}
    for name, value in arrays.items():
        value = np.asarray(value, dtype=float)
        expected = (count, 3, 3) if name.startswith("rotations") else (count, 3)
        if value.shape != expected:
            raise ValueError(f"{name} must have shape {expected}, got {value.shape}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{name} contains NaN or infinite values")
        arrays[name] = value
    return BodyCorrespondences(
        bearings_i=_read_only(np.einsum("nab,nb->na", arrays["rotations_i"], unit_i)),
        bearings_j=_read_only(np.einsum("nab,nb->na", arrays["rotations_j"], unit_j)),
        center_i=_read_only(arrays["centers_i"]),
        center_j=_read_only(arrays["centers_j"]),
    )


def epipolar_error(
    T_world_i: gtsam.Pose3,
    T_world_j: gtsam.Pose3,
    correspondences: BodyCorrespondences,
    jacobians: bool = False,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Sampson GEC residuals (N,) of one body between two keyframes (module docstring) and, if
    ``jacobians``, ``[d s / d T_world_i, d s / d T_world_j]``, each (N, 6)."""
    c = correspondences
    if c.center_i.ndim != 1 or c.center_j.ndim != 1:
        raise ValueError("correspondences with one camera centre per row: use StackedEpipolarFactor")
    T_i_j, between_i = relative_motion(T_world_i, T_world_j)
    rotation = T_i_j.rotation().matrix()
    translation = T_i_j.translation()
    if not jacobians:
        return gec_sampson(c.bearings_i, c.bearings_j, rotation, translation, c.center_i, c.center_j), None
    residual, jacobian = gec_sampson_jacobian(c.bearings_i, c.bearings_j, rotation, translation, c.center_i, c.center_j)
    return residual, [jacobian @ between_i, jacobian]


class GeneralizedEpipolarFactor(gtsam.CustomFactor):
    """All N correspondences of one camera (or one camera pair) of a body between keyframes i, j.

    One vectorised ``CustomFactor`` with N Sampson-normalised GEC residuals (module docstring) on
    two ``Pose3`` keys ``T_world_body`` (tractor X keys for tractor cameras, trailer Y keys for
    trailer cameras). ``bearings_i``/``bearings_j`` are (N, 3) camera-frame bearings (OpenCV axes,
    any length > 0). With ``T_body_camera_j`` the bearings of view j come from that second camera
    of the same body (Plücker form, e.g. overlapping views). ``noise_model`` must have dimension N,
    e.g. ``robust_noise(pixel_sigma / focal, N, huber_k)``.
    """

    def __init__(
        self,
        key_i: int,
        key_j: int,
        T_body_camera: object,
        bearings_i: object,
        bearings_j: object,
        noise_model: gtsam.noiseModel.Base,
        T_body_camera_j: object | None = None,
    ) -> None:
        keys = check_distinct_keys({"key_i": key_i, "key_j": key_j})
        correspondences = body_correspondences(T_body_camera, bearings_i, bearings_j, T_body_camera_j)
        check_noise_model(noise_model, len(correspondences))

        def evaluate(T_world_i, T_world_j, jacobians=False, correspondences=correspondences):
            return epipolar_error(T_world_i, T_world_j, correspondences, jacobians)

        super().__init__(noise_model, keys, make_error_function(keys, (POSE, POSE), evaluate))
        self.correspondences = correspondences

    def evaluate(
        self, T_world_i: gtsam.Pose3, T_world_j: gtsam.Pose3, jacobians: bool = False
    ) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Unwhitened residuals (N,) and optionally the two (N, 6) Jacobians (see :func:`epipolar_error`)."""
        return epipolar_error(T_world_i, T_world_j, self.correspondences, jacobians)


@dataclass(frozen=True)
class EpipolarBlock:
    """Correspondences of one camera (or camera pair) between two keyframes: a block of rows of a
    :class:`StackedEpipolarFactor`. ``key_i``/``key_j``: the ``Pose3`` keys ``T_world_body`` of the
    two views; ``correspondences`` from :func:`body_correspondences`."""

    key_i: int
    key_j: int
    correspondences: BodyCorrespondences


def huber_rows(whitened: np.ndarray, huber_k: float | np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Per-residual Huber loss as residuals: ``z~ = sign(z) sqrt(2 rho(z))`` and ``d z~ / d z``.

    ``rho(z) = z^2 / 2`` for ``|z| <= k``, ``k |z| - k^2 / 2`` beyond, so ``|z~|^2 / 2`` summed is
    exactly the robust cost (which LM compares between steps) and the gradient ``z~ dz~/dz =
    rho'(z)`` is Huber's; the Gauss-Newton weight beyond k is ``k^2 / (2 k |z| - k^2)``.
    ``huber_k``: one threshold, one per row (``inf``: that row plain least squares), or None
    (plain least squares).
    """
    if huber_k is None:
        return whitened, np.ones_like(whitened)
    magnitude = np.abs(whitened)
    outside = np.flatnonzero(magnitude > huber_k)  # indices: usually few rows, cheaper than a mask
    robust = whitened.copy()
    scale = np.ones(whitened.shape)
    if outside.size:
        k = huber_k[outside] if isinstance(huber_k, np.ndarray) else huber_k
        root = np.sqrt(2.0 * k * magnitude[outside] - k * k)
        robust[outside] = np.sign(whitened[outside]) * root
        scale[outside] = k / root
    return robust, scale


@dataclass(frozen=True)
class MountRotations:
    """The camera mounts' rotation between the two views of each block, a nuisance of the GEC
    (DESIGN 11, "Camera mounts"): ``block_starts`` (B,) the first row of each block (rows sorted by
    pair, blocks contiguous), ``row_block`` (N,) each row's block, ``block_pair`` (B,) each block's
    keyframe pair, ``sigma`` (B,) radians per axis; ``prior_information`` (B, 3, 3), ``I / sigma^2``,
    follows from ``sigma``."""

    block_starts: np.ndarray
    row_block: np.ndarray
    block_pair: np.ndarray
    sigma: np.ndarray
    prior_information: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "prior_information", _read_only(np.eye(3) / (np.asarray(self.sigma, dtype=float) ** 2)[:, None, None]))


_MOUNT_ITERATIONS = 10  # at most this many reweighted solves of the blocks' rotations (Huber rows; 1 when Gaussian)
_MOUNT_TOLERANCE = 1e-4  # ... until no rotation changes by more than this fraction of its prior sigma


def _reweighted(total: np.ndarray, per_row: np.ndarray, weight: np.ndarray, row_block: np.ndarray) -> np.ndarray:
    """``sum_n weight_n per_row_n`` per block from the unweighted sums ``total`` (B, ...): only the
    rows with a weight below 1 (Huber's few outliers) are visited."""
    reduced = np.flatnonzero(weight < 1.0)
    if reduced.size == 0:
        return total
    result = total.copy()
    np.add.at(result, row_block[reduced], -(1.0 - weight[reduced]).reshape((-1,) + (1,) * (per_row.ndim - 1)) * per_row[reduced])
    return result


def _mount_rotations(
    whitened: np.ndarray, bearing_part: np.ndarray, outer: np.ndarray, normal: np.ndarray, mount: MountRotations, huber_k: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """The rotation ``epsilon`` (B, 3) of view j's bearings per block that minimises the block's
    robust cost ``sum rho(z + B epsilon) + |epsilon|^2 / (2 sigma^2)`` (rows linear in
    ``epsilon``) and the rows ``z + B epsilon`` (N,) at it: iteratively reweighted least squares
    from ``epsilon = 0`` with Huber's weights, until a step changes no rotation by more than
    ``_MOUNT_TOLERANCE`` of its sigma or the weights did not change (the next solve would repeat this
    one). ``outer`` (N, 3, 3): the rows' ``b b^T``; ``normal`` (B, 3, 3): their sums per block."""
    rows_rhs = bearing_part * whitened[:, None]
    rhs = np.add.reduceat(rows_rhs, mount.block_starts, axis=0)
    epsilon = np.zeros((mount.block_starts.shape[0], 3))
    tolerance = _MOUNT_TOLERANCE * mount.sigma[:, None]
    _, scale = huber_rows(whitened, huber_k)
    corrected = whitened
    for _ in range(_MOUNT_ITERATIONS):
        weight = scale * scale  # Huber's Gauss-Newton weight rho'(r) / r
        system = _reweighted(normal, outer, weight, mount.row_block) + mount.prior_information
        previous = epsilon
        epsilon = -np.linalg.solve(system, _reweighted(rhs, rows_rhs, weight, mount.row_block)[:, :, None])[:, :, 0]
        corrected = whitened + np.einsum("na,na->n", bearing_part, epsilon[mount.row_block])
        if huber_k is None or np.all(np.abs(epsilon - previous) < tolerance):
            break
        previous_scale = scale
        _, scale = huber_rows(corrected, huber_k)
        if np.array_equal(scale, previous_scale):
            break
    return epsilon, corrected


def _marginalise_mount_rotations(
    by_motion: np.ndarray,
    robust: np.ndarray,
    scale: np.ndarray,
    bearing_part: np.ndarray,
    outer: np.ndarray,
    normal: np.ndarray,
    epsilon: np.ndarray,
    mount: MountRotations,
    information: np.ndarray,
    gradient: np.ndarray,
) -> None:
    """Eliminate the blocks' rotations (:func:`_mount_rotations`) from the pairs' Gauss-Newton
    ``information`` (P, 6, 6) and ``gradient`` (P, 6), in place: the Schur complement of the
    augmented system at ``epsilon``, robust rows ``r`` with Jacobians ``[A B]`` (``A`` the
    whitened ``by_motion`` and ``B`` the ``bearing_part``, both times the rows' Huber ``scale``)
    and the prior rows ``epsilon / sigma``:

        information -= A^T B H^-1 B^T A,   gradient -= A^T B H^-1 (B^T r + epsilon / sigma^2),
        H = B^T B + I / sigma^2

    (the last bracket is ~0 at the solved ``epsilon``). ``B`` is held at the current motion
    (variable projection; its change with the motion is left out, Kaufman's approximation).
    ``outer``, ``normal``: as in :func:`_mount_rotations`."""
    weight = scale * scale
    system = _reweighted(normal, outer, weight, mount.row_block) + mount.prior_information
    weighted_bearing = bearing_part * weight[:, None]
    bounds = list(mount.block_starts) + [by_motion.shape[0]]
    coupling_t = np.empty((len(bounds) - 1, 3, 7))  # per block: (B^T A | B^T r + epsilon / sigma^2)
    for block, (start, stop) in enumerate(zip(bounds[:-1], bounds[1:])):
        coupling_t[block, :, :6] = weighted_bearing[start:stop].T @ by_motion[start:stop]
    coupling_t[:, :, 6] = np.add.reduceat(bearing_part * (robust * scale)[:, None], mount.block_starts, axis=0) + epsilon / (mount.sigma**2)[:, None]
    solved = np.linalg.solve(system, coupling_t)  # (B, 3, 7)
    reduction = np.swapaxes(coupling_t[:, :, :6], 1, 2) @ solved  # (B, 6, 7): A^T B H^-1 (B^T A | ...)
    np.add.at(information, mount.block_pair, -reduction[:, :, :6])
    np.add.at(gradient, mount.block_pair, -reduction[:, :, 6])


_EIGEN_FLOOR = 1e-12  # relative: information directions below it carry no information


def stacked_epipolar_error(
    poses: list[gtsam.Pose3],
    pair_keys: np.ndarray,
    pair_starts: np.ndarray,
    rows: dict[str, np.ndarray],
    huber_k: float | None,
    jacobians: bool = False,
    mount: MountRotations | None = None,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Compressed residual (6 P + 1,) of a :class:`StackedEpipolarFactor` and, if ``jacobians``, one
    (6 P + 1, 6) Jacobian per pose.

    ``pair_keys`` (P, 2): indices into ``poses`` of views i and j of each keyframe pair; the rows of
    pair p start at ``pair_starts[p]`` (rows sorted by pair); ``rows``: per-row body-frame bearings
    and centres (``bearings_i``, ``bearings_j``, ``centers_i``, ``centers_j``, (N, 3)), the pair
    index ``pair`` (N,) and the Sampson sigma ``sigma`` (N,). Steps: Sampson GEC per row, whitened
    by its sigma, Huber per row (:func:`huber_rows`); then per pair the rows (a function of the
    pair's relative motion only, 6 parameters) are replaced by the square root of their Gauss-Newton
    system: with ``J^T J = V diag(w) V^T`` and ``g = J^T z``, rows ``diag(sqrt w) V^T`` and
    residual ``diag(1/sqrt w) V^T g``; the last row carries the remaining residual norm (zero
    Jacobian), so the error ``|r|^2 / 2`` is exactly the sum of the Huber losses and the linear
    system (information and gradient) is exactly that of the N rows. With ``mount``, each block's
    camera rotation relative to its body is a nuisance: solved per block (:func:`_mount_rotations`,
    the rows then taken at it and its prior added to the cost) and eliminated from the system
    before the compression (:func:`_marginalise_mount_rotations`).
    """
    motions = [relative_motion(poses[i], poses[j]) for i, j in pair_keys]
    rotations = np.array([T_i_j.rotation().matrix() for T_i_j, _ in motions])
    translations = np.array([T_i_j.translation() for T_i_j, _ in motions])
    sampson, by_motion, bearing_part = gec_sampson_pairs_jacobian(
        rows["bearings_i"], rows["bearings_j"], rotations, translations, rows["centers_i"], rows["centers_j"], pair_starts, bearing_jacobian=True
    )
    whitened = sampson / rows["sigma"]
    by_motion = by_motion / rows["sigma"][:, None]
    prior_cost = 0.0
    if mount is not None:
        bearing_part = bearing_part / rows["sigma"][:, None]  # d z / d epsilon (view j's bearings only)
        outer = bearing_part[:, :, None] * bearing_part[:, None, :]
        normal = np.add.reduceat(outer, mount.block_starts, axis=0)
        epsilon, whitened = _mount_rotations(whitened, bearing_part, outer, normal, mount, huber_k)
        prior_cost = float(np.sum((epsilon / mount.sigma[:, None]) ** 2))
    whitened, scale = huber_rows(whitened, huber_k)
    weighted = by_motion * scale[:, None]
    bounds = list(pair_starts) + [whitened.shape[0]]
    information = np.array([weighted[start:stop].T @ weighted[start:stop] for start, stop in zip(bounds[:-1], bounds[1:])])  # (P, 6, 6)
    gradient = np.add.reduceat(weighted * whitened[:, None], pair_starts, axis=0)  # (P, 6)
    cost = float(whitened @ whitened) + prior_cost
    if mount is not None:
        _marginalise_mount_rotations(by_motion, whitened, scale, bearing_part, outer, normal, epsilon, mount, information, gradient)
    eigenvalues, eigenvectors = np.linalg.eigh(information)
    floor = _EIGEN_FLOOR * np.maximum(eigenvalues[:, -1:], 1e-300)
    informative = eigenvalues > floor
    root = np.sqrt(np.where(informative, eigenvalues, 0.0))
    projected = np.einsum("pab,pa->pb", eigenvectors, gradient)  # V^T g
    compressed = np.where(informative, projected / np.where(informative, root, 1.0), 0.0)
    remainder = max(cost - float(np.sum(compressed * compressed)), 0.0)
    residual = np.concatenate([compressed.ravel(), [np.sqrt(remainder)]])
    if not jacobians:
        return residual, None
    square_root = root[:, :, None] * np.swapaxes(eigenvectors, 1, 2)  # (P, 6, 6): diag(sqrt w) V^T
    blocks = [np.zeros((residual.shape[0], 6)) for _ in poses]
    for index, ((index_i, index_j), (_, between_i)) in enumerate(zip(pair_keys, motions)):
        selected = slice(6 * index, 6 * index + 6)
        blocks[index_i][selected] = square_root[index] @ between_i
        blocks[index_j][selected] = square_root[index]
    return residual, blocks


@dataclass(frozen=True)
class LinearisationPoint:
    """Where a :class:`StackedEpipolarFactor` was last evaluated in full: each keyframe pair's
    relative motion ``motions`` (P ``Pose3`` ``T_i_j``; ``chords`` their lengths follow), the
    compressed ``residual`` (6 P + 1,) and each pair's square-root information ``square_roots``
    (P, 6, 6), the rows' Jacobian w.r.t. the right perturbation of ``T_i_j``
    (:func:`stacked_epipolar_error`)."""

    motions: tuple
    residual: np.ndarray
    square_roots: np.ndarray
    chords: np.ndarray = field(init=False, repr=False)  # (P,) each pair's |t_i_j| (metres)

    def __post_init__(self) -> None:
        object.__setattr__(self, "chords", np.array([np.linalg.norm(T_i_j.translation()) for T_i_j in self.motions]))


def linearisation_point(poses: list[gtsam.Pose3], pair_keys: np.ndarray, residual: np.ndarray, blocks: list[np.ndarray]) -> LinearisationPoint:
    """The :class:`LinearisationPoint` of a full evaluation ``(residual, blocks)`` of
    :func:`stacked_epipolar_error` at ``poses`` (pair p's square root is the Jacobian block of its
    view j, rows ``6 p .. 6 p + 5``)."""
    motions = tuple(poses[i].between(poses[j]) for i, j in pair_keys)
    square_roots = np.array([blocks[j][6 * pair:6 * pair + 6] for pair, (_, j) in enumerate(pair_keys)])
    return LinearisationPoint(motions, residual, square_roots)


def relinearised_stacked_epipolar(
    poses: list[gtsam.Pose3], pair_keys: np.ndarray, point: LinearisationPoint, threshold: float
) -> tuple[np.ndarray, list[np.ndarray]] | None:
    """The factor's Gauss-Newton model at ``poses`` from its last full evaluation ``point``, or None
    when any keyframe pair's relative motion moved too far from ``point.motions``: then it must be
    evaluated anew (iSAM2's fluid relinearisation, Kaess et al. 2012, on the factor's own variables:
    the relative motions, so the window's common drift does not count). Too far: with
    ``xi_p = Log(T_i_j,point^-1 T_i_j) = [omega, v]``, a rotation component above ``threshold``
    (radians) or a translation component above ``threshold`` times the pair's chord ``|t_p|`` (the
    rows see the baseline's direction, which ``v`` turns by ``|v| / |t_p|`` radians).

    Residual ``r_p + S_p xi_p`` per pair (``S_p`` its square root, :class:`LinearisationPoint`), the
    last row (the remaining cost) unchanged; Jacobians ``S_p`` w.r.t. view j and ``S_p dT_i_j/dT_i``
    at the current poses. Its error is the Gauss-Newton model of the cost, exact to first order in
    ``xi``: with ``threshold`` 1e-4 the Huber weights and the Sampson denominators held at ``point``
    belong to rows that moved by about ``threshold * focal`` pixels (0.05 px at 500 px), far below
    the pixel noise.
    """
    motions = [relative_motion(poses[i], poses[j]) for i, j in pair_keys]
    steps = np.array([reference.localCoordinates(T_i_j) for reference, (T_i_j, _) in zip(point.motions, motions)])
    if not (np.all(np.abs(steps[:, :3]) <= threshold) and np.all(np.abs(steps[:, 3:]) <= threshold * point.chords[:, None])):
        return None
    residual = point.residual.copy()
    pairs = len(motions)
    residual[:6 * pairs] += np.einsum("pab,pb->pa", point.square_roots, steps).ravel()
    blocks = [np.zeros((residual.shape[0], 6)) for _ in poses]
    for index, ((index_i, index_j), (_, between_i)) in enumerate(zip(pair_keys, motions)):
        selected = slice(6 * index, 6 * index + 6)
        blocks[index_i][selected] = point.square_roots[index] @ between_i
        blocks[index_j][selected] = point.square_roots[index]
    return residual, blocks


def _per_block(values: float | list[float], count: int, name: str) -> list[float]:
    """One positive finite value per block from one value or a list of ``count``; ``ValueError`` otherwise."""
    per_block = [float(values)] * count if np.isscalar(values) else [float(value) for value in values]
    if len(per_block) != count or not all(np.isfinite(value) and value > 0 for value in per_block):
        raise ValueError(f"{name} must be one positive number or one per block, got {values!r}")
    return per_block


class StackedEpipolarFactor(gtsam.CustomFactor):
    """Many :class:`EpipolarBlock` s in one vectorised factor: every camera (and camera pair) of every
    keyframe pair that a new keyframe closes, on one or both bodies (module docstring residual).

    GTSAM calls Python once per evaluation instead of once per block, numpy works on all rows at
    once, and the factor hands GTSAM 6 rows per keyframe pair instead of one per correspondence
    (:func:`stacked_epipolar_error`: the same Gauss-Newton system and the same robust cost as the N
    Huber-weighted rows): the smoother's hot path (issue 5 timing). ``sigmas``: the Sampson sigma
    (pixel sigma / focal) of each block, or one for all; ``huber_k`` in sigmas (None: Gaussian).
    Keys: the distinct ``Pose3`` keys of the blocks, in order of first appearance. The noise model
    is ``Unit`` (whitening and robust weighting happen inside). ``mount_sigmas`` (radians per axis,
    one or one per block; None: rigid mounts): the rotation of each block's camera relative to its
    body between the two views, marginalised (:func:`_marginalise_mount_rotations`).
    ``relinearize_threshold`` (radians, and translation per metre of chord; 0: every evaluation in
    full): while no keyframe pair's relative motion has moved farther than this from the last full
    evaluation, the factor
    gives its Gauss-Newton model there (:func:`relinearised_stacked_epipolar`), at a tenth of the
    cost; the smoother's older keyframe pairs barely move from update to update.
    """

    def __init__(
        self,
        blocks: list[EpipolarBlock],
        sigmas: float | list[float],
        huber_k: float | None = 1.345,
        mount_sigmas: float | list[float] | None = None,
        relinearize_threshold: float = 0.0,
    ) -> None:
        if not blocks:
            raise ValueError("StackedEpipolarFactor needs at least one block")
        sigma_of_block = _per_block(sigmas, len(blocks), "sigmas")
        mount_of_block = None if mount_sigmas is None else _per_block(mount_sigmas, len(blocks), "mount_sigmas")
        if huber_k is not None and not huber_k > 0:
            raise ValueError(f"huber_k must be positive or None, got {huber_k!r}")
        if not (np.isfinite(relinearize_threshold) and relinearize_threshold >= 0):
            raise ValueError(f"relinearize_threshold must be >= 0, got {relinearize_threshold!r}")
        keys: list[int] = []
        for block in blocks:
            check_distinct_keys({"key_i": block.key_i, "key_j": block.key_j})
            for key in (block.key_i, block.key_j):
                if int(key) not in keys:
                    keys.append(int(key))
        pair_of_block = [(keys.index(int(block.key_i)), keys.index(int(block.key_j))) for block in blocks]
        pairs = list(dict.fromkeys(pair_of_block))
        order = sorted(range(len(blocks)), key=lambda index: pairs.index(pair_of_block[index]))
        ordered = [blocks[index] for index in order]
        counts = [len(block.correspondences) for block in ordered]
        pair_of_ordered_block = np.array([pairs.index(pair_of_block[index]) for index in order], dtype=np.int64)
        pair_of_row = np.repeat(pair_of_ordered_block, counts)
        pair_starts = np.searchsorted(pair_of_row, np.arange(len(pairs)))
        rows = {
            "bearings_i": _read_only(np.concatenate([block.correspondences.bearings_i for block in ordered])),
            "bearings_j": _read_only(np.concatenate([block.correspondences.bearings_j for block in ordered])),
            "centers_i": _read_only(np.concatenate([np.broadcast_to(block.correspondences.center_i, (count, 3)) for block, count in zip(ordered, counts)])),
            "centers_j": _read_only(np.concatenate([np.broadcast_to(block.correspondences.center_j, (count, 3)) for block, count in zip(ordered, counts)])),
            "sigma": _read_only(np.repeat(np.array([sigma_of_block[index] for index in order]), counts)),
            "pair": pair_of_row,
        }
        pair_of_row.flags.writeable = False
        pair_keys = np.array(pairs, dtype=np.int64)
        dimension = 6 * len(pairs) + 1
        mount = None
        if mount_of_block is not None:
            mount = MountRotations(
                block_starts=np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64),
                row_block=np.repeat(np.arange(len(ordered)), counts),
                block_pair=pair_of_ordered_block,
                sigma=_read_only(np.array([mount_of_block[index] for index in order])),
            )

        point: list[LinearisationPoint] = []  # the last full evaluation (relinearize_threshold > 0)

        def evaluate(*poses, jacobians=False, pair_keys=pair_keys, pair_starts=pair_starts, rows=rows, huber_k=huber_k, mount=mount):
            poses = list(poses)
            if point:
                model = relinearised_stacked_epipolar(poses, pair_keys, point[0], relinearize_threshold)
                if model is not None:
                    return model if jacobians else (model[0], None)
            residual, blocks = stacked_epipolar_error(poses, pair_keys, pair_starts, rows, huber_k, True if relinearize_threshold > 0 else jacobians, mount)
            if relinearize_threshold > 0:
                point[:] = [linearisation_point(poses, pair_keys, residual, blocks)]
            return residual, (blocks if jacobians else None)

        super().__init__(gtsam.noiseModel.Unit.Create(dimension), keys, make_error_function(keys, (POSE,) * len(keys), evaluate))
        self.blocks = tuple(ordered)  # row order of the (uncompressed) correspondences
        self.rows = int(sum(counts))

    def __len__(self) -> int:
        return self.rows
