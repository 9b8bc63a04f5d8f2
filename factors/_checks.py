"""Input guards of the factor constructors: bad input raises a clear ``ValueError`` here.

GTSAM cannot report a bad residual or Jacobian shape from a Python ``CustomFactor`` (a wrong
shape segfaults the process, DESIGN section 3), so every constructor validates keys, extrinsics,
bearings, scalars and the noise model dimension before GTSAM ever sees them.
"""
from __future__ import annotations

import numbers

import gtsam
import numpy as np

from ampc_vo.errors import BearingError
from ampc_vo.geometry import ROTATION_TOLERANCE, check_bearings, nearest_rotation, orthonormality_error


def check_key(key: object, name: str = "key") -> int:
    """A GTSAM key: a non-negative integer (e.g. ``gtsam.symbol('x', 0)``)."""
    if isinstance(key, bool) or not isinstance(key, numbers.Integral) or int(key) < 0:
        raise ValueError(f"{name} must be a non-negative integer GTSAM key, got {key!r}")
    return int(key)


def check_distinct_keys(keys: dict[str, object]) -> list[int]:
    """Validate named keys and require them to be pairwise different."""
    checked = [check_key(key, name) for name, key in keys.items()]
    if len(set(checked)) != len(checked):
        raise ValueError(f"keys must be distinct, got {dict(zip(keys, checked))}")
    return checked


def check_finite_scalar(value: object, name: str) -> float:
    """A finite real number as ``float``."""
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a real number, got {value!r}") from error
    if not np.isfinite(number):
        raise ValueError(f"{name} must be finite, got {number}")
    return number


def check_positive_scalar(value: object, name: str) -> float:
    """A finite number > 0 as ``float``."""
    number = check_finite_scalar(value, name)
    if number <= 0.0:
        raise ValueError(f"{name} must be positive, got {number}")
    return number


def check_rigid_transform(transform: object, name: str) -> np.ndarray:
    """A 4x4 rigid transform (numpy array or ``gtsam.Pose3``) as a float64 (4, 4) array; a rotation
    within :data:`~ampc_vo.geometry.ROTATION_TOLERANCE` of orthonormal (rounded) is projected onto
    the nearest rotation, a worse one is an error."""
    matrix = transform.matrix() if isinstance(transform, gtsam.Pose3) else np.asarray(transform, dtype=float)
    if matrix.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 rigid transform, got shape {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise ValueError(f"{name} contains NaN or infinite values")
    rotation = matrix[:3, :3]
    error = orthonormality_error(rotation)
    if error > ROTATION_TOLERANCE or np.linalg.det(rotation) <= 0.0 or np.max(np.abs(matrix[3] - [0.0, 0.0, 0.0, 1.0])) > 0.0:
        raise ValueError(f"{name} is not a rigid transform (rotation not orthonormal: error {error:.2g} > {ROTATION_TOLERANCE:g}, or bad last row)")
    if error > 1e-12:
        matrix = matrix.copy()
        matrix[:3, :3] = nearest_rotation(rotation)
    return matrix


def check_bearing_pair(bearings_i: object, bearings_j: object) -> tuple[np.ndarray, np.ndarray]:
    """Two (N, 3) arrays of corresponding bearings, N >= 1, finite and non-zero; returned as unit vectors.

    Raises :class:`ampc_vo.errors.BearingError` (a ``ValueError``).
    """
    unit_i = check_bearings(bearings_i, "bearings_i")
    unit_j = check_bearings(bearings_j, "bearings_j", count=unit_i.shape[0])
    if unit_i.shape[0] == 0:
        raise BearingError("bearings_i and bearings_j must hold at least one correspondence")
    return unit_i, unit_j


def check_noise_model(noise_model: object, dim: int, name: str = "noise_model") -> gtsam.noiseModel.Base:
    """A GTSAM noise model whose dimension equals the residual dimension ``dim``."""
    if not isinstance(noise_model, gtsam.noiseModel.Base):
        raise ValueError(f"{name} must be a gtsam.noiseModel, got {type(noise_model).__name__}")
    if noise_model.dim() != dim:
        raise ValueError(f"{name} has dimension {noise_model.dim()}, the factor has {dim} residuals")
    return noise_model
