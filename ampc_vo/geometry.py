"""Pure geometry helpers shared by every module (DESIGN section 1 and 2).

Poses are 4x4 homogeneous numpy arrays named ``T_<to>_<from>``; ``T_world_tractor`` maps
tractor-frame points into the world. Relative motion of one body between views i and j is
``T_i_j = inv(T_world_i) @ T_world_j`` (paper ``R_AA'``, ``t_AA'``). Angles are radians.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ampc_vo.errors import BearingError

ArrayF = np.ndarray

# The one rotation tolerance of the code base (issue 14): how far a rotation may be from a proper
# one, as |norm - 1| of a quaternion or max |R^T R - I| of a matrix. Within it a value is a rounded
# or hand-typed rotation and is normalised where it enters (rig.yaml, groundtruth.csv, TUM files,
# factor constructors); beyond it, it is a typo or a wrong order and an error.
ROTATION_TOLERANCE = 1e-3


def rot_z(angle: float) -> ArrayF:
    """Rotation about z by ``angle`` (paper eq. (7): Q = Rz(theta))."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(angle: float) -> ArrayF:
    """Rotation about x by ``angle``."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> ArrayF:
    """Rotation about y by ``angle``."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def unit_heading(angle: float | ArrayF) -> ArrayF:
    """DESIGN's ``u(a) = (cos a, sin a, 0)``; vectorised over ``angle``."""
    angle = np.asarray(angle, dtype=float)
    return np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=-1)


def unit_normal(angle: float | ArrayF) -> ArrayF:
    """DESIGN's ``n(a) = (-sin a, cos a, 0)``; vectorised over ``angle``."""
    angle = np.asarray(angle, dtype=float)
    return np.stack([-np.sin(angle), np.cos(angle), np.zeros_like(angle)], axis=-1)


