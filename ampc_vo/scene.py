"""The 3D world the simulated cameras look at: textured planar rectangles (DESIGN section 6).

One description serves two consumers, so that bearing measurements and rendered images agree:
``simulation`` samples landmarks on the quads' surfaces and ``render`` ray-casts the same quads with
their textures.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

QUAD_KINDS = ("road", "ground", "facade", "box", "pole", "marker")


@dataclass(frozen=True, eq=False)
class Quad:
    """A planar textured rectangle in world coordinates.

    Its points are ``origin + a * axis_u + b * axis_v`` for ``a`` in [0, width] and ``b`` in
    [0, height] (metres); ``axis_u`` and ``axis_v`` are orthonormal. Texture coordinates are
    ``(a, b) / texture_scale`` (texture repeats every ``texture_scale`` metres).
    """

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    width: float
    height: float
    kind: str
    texture: str
    texture_scale: float = 4.0

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.axis_u, self.axis_v)

    def points(self, coordinates: np.ndarray) -> np.ndarray:
        """World points (N, 3) at surface coordinates (N, 2) = (a, b) in metres."""
        coordinates = np.asarray(coordinates, dtype=float)
        return self.origin + coordinates[:, :1] * self.axis_u + coordinates[:, 1:2] * self.axis_v


@dataclass(frozen=True)
class Scene:
    """All quads of a simulated world."""

    quads: tuple[Quad, ...]
