"""Helpers shared by the simulator tests (tests/sim)."""
from __future__ import annotations

import numpy as np

from ampc_vo.sim.scene import Quad


def facing_marker(centre: np.ndarray, normal: np.ndarray, size: float) -> Quad:
    """An upright checker marker (corner at ``centre``) of side ``size`` facing ``normal``."""
    normal = normal / np.linalg.norm(normal)
    axis_u = np.cross(np.array([0.0, 0.0, 1.0]), normal)
    axis_u /= np.linalg.norm(axis_u)
    axis_v = np.cross(normal, axis_u)
    return Quad(centre - 0.5 * size * (axis_u + axis_v), axis_u, axis_v, size, size, "marker", "marker", size)