def wrap_angle(angle: float | ArrayF) -> float | ArrayF:
    """Wrap an angle (or array of angles) to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def skew(vector: ArrayF) -> ArrayF:
    """Cross-product matrix ``[v]x`` with ``skew(a) @ b == cross(a, b)``."""
    x, y, z = vector
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def make_pose(rotation: ArrayF, translation: ArrayF) -> ArrayF:
    """4x4 pose from a 3x3 rotation and a 3-vector translation."""
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = translation
    return pose


def hitch_transform(hitch_angle: float) -> ArrayF:
    """``T_tractor_trailer = (Rz(theta), 0)`` (4x4): both body frames have their origin at the
    hitch (DESIGN 1; ``factors._lie.hitch_pose`` is the GTSAM form)."""
    return make_pose(rot_z(hitch_angle), np.zeros(3))


def invert_pose(pose: ArrayF) -> ArrayF:
    """Inverse of a 4x4 rigid transform."""
    rotation = pose[:3, :3]
    inverse = np.eye(4)
    inverse[:3, :3] = rotation.T
    inverse[:3, 3] = -rotation.T @ pose[:3, 3]
    return inverse


def relative_pose(T_world_i: ArrayF, T_world_j: ArrayF) -> ArrayF:
    """``T_i_j = inv(T_world_i) @ T_world_j`` (so ``p_i = R_ij p_j + t_ij``)."""
    return invert_pose(T_world_i) @ T_world_j


def planar_pose(x: float, y: float, yaw: float, z: float = 0.0) -> ArrayF:
    """Pose of a body on the ground plane at (x, y, z) with heading ``yaw``."""
    return make_pose(rot_z(yaw), np.array([x, y, z], dtype=float))


def yaw_of(rotation: ArrayF) -> float:
    """Heading (rotation about world z) of a rotation matrix or 4x4 pose."""
    return float(np.arctan2(rotation[1, 0], rotation[0, 0]))


def yaws_of(rotations: ArrayF) -> ArrayF:
    """Headings (N,) of a stack of rotation matrices or 4x4 poses (N, 3, 3) / (N, 4, 4): :func:`yaw_of` of each."""
    return np.arctan2(rotations[:, 1, 0], rotations[:, 0, 0])


def transform_points(pose: ArrayF, points: ArrayF) -> ArrayF:
    """Apply a 4x4 pose to (N, 3) points: ``R p + t``."""
    points = np.asarray(points, dtype=float)
    return points @ pose[:3, :3].T + pose[:3, 3]


def quat_xyzw_from_rotation(rotation: ArrayF) -> ArrayF:
    """Unit quaternion (x, y, z, w) with w >= 0 from a rotation matrix (Shepperd's method)."""
    m = np.asarray(rotation, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = np.array([(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s])
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def rotation_from_quat_xyzw(quaternion: ArrayF) -> ArrayF:
    """Rotation matrix from a quaternion (x, y, z, w), normalised first (so a rounded quaternion
    still gives an orthonormal matrix; checking that it was near unit length is the caller's job,
    :data:`ROTATION_TOLERANCE`)."""
    quaternion = np.asarray(quaternion, dtype=float)
    x, y, z, w = quaternion / np.linalg.norm(quaternion)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def orthonormality_error(rotation: ArrayF) -> float:
    """max |R^T R - I| of a 3x3 matrix (0 for a rotation; compare with :data:`ROTATION_TOLERANCE`)."""
    rotation = np.asarray(rotation, dtype=float)
    return float(np.max(np.abs(rotation.T @ rotation - np.eye(3))))


def nearest_rotation(matrix: ArrayF) -> ArrayF:
    """The rotation closest to a 3x3 matrix in the Frobenius norm (SVD projection onto SO(3),
    Higham 1989), for matrices that are rotations up to rounding."""
    u, _, vt = np.linalg.svd(np.asarray(matrix, dtype=float))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def pose_to_xyz_quat(pose: ArrayF) -> ArrayF:
    """(x, y, z, qx, qy, qz, qw) of a 4x4 pose, the row layout of TUM files and groundtruth.csv."""
    return np.concatenate([pose[:3, 3], quat_xyzw_from_rotation(pose[:3, :3])])


def pose_from_xyz_quat(row: ArrayF) -> ArrayF:
    """4x4 pose from (x, y, z, qx, qy, qz, qw)."""
    row = np.asarray(row, dtype=float)
    return make_pose(rotation_from_quat_xyzw(row[3:7]), row[:3])


def rotation_from_vector(vector: ArrayF) -> ArrayF:
    """Rotation matrix of a rotation vector (axis times angle, radians; SO(3) exp), SciPy's."""
    return Rotation.from_rotvec(np.asarray(vector, dtype=float)).as_matrix()


def rotation_angle(rotation: ArrayF) -> float:
    """Angle (radians) of a rotation matrix; used for rotation errors."""
    cos_angle = np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.arccos(cos_angle))


def normalize_bearings(vectors: ArrayF) -> ArrayF:
    """Scale (N, 3) vectors to unit length; raises :class:`BearingError` for zero/NaN rows."""
    vectors = np.asarray(vectors, dtype=float)
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    if not np.all(np.isfinite(norms)) or np.any(norms < 1e-12):
        raise BearingError("bearing vectors must be finite and non-zero")
    return vectors / norms


def check_bearings(bearings: ArrayF, name: str = "bearings", count: int | None = None) -> ArrayF:
    """Validate an (N, 3) array of bearings: right shape, finite, non-zero length.

    Returns the bearings as float64 unit vectors. Raises :class:`BearingError` (a ``ValueError``)
    naming ``name`` and the problem, so bad input never reaches GTSAM or a solver.
    """
    array = np.asarray(bearings, dtype=float)
    if array.ndim != 2 or array.shape[1] != 3:
        raise BearingError(f"{name} must have shape (N, 3), got {array.shape}")
    if count is not None and array.shape[0] != count:
        raise BearingError(f"{name} must have {count} rows, got {array.shape[0]}")
    if not np.all(np.isfinite(array)):
        raise BearingError(f"{name} contains NaN or infinite values")
    norms = np.linalg.norm(array, axis=1)
    if np.any(norms < 1e-9):
        raise BearingError(f"{name} contains zero-length vectors")
    return array / norms[:, None]


def triangulate_midpoint(bearings_first: np.ndarray, bearings_second: np.ndarray, T_first_second: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint triangulation of rays (vectorised); returns ``(points (N, 3) in the first camera
    frame, depths along the first rays (N,))``. Parallel rays get depth ``inf``."""
    rotation, baseline = T_first_second[:3, :3], T_first_second[:3, 3]
    d1 = bearings_first
    d2 = bearings_second @ rotation.T
    # minimise |s d1 - (baseline + u d2)|: normal equations of the 2x2 system
    a = np.einsum("na,na->n", d1, d1)
    b = np.einsum("na,na->n", d1, d2)
    c = np.einsum("na,na->n", d2, d2)
    e = d1 @ baseline
    f = d2 @ baseline
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(np.abs(det) > 1e-12, (e * c - b * f) / det, np.inf)
        u = np.where(np.abs(det) > 1e-12, (b * e - a * f) / det, np.inf)
        points = 0.5 * (s[:, None] * d1 + baseline + u[:, None] * d2)
    depth = np.where(u > 0, s, -np.abs(s))  # both rays must point at the point
    return points, depth


def rays_hit_box(origin: ArrayF, directions: ArrayF, lower: ArrayF, upper: ArrayF) -> np.ndarray:
    """Whether rays ``origin + t d`` (``t > 0``; origin (3,), directions (N, 3)) meet the axis-aligned
    box ``lower <= p <= upper`` (slab test, vectorised): mask (N,)."""
    directions = np.asarray(directions, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / directions
        near = (np.asarray(lower, dtype=float) - origin) * inverse
        far = (np.asarray(upper, dtype=float) - origin) * inverse
    entry = np.nanmax(np.minimum(near, far), axis=1)
    leave = np.nanmin(np.maximum(near, far), axis=1)
    return (leave >= np.maximum(entry, 0.0)) & np.isfinite(leave)
