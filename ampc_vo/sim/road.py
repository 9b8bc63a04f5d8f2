"""Road surface of the simulated world: height and normal at any world ``(x, y)`` (issue 13, DESIGN 6).

The surface is the sum of three parts, each vectorised over points:

* a **plane** ``z = slope_x x + slope_y y`` (a yard's drainage slope; 0 by default);
* a **road profile** along a centre line (station ``s``, lateral offset ``d``, left positive):
  the elevation ``z(s)`` of a grade line with **parabolic vertical curves** (AASHTO, *A Policy on
  Geometric Design of Highways and Streets*, 2018, sec. 3.4.6: the grade changes linearly over the
  curve length ``L``, so the elevation is a parabola there). Grade changes ``dg_i`` at stations
  ``s_i`` give ``g(s) = g_0 + sum_i dg_i clip((s - s_i + L/2) / L, 0, 1)`` and, integrated in
  closed form, ``z(s) = g_0 s + sum_i dg_i I((s - s_i + L/2) / L) L`` with ``I(u) = 0`` (u < 0),
  ``u^2 / 2`` (0 <= u <= 1), ``u - 1/2`` (u > 1). The **cross-section** is a crown of cross-slope
  ``c`` (both halves fall away from the centre) that rotates into a planar **superelevation**
  ``e(s)`` in curves (the outer lane rotates first, AASHTO sec. 3.3.8 "superelevation runoff"):

      h(s, d) = z(s) - e d - c |d| max(0, 1 - |e| / c),     e(s) = e_max clip(kappa(s) R_min, -1, 1)

  with the centre line's curvature ``kappa(s)`` (> 0 left: the left side is lower), linearly
  interpolated between centre-line samples: superelevation proportional to curvature, reaching
  ``e_max`` at the minimum radius ``R_min = v_d^2 / (g (e_max + f_max))`` of the design speed
  ``v_d`` with side friction ``f_max = 0.15`` (AASHTO sec. 3.3.5, distribution method 1), so it
  runs off along the clothoid transitions. Beyond the shoulders (``|d| > edge``) the terrain is level across at the
  height of the edge;
* **bumps and potholes**: raised-cosine features fixed in the world (centre, direction, length
  along, width across, height; negative height = a pothole).

The normal is ``normalize(-dh/dx, -dh/dy, 1)`` from central differences of the height (1 cm).
World points are mapped to ``(s, d)`` through the nearest sample of the densely resampled centre
line (0.25 m) and the tangent there; the profile therefore needs a centre line that does not fold
back onto itself within the road band (routes with reversing use the plane and bumps only).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

GRAVITY = 9.81
SIDE_FRICTION = 0.15    # f_max of the superelevation distribution (AASHTO 2018, table 3-7 at ~50 km/h)
_STEP_M = 0.25          # centre-line resampling for the (s, d) lookup
_NORMAL_STEP_M = 0.01   # central-difference step of the normal


@dataclass(frozen=True)
class Bump:
    """A raised-cosine bump (``height`` > 0) or pothole (< 0) fixed in the world."""

    center: tuple[float, float]
    direction: float      # radians: heading of the ``length`` axis (the road direction there)
    length: float         # m along ``direction``
    width: float          # m across
    height: float         # m

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        relative = xy - np.asarray(self.center)
        along = relative @ np.array([np.cos(self.direction), np.sin(self.direction)])
        across = relative @ np.array([-np.sin(self.direction), np.cos(self.direction)])
        u, w = 2.0 * along / self.length, 2.0 * across / self.width
        inside = (np.abs(u) < 1.0) & (np.abs(w) < 1.0)
        # cos^2 taper across keeps the edges of a pothole smooth as well (evaluated inside only)
        height = np.zeros(np.shape(u))
        height[inside] = self.height * 0.5 * (1.0 + np.cos(np.pi * u[inside])) * np.cos(0.5 * np.pi * w[inside]) ** 2
        return height


def relief_height(bumps: "tuple[Bump, ...] | list[Bump]", xy: np.ndarray) -> np.ndarray:
    """Summed height (N,) of bumps and potholes at world points (N, 2) (the relief the renderer adds
    to the road's quads, ``render.relief_hits``)."""
    height = np.zeros(len(xy))
    for bump in bumps:
        height = height + bump.height_at(xy)
    return height


def relief_gradient(bumps: "tuple[Bump, ...] | list[Bump]", xy: np.ndarray) -> np.ndarray:
    """Gradient (N, 2) of :func:`relief_height` by central differences (``_NORMAL_STEP_M``)."""
    step = _NORMAL_STEP_M
    dx, dy = np.array([step, 0.0]), np.array([0.0, step])
    return np.column_stack([relief_height(bumps, xy + dx) - relief_height(bumps, xy - dx),
                            relief_height(bumps, xy + dy) - relief_height(bumps, xy - dy)]) / (2.0 * step)


@dataclass(frozen=True)
class RoadProfile:
    """Vertical and cross-section design of a road along its centre line (module docstring)."""

    start_grade: float = 0.0                                  # grade at station 0 (rise / run)
    grade_changes: tuple[tuple[float, float], ...] = ()       # (station m, new grade) points of vertical intersection
    vertical_curve_m: float = 80.0                            # L of every parabolic vertical curve
    crown: float = 0.0                                        # cross-slope c of each half on straights
    max_superelevation: float = 0.0                           # e_max
    design_speed: float = 15.0                                # v_d (m/s): e_max is reached at R_min = v_d^2 / (g (e_max + f_max))

    def elevation(self, station: np.ndarray) -> np.ndarray:
        """Centre-line elevation ``z(s)``, the closed-form integral of the grade ``g(s)`` (module docstring; z(0) = 0)."""
        station = np.asarray(station, dtype=float)

        def ramp_integral(s: np.ndarray, at: float) -> np.ndarray:
            length = self.vertical_curve_m
            u = (s - at + 0.5 * length) / length
            return length * np.where(u < 0.0, 0.0, np.where(u <= 1.0, 0.5 * u * u, u - 0.5))

        height = self.start_grade * station
        previous = self.start_grade
        for at, new in self.grade_changes:
            height = height + (new - previous) * (ramp_integral(station, at) - ramp_integral(np.zeros(1), at))
            previous = new
        return height

    def superelevation(self, curvature: np.ndarray) -> np.ndarray:
        """``e = e_max clip(kappa R_min, -1, 1)``, signed like the curvature (left turn: left side low)."""
        minimum_radius = self.design_speed**2 / (GRAVITY * (self.max_superelevation + SIDE_FRICTION))
        return self.max_superelevation * np.clip(np.asarray(curvature) * minimum_radius, -1.0, 1.0)

    def cross_section(self, lateral: np.ndarray, curvature: np.ndarray) -> np.ndarray:
        """Height relative to the centre line at lateral offset ``d`` (module docstring)."""
        bank = self.superelevation(curvature)
        crown = self.crown * np.abs(lateral) * (np.clip(1.0 - np.abs(bank) / self.crown, 0.0, 1.0) if self.crown > 0.0 else 0.0)
        return -bank * lateral - crown


@dataclass(frozen=True)
class Centerline2D:
    """The road's reference line: points (K, 2) every ~0.25 m, unit tangents (K, 2), station (K,)
    and curvature (K,)."""

    points: np.ndarray
    tangents: np.ndarray
    station: np.ndarray
    curvature: np.ndarray
    tree: cKDTree = field(repr=False, compare=False)

    @staticmethod
    def from_path(points: np.ndarray, station: np.ndarray, curvature: np.ndarray, lateral_offset: float = 0.0) -> "Centerline2D":
        """Resample a path (N, 2) with its stations (N,) and curvatures (N,) every 0.25 m, shifted
        ``lateral_offset`` to the left (the road's centre left of the driven lane)."""
        keep = np.concatenate([[True], np.diff(station) > 1e-9])
        points, station, curvature = points[keep], station[keep], curvature[keep]
        samples = np.arange(station[0], station[-1] + 1e-9, _STEP_M)
        resampled = np.column_stack([np.interp(samples, station, points[:, axis]) for axis in range(2)])
        tangents = np.gradient(resampled, axis=0)
        tangents /= np.maximum(np.linalg.norm(tangents, axis=1, keepdims=True), 1e-12)
        normals = np.column_stack([-tangents[:, 1], tangents[:, 0]])
        kappa = np.interp(samples, station, curvature)
        shifted = resampled + lateral_offset * normals
        return Centerline2D(shifted, tangents, samples, kappa, cKDTree(shifted))

    def station_offset(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, d, kappa)`` of world points (N, 2): station, left offset and curvature at the
        nearest centre-line sample, refined along its tangent."""
        _, index = self.tree.query(xy)
        relative = xy - self.points[index]
        tangent = self.tangents[index]
        along = np.einsum("ij,ij->i", relative, tangent)
        lateral = relative[:, 1] * tangent[:, 0] - relative[:, 0] * tangent[:, 1]
        # curvature interpolated towards the neighbouring sample (a nearest-sample curvature would
        # step the superelevated surface by centimetres)
        neighbour = np.clip(index + np.where(along >= 0.0, 1, -1), 0, len(self.station) - 1)
        fraction = np.clip(np.abs(along) / _STEP_M, 0.0, 1.0)
        curvature = self.curvature[index] + (self.curvature[neighbour] - self.curvature[index]) * fraction
        return self.station[index] + along, lateral, curvature


@dataclass(frozen=True)
class RoadSurface:
    """Height and normal of the world's driving surface (module docstring)."""

    plane_slope: tuple[float, float] = (0.0, 0.0)
    profile: RoadProfile | None = None
    centerline: Centerline2D | None = None
    edge_m: float = 6.5                       # |d| beyond which the terrain is level across
    bumps: tuple[Bump, ...] = ()
    lane_offset_m: float = 0.0                # the road's centre this far left of the driven path (scene)

    @property
    def is_flat(self) -> bool:
        return self.plane_slope == (0.0, 0.0) and not self.bumps and (
            self.profile is None or (self.profile.start_grade == 0.0 and not self.profile.grade_changes
                                     and self.profile.crown == 0.0 and self.profile.max_superelevation == 0.0))

    def height(self, xy: np.ndarray) -> np.ndarray:
        """Surface height (N,) at world points (N, 2) (or (..., 2))."""
        xy = np.asarray(xy, dtype=float)
        shape = xy.shape[:-1]
        flat = xy.reshape(-1, 2)
        height = flat @ np.asarray(self.plane_slope, dtype=float)
        if self.profile is not None and self.centerline is not None:
            station, lateral, curvature = self.centerline.station_offset(flat)
            lateral = np.clip(lateral, -self.edge_m, self.edge_m)
            height = height + self.profile.elevation(station) + self.profile.cross_section(lateral, curvature)
        return (height + relief_height(self.bumps, flat)).reshape(shape)

    def normal(self, xy: np.ndarray) -> np.ndarray:
        """Unit upward normals (N, 3) by central differences of :meth:`height`."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        step = _NORMAL_STEP_M
        offsets = np.array([[step, 0.0], [-step, 0.0], [0.0, step], [0.0, -step]])
        heights = self.height(xy[:, None, :] + offsets[None, :, :])
        normal = np.column_stack([-(heights[:, 0] - heights[:, 1]) / (2 * step), -(heights[:, 2] - heights[:, 3]) / (2 * step), np.ones(len(xy))])
        return normal / np.linalg.norm(normal, axis=1, keepdims=True)

    def lateral_slope(self, xy: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """``dh/dn``: the surface's rise per metre to the left of ``heading`` (radians) at ``xy``."""
        normal = self.normal(xy)
        gradient = -normal[:, :2] / normal[:, 2:3]
        return -gradient[:, 0] * np.sin(heading) + gradient[:, 1] * np.cos(heading)


FLAT_ROAD = RoadSurface()


@dataclass(frozen=True)
class RoadConfig:
    """The ``road:`` section of a sim config (percentages in YAML, fractions here)."""

    start_grade: float = 0.0                                   # YAML start_grade_percent
    grade_changes: tuple[tuple[float, float], ...] = ()        # YAML grades: [[station m, grade percent], ...]
    vertical_curve_m: float = 80.0
    crown: float = 0.0                                         # YAML crown_percent
    max_superelevation: float = 0.0                            # YAML max_superelevation_percent
    design_speed: float = 15.0                                 # m/s
    lane_offset_m: float = 0.0                                 # the road's centre this far left of the tractor's path
    plane_slope: tuple[float, float] = (0.0, 0.0)              # YAML plane_slope_percent: [x, y]
    bumps: tuple[tuple[float, float, float, float, float], ...] = ()  # (station, lateral, length, width, height) m

    @property
    def has_profile(self) -> bool:
        return bool(self.start_grade or self.grade_changes or self.crown or self.max_superelevation)

    def profile(self) -> RoadProfile:
        return RoadProfile(self.start_grade, self.grade_changes, self.vertical_curve_m, self.crown, self.max_superelevation, self.design_speed)

    def lane_slope(self, curvature: Callable[[float], float], lane_change_offset: Callable[[float], float] | None = None
                   ) -> Callable[[float, float], float]:
        """``dh/dn`` (rise per metre to the left) of the driven lane at a station and heading, for
        the kinematics' cross-slope drift: the plane's gradient across the heading plus the
        cross-section's slope at ``d = -lane_offset_m + lane_change_offset(station)`` with the
        design line's ``curvature(station)`` (bumps ignored)."""
        profile = self.profile()
        slope_x, slope_y = self.plane_slope
        has_profile = self.has_profile
        crown, maximum = profile.crown, profile.max_superelevation
        minimum_radius = profile.design_speed**2 / (GRAVITY * (maximum + SIDE_FRICTION))
        lane = -self.lane_offset_m

        def slope(station: float, heading: float) -> float:  # scalar math: called 4 times per integration step
            value = -slope_x * math.sin(heading) + slope_y * math.cos(heading) if slope_x or slope_y else 0.0
            if has_profile:
                lateral = lane + (lane_change_offset(station) if lane_change_offset is not None else 0.0)
                side = math.copysign(1.0, lateral) if lateral != 0.0 else 0.0
                bank = maximum * min(max(curvature(max(station, 0.0)) * minimum_radius, -1.0), 1.0)
                value += -bank - (crown * max(0.0, 1.0 - abs(bank) / crown) * side if crown > 0.0 else 0.0)
            return value

        return slope

    def surface(self, path_xy: np.ndarray, station: np.ndarray, curvature: np.ndarray, edge_m: float) -> RoadSurface:
        """The :class:`RoadSurface` along a design path (N, 2) with its stations and curvatures
        (``routes.Route.design_path``), the road's centre ``lane_offset_m`` left of it; bumps are
        placed at their station on the road (``lateral`` from the road's centre)."""
        centerline = Centerline2D.from_path(path_xy, station, curvature, self.lane_offset_m)
        bumps = []
        for at, lateral, length, width, height in self.bumps:
            index = int(np.clip(np.searchsorted(centerline.station, at), 0, len(centerline.station) - 1))
            tangent = centerline.tangents[index]
            normal = np.array([-tangent[1], tangent[0]])
            center = centerline.points[index] + lateral * normal
            bumps.append(Bump((float(center[0]), float(center[1])), float(np.arctan2(tangent[1], tangent[0])), length, width, height))
        return RoadSurface(self.plane_slope, self.profile() if self.has_profile else None, centerline if self.has_profile else None, edge_m,
                           tuple(bumps), self.lane_offset_m)
