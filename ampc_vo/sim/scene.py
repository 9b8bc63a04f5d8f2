"""The 3D world the simulated cameras look at: textured planar rectangles (DESIGN section 6).

One description serves two consumers, so that bearing measurements and rendered images agree:
``simulation`` samples landmarks on the quads' surfaces and ``render`` ray-casts the same quads with
their textures.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

logger = logging.getLogger(__name__)

if TYPE_CHECKING:  # pragma: no cover
    from ampc_vo.io.groundtruth import Trajectory
    from ampc_vo.sim.config import SceneConfig
    from ampc_vo.sim.road import Bump, Centerline2D, RoadSurface

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
    # road quads: where the quad lies across its carriageway, for the lane markings: the across-road
    # coordinate (m, from the carriageway's right edge) of its b = 0 edge, and the carriageway's
    # width (0: the quad is the whole carriageway)
    road_across: float = 0.0
    road_width: float = 0.0

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.axis_u, self.axis_v)

    def points(self, coordinates: np.ndarray) -> np.ndarray:
        """World points (N, 3) at surface coordinates (N, 2) = (a, b) in metres."""
        coordinates = np.asarray(coordinates, dtype=float)
        return self.origin + coordinates[:, :1] * self.axis_u + coordinates[:, 1:2] * self.axis_v


@dataclass(frozen=True)
class Scene:
    """All quads of a simulated world, and the bumps and potholes (``road.Bump``) that the renderer
    adds to the heights of its horizontal road and ground quads (``relief``, DESIGN 6)."""

    quads: tuple[Quad, ...]
    relief: "tuple[Bump, ...]" = ()


# ---------------------------------------------------------------------- procedural scene along a route
# Body-frame x of points on each body's centre line that sweep the road (hitch at 0): tractor nose,
# axle and hitch; trailer hitch, middle and rear. The clearance corridor is measured from them.
TRACTOR_FOOTPRINT_X = (3.5, 1.5, 0.0)
TRAILER_FOOTPRINT_X = (0.0, -4.5, -9.0, -14.0)
FACADE_TEXTURES = ("brick", "concrete", "wood", "facade")
WALL_TEXTURES = ("concrete", "brick")
OBJECT_TEXTURES = ("wood", "metal", "concrete")
_ROAD_STEP_M = 2.0
_ROAD_OVERLAP_M = 0.6
# the asphalt is the road surface at z = 0 (the body origin's height: ground truth, the
# ground-plane scale and KITTI agree on it); shoulders and grass lie slightly below it so the
# overlapping quads do not z-fight
_ROAD_Z = 0.0
_SHOULDER_Z = -0.01
_GRASS_Z = -0.02
_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Centerline:
    """The road's centre line, resampled every ~2 m: points (K, 3), unit tangents (K, 3), left
    normals (K, 3) and arc length (K,). It extends the tractor's path straight before its start and
    after its end, so the rear camera at the start and the front camera at the end see a street."""

    points: np.ndarray
    tangents: np.ndarray
    normals: np.ndarray
    arc_length: np.ndarray


def route_centerline(T_world_tractor: np.ndarray, extension_m: float, step_m: float = _ROAD_STEP_M) -> Centerline:
    """Centre line through the tractor hitch positions (F, 4, 4 poses) with straight extensions."""
    positions = T_world_tractor[:, :3, 3].copy()
    positions[:, 2] = 0.0
    start_heading = T_world_tractor[0, :3, 0] * np.array([1.0, 1.0, 0.0])
    end_heading = T_world_tractor[-1, :3, 0] * np.array([1.0, 1.0, 0.0])
    start_heading /= np.linalg.norm(start_heading)
    end_heading /= np.linalg.norm(end_heading)
    offsets = np.arange(1.0, extension_m + 1e-9, 1.0)
    before = positions[0] - offsets[::-1, None] * start_heading
    after = positions[-1] + offsets[:, None] * end_heading
    polyline = np.concatenate([before, positions, after])
    steps = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    keep = np.concatenate([[True], steps > 1e-6])
    polyline = polyline[keep]
    cumulative = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(polyline, axis=0), axis=1))])
    samples = np.linspace(0.0, cumulative[-1], max(int(np.ceil(cumulative[-1] / step_m)), 1) + 1)
    points = np.stack([np.interp(samples, cumulative, polyline[:, axis]) for axis in range(3)], axis=1)
    tangents = np.gradient(points, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    normals = np.cross(_UP, tangents)
    return Centerline(points, tangents, normals, samples - extension_m)


def _road_centerline(line: "Centerline2D", start: float, stop: float, step_m: float = _ROAD_STEP_M) -> Centerline:
    """A scene :class:`Centerline` (every ~2 m, z = 0) along a road's design line between two stations."""
    samples = np.linspace(start, stop, max(int(np.ceil((stop - start) / step_m)), 1) + 1)
    points = np.column_stack([np.interp(samples, line.station, line.points[:, axis]) for axis in range(2)] + [np.zeros(len(samples))])
    tangents = np.gradient(points, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    return Centerline(points, tangents, np.cross(_UP, tangents), samples)


def swept_path_points(T_world_tractor: np.ndarray, T_world_trailer: np.ndarray, centerline: Centerline | None = None) -> np.ndarray:
    """2-D points (N, 2) on the centre lines of both bodies over the whole trajectory (and the
    extended road, if given): everything within the clearance of them is the vehicle's corridor."""
    parts = []
    for poses, footprint in ((T_world_tractor, TRACTOR_FOOTPRINT_X), (T_world_trailer, TRAILER_FOOTPRINT_X)):
        for body_x in footprint:
            parts.append(poses[:, :2, 3] + body_x * poses[:, :2, 0])
    if centerline is not None:
        parts.append(centerline.points[:, :2])
    # Frames are at most ~2 m apart; build_scene adds a 0.5 m margin to the clearance for the gaps.
    return np.concatenate(parts)


def _strip_quads(centerline: Centerline, lateral_from: float, lateral_to: float, z: float, kind: str, texture: str, texture_scale: float,
                 road: "RoadSurface | None" = None) -> list[Quad]:
    """Rectangles covering the band ``lateral_from..lateral_to`` (m, left positive) along the centre line.

    On a 3D road (``road`` given) each rectangle is tilted onto the surface: ``axis_u`` along the
    chord between the surface points at the band's middle, ``axis_v`` across to the surface at the
    band's far edge (orthogonalised), raised ``z`` plus the mean of the surface's deviation from that
    plane across the band (a crowned road deviates from one plane by up to ``crown * width / 4``)."""
    if road is not None:
        return _tilted_strip_quads(centerline, lateral_from, lateral_to, z, kind, texture, texture_scale, road)
    quads = []
    for index in range(len(centerline.points) - 1):
        start, stop = centerline.points[index], centerline.points[index + 1]
        chord = stop - start
        length = float(np.linalg.norm(chord))
        if length < 1e-6:
            continue
        axis_u = chord / length
        axis_v = np.cross(_UP, axis_u)
        origin = start - _ROAD_OVERLAP_M * axis_u + lateral_from * axis_v + np.array([0.0, 0.0, z])
        quads.append(Quad(origin, axis_u, axis_v, length + 2.0 * _ROAD_OVERLAP_M, lateral_to - lateral_from, kind, texture, texture_scale))
    return quads


_MERGE_PLAN_M = 0.02      # merged tilted strips: largest distance of the centre line from the merged chord
_MERGE_HEIGHT_M = 0.01    # and largest height difference from the 2 m pieces they replace
_MERGE_PIECES = 12        # at most this many 2 m pieces in one quad


def _surface_quad(start: np.ndarray, end: np.ndarray, lateral_from: float, lateral_to: float, z: float, road: "RoadSurface"
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """``(origin, axis_u, axis_v, width, height)`` of the band ``lateral_from..lateral_to`` over the
    chord ``start -> end`` (2-D) tilted onto the surface (:func:`_strip_quads`)."""
    chord = end - start
    direction = chord / np.linalg.norm(chord)
    normal = np.array([-direction[1], direction[0]])
    middle = 0.5 * (lateral_from + lateral_to)
    across = np.linspace(lateral_from, lateral_to, 5)
    heights = road.height(np.vstack([start + across[:, None] * normal, start + middle * normal, end + middle * normal]))
    begin_mid = np.append(start + middle * normal, heights[5])
    end_mid = np.append(end + middle * normal, heights[6])
    axis_u = (end_mid - begin_mid) / np.linalg.norm(end_mid - begin_mid)
    edge = np.append((lateral_to - lateral_from) * normal, heights[4] - heights[0])
    axis_v = edge - (edge @ axis_u) * axis_u
    axis_v /= np.linalg.norm(axis_v)
    plane = heights[0] + (heights[4] - heights[0]) * (across - lateral_from) / (lateral_to - lateral_from)
    origin = np.append(start + lateral_from * normal, heights[0] + float(np.mean(heights[:5] - plane)) + z)
    return origin, axis_u, axis_v, float(np.linalg.norm(end_mid - begin_mid)), float(np.linalg.norm(edge))


def _plane_height(origin: np.ndarray, axis_u: np.ndarray, axis_v: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Height of the quad's plane over points (N, 2)."""
    normal = np.cross(axis_u, axis_v)
    return origin[2] - ((xy[:, 0] - origin[0]) * normal[0] + (xy[:, 1] - origin[1]) * normal[1]) / normal[2]


def _tilted_strip_quads(centerline: Centerline, lateral_from: float, lateral_to: float, z: float, kind: str, texture: str,
                        texture_scale: float, road: "RoadSurface") -> list[Quad]:
    """:func:`_strip_quads` on the road surface: 2 m pieces, merged greedily into longer quads where
    the centre line stays within ``_MERGE_PLAN_M`` of the merged chord and the merged plane within
    ``_MERGE_HEIGHT_M`` of the pieces' planes (straights on a constant grade become one quad, as on
    flat roads; curves and vertical curves keep short pieces)."""
    points = centerline.points[:, :2]
    keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-6])
    points = points[keep]
    count = len(points) - 1
    if count < 1:
        return []

    def chord_ends(first: int, last: int) -> tuple[np.ndarray, np.ndarray]:
        direction = points[last + 1] - points[first]
        direction = direction / np.linalg.norm(direction)
        return points[first] - _ROAD_OVERLAP_M * direction, points[last + 1] + _ROAD_OVERLAP_M * direction

    pieces = [_surface_quad(*chord_ends(index, index), lateral_from, lateral_to, z, road) for index in range(count)]
    across = np.linspace(0.0, 1.0, 4)
    quads = []
    first = 0
    while first < count:
        best, best_quad = first, pieces[first]
        for last in range(first + 1, min(first + _MERGE_PIECES, count)):
            start, end = chord_ends(first, last)
            direction = (end - start) / np.linalg.norm(end - start)
            offsets = points[first:last + 2] - start
            if np.max(np.abs(offsets[:, 0] * direction[1] - offsets[:, 1] * direction[0])) > _MERGE_PLAN_M:
                break
            candidate = _surface_quad(start, end, lateral_from, lateral_to, z, road)
            worst = 0.0
            for index in range(first, last + 1):
                origin, axis_u, axis_v, width, height = pieces[index]
                xy = origin[:2] + (across[:, None, None] * width * axis_u[:2] + across[None, :, None] * height * axis_v[:2]).reshape(-1, 2)
                worst = max(worst, float(np.max(np.abs(_plane_height(candidate[0], candidate[1], candidate[2], xy)
                                                       - _plane_height(origin, axis_u, axis_v, xy)))))
            if worst > _MERGE_HEIGHT_M:
                break
            best, best_quad = last, candidate
        origin, axis_u, axis_v, width, height = best_quad
        quads.append(Quad(origin, axis_u, axis_v, width, height, kind, texture, texture_scale))
        first = best + 1
    return quads


def _clear(points_2d: np.ndarray, tree, clearance: float) -> bool:
    distances, _ = tree.query(points_2d)
    return bool(np.min(distances) >= clearance)


def _segment_samples(start: np.ndarray, stop: np.ndarray, spacing: float = 0.5) -> np.ndarray:
    count = max(int(np.ceil(np.linalg.norm(stop - start) / spacing)), 1) + 1
    return start[None, :2] + np.linspace(0.0, 1.0, count)[:, None] * (stop - start)[None, :2]


def box_quads(center: np.ndarray, yaw: float, size: tuple[float, float, float], kind: str, texture: str, texture_scale: float = 2.0,
              base_z: float = 0.0) -> list[Quad]:
    """Four outward-facing sides and the top of an upright box standing on ``z = base_z``."""
    length, width, height = size
    x_axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    y_axis = np.cross(_UP, x_axis)
    base = np.array([center[0], center[1], base_z])
    quads = []
    for outward, half_normal, side in ((x_axis, length / 2, width), (-x_axis, length / 2, width), (y_axis, width / 2, length), (-y_axis, width / 2, length)):
        axis_u = np.cross(_UP, outward)  # so that axis_u x up = outward normal
        origin = base + half_normal * outward - (side / 2) * axis_u
        quads.append(Quad(origin, axis_u, _UP.copy(), side, height, kind, texture, texture_scale))
    top_origin = base - (length / 2) * x_axis - (width / 2) * y_axis + height * _UP
    quads.append(Quad(top_origin, x_axis, y_axis, length, width, kind, texture, texture_scale))
    return quads


def build_scene(trajectory: "Trajectory", rng: np.random.Generator, config: "SceneConfig | None" = None,
                road: "RoadSurface | None" = None) -> Scene:
    """Procedural world along a trajectory (``kinematics.Trajectory``) for rendering and landmarks.

    Quads: one large grass ``ground`` plane (2 cm below the road), gravel shoulders and the asphalt ``road`` strip
    (slightly raised, so the renderer's nearest hit shows them), vertical ``facade`` quads (building
    fronts and low walls) on both sides at 5-25 m, facing the road, and free-standing ``box`` and
    ``pole`` objects. The road is extended straight before the start and after the end
    (``config.extension_m``) and lined with facades there too. No vertical quad comes closer than
    ``config.clearance`` (2-D distance) to the swept centre lines of both bodies or the road's
    centre line, so nothing intersects the vehicle's path. ``config`` is a
    :class:`ampc_vo.sim.config.SceneConfig` (defaults if ``None``).

    On a 3D road (``road``, a :class:`ampc_vo.sim.road.RoadSurface` that is not flat) the road,
    shoulders and a grass band of ``ground_margin_m`` on each side are tilted strips on the surface
    (:func:`_strip_quads`), centred on the road's centre (``road.lane_offset_m`` left of the path);
    the large grass plane lies 1 m below the lowest point, and facades and objects stand on the
    terrain (sunk 0.5 m so that no gap shows on a slope). Bumps and potholes are not in the quads:
    they are the scene's ``relief``, which the renderer adds per pixel (the strips follow the road
    without them).
    """
    relief = tuple(road.bumps) if road is not None else ()
    if road is not None and road.bumps:
        road = dataclasses.replace(road, bumps=())
    if road is not None and road.is_flat:
        road = None
    from scipy.spatial import cKDTree

    from ampc_vo.sim.config import SceneConfig

    config = SceneConfig() if config is None else config
    centerline = route_centerline(trajectory.T_world_tractor, config.extension_m)
    if road is not None and road.centerline is not None:  # the road's own design line (lane changes do not move it)
        end = float(trajectory.arc_length[-1]) if trajectory.arc_length is not None else float(road.centerline.station[-1])
        centerline = _road_centerline(road.centerline, -config.extension_m, end + config.extension_m)
    corridor = cKDTree(swept_path_points(trajectory.T_world_tractor, trajectory.T_world_trailer, centerline))
    clearance = config.clearance + 0.5  # margin for the sampling of the corridor points
    half_road = config.road_width / 2.0

    low, high = centerline.points[:, :2].min(axis=0) - config.ground_margin_m, centerline.points[:, :2].max(axis=0) + config.ground_margin_m
    grass_z = _GRASS_Z
    centre = 0.0
    if road is not None:
        centre = road.lane_offset_m if road.centerline is None else 0.0
        grass_z = float(np.min(road.height(centerline.points[:, :2]))) - 1.0
    quads: list[Quad] = [Quad(np.array([low[0], low[1], grass_z]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), float(high[0] - low[0]), float(high[1] - low[1]), "ground", "grass", 4.0)]
    # each half of the carriageway is a plane of its own: the crown turns the cross-slope over at the
    # centre line (one plane across both halves lay up to crown x width / 4 off the lanes)
    for lateral_from, lateral_to in ((centre - half_road, centre), (centre, centre + half_road)):
        quads += [dataclasses.replace(quad, road_across=lateral_from - (centre - half_road), road_width=config.road_width)
                  for quad in _strip_quads(centerline, lateral_from, lateral_to, _ROAD_Z, "road", "asphalt", 4.0, road)]
    quads += _strip_quads(centerline, centre + half_road, centre + half_road + config.shoulder_width, _SHOULDER_Z, "ground", "gravel", 3.0, road)
    quads += _strip_quads(centerline, centre - half_road - config.shoulder_width, centre - half_road, _SHOULDER_Z, "ground", "gravel", 3.0, road)
    if road is not None:
        outer = centre + half_road + config.shoulder_width
        quads += _strip_quads(centerline, outer, outer + config.ground_margin_m, _GRASS_Z, "ground", "grass", 4.0, road)
        outer = centre - half_road - config.shoulder_width
        quads += _strip_quads(centerline, outer - config.ground_margin_m, outer, _GRASS_Z, "ground", "grass", 4.0, road)

    def terrain(points_2d: np.ndarray) -> float:
        """Height to stand a facade or object on: the lowest terrain under it, 0.5 m sunk (0 on a flat road)."""
        if road is None:
            return 0.0
        return float(np.min(road.height(np.atleast_2d(points_2d)[:, :2]))) - 0.5

    total = float(centerline.arc_length[-1] - centerline.arc_length[0])
    arc = centerline.arc_length - centerline.arc_length[0]

    def frame_at(s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        index = int(np.clip(np.searchsorted(arc, s), 0, len(arc) - 1))
        return centerline.points[index], centerline.tangents[index], centerline.normals[index]

    facade_count = object_count = 0
    for side in (1.0, -1.0):
        s = float(rng.uniform(0.0, 4.0))
        while s < total:
            length = float(rng.uniform(*config.facade_length))
            distance = float(rng.uniform(*config.facade_distance))
            is_wall = rng.random() < 0.2
            height = float(rng.uniform(1.5, 3.0)) if is_wall else float(rng.uniform(*config.facade_height))
            point, tangent, normal = frame_at(s + length / 2.0)
            axis_u = tangent if side > 0 else -tangent  # normal axis_u x up faces the road
            center = point + side * distance * normal
            start, stop = center - axis_u * length / 2.0, center + axis_u * length / 2.0
            if _clear(_segment_samples(start, stop), corridor, clearance):
                texture = str(rng.choice(WALL_TEXTURES if is_wall else FACADE_TEXTURES))
                base = terrain(np.array([start[:2], stop[:2]]))
                quads.append(Quad(start + np.array([0.0, 0.0, base]), axis_u.copy(), _UP.copy(), length, height + (0.5 if road is not None else 0.0),
                                  "facade", texture, 3.0 if is_wall else 4.0))
                facade_count += 1
                s += length + float(rng.uniform(*config.facade_gap))
            else:
                s += 2.0
        s = float(rng.uniform(0.0, config.object_spacing))
        while s < total and config.object_spacing > 0.0:
            point, tangent, normal = frame_at(s)
            distance = float(rng.uniform(config.clearance + 1.5, max(config.clearance + 2.0, config.facade_distance[0] + 2.0)))
            center = point + side * distance * normal
            if rng.random() < 0.5:
                size = (0.25, 0.25, float(rng.uniform(3.0, 6.0)))
                kind, texture = "pole", "metal"
            else:
                size = (float(rng.uniform(1.0, 3.0)), float(rng.uniform(1.0, 2.5)), float(rng.uniform(0.8, 2.5)))
                kind, texture = "box", str(rng.choice(OBJECT_TEXTURES))
            yaw = float(np.arctan2(tangent[1], tangent[0]) + rng.uniform(-0.5, 0.5))
            local = np.array([[dx * size[0], dy * size[1]] for dx in (-0.5, 0.5) for dy in (-0.5, 0.5)])
            rotation = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
            corners = center[:2] + local @ rotation.T
            if _clear(corners, corridor, clearance):
                base = terrain(corners)
                quads += box_quads(center, yaw, (size[0], size[1], size[2] + (0.5 if road is not None else 0.0)), kind, texture, base_z=base)
                object_count += 1
            s += config.object_spacing * float(rng.uniform(0.7, 1.3))
    logger.info("scene: %d quads (%d facades, %d objects) along %.0f m", len(quads), facade_count, object_count, total)
    return Scene(tuple(quads), relief)
