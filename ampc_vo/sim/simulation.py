"""Simulated landmarks and feature tracks with ground truth (DESIGN section 6; issue 2).

Pipeline of :func:`simulate_dataset`: route config -> true motion (:func:`simulate_truth`: planar
kinematics ``kinematics.simulate_kinematics`` at >= 200 Hz, the road surface ``road``, 6-DoF poses on
it ``attitude.poses_on_road``; the camera frames are every k-th dense sample) -> procedural scene
(``scene.build_scene``, on the road) -> landmarks sampled **on the scene's quads** (so that
rendered images and bearing measurements show the same world; ground points on the road surface)
-> per camera and frame visibility -> tracks with pixel noise and outliers -> dataset folder
(``ampc_vo.io.folder``) and, when the renderer is available, images.

Visibility of a landmark in a camera at a frame (all vectorised over landmarks):

1. within ``max_range_m`` of the camera centre and at depth >= ``min_range_m``;
2. ``Camera.project`` valid (in front, inside the image);
3. **not occluded**: an exact ray-versus-rectangle test of the segment camera -> landmark against
   every occluding quad (``facade``, ``box``, ``pole``; the road and the ground lie on the ground
   plane and cannot hide anything seen from above it) within range. We chose the exact ray test
   over a z-buffer because it is simple, has no resolution artefacts, and costs only
   O(candidates x nearby occluders) per camera and frame; it is evaluated lazily, only for the
   continuing tracks and for random batches of new candidates until the track cap is filled.

Tracks: each camera keeps the landmarks it tracked in the previous frame while they stay visible
(``track_id`` unchanged); free slots up to ``max_tracks_per_camera`` are filled with newly visible
landmarks, emptiest cells of an 8 x 6 image grid first (like a tracker's grid replenishment;
random within a cell), each given a new track id (a landmark re-acquired after a gap gets a new
id, as a real tracker would). ``track_id`` values are unique over all cameras. In each camera and
frame ``round(outlier_fraction * K)`` of the K tracks are outliers: their pixel is replaced by a
uniformly random pixel (the track id persists; ``is_outlier`` marks them). Inliers get Gaussian
pixel noise of ``pixel_noise_px``.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ampc_vo.errors import ConfigError, OutputError
from ampc_vo.geometry import invert_pose
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.sim.attitude import BodyAngles, mount_vibration, poses_on_road
from ampc_vo.sim.kinematics import AxleGroup, simulate_kinematics
from ampc_vo.sim.road import FLAT_ROAD, RoadSurface
from ampc_vo.io.measurements import MEASUREMENTS_FILE, Measurements, load_measurements, save_measurements
from ampc_vo.rig import BodyBox, Rig
from ampc_vo.sim.scene import Scene, build_scene, route_centerline
from ampc_vo.sim.traffic import DynamicScene, TrailerBodySpec, build_dynamic_scene
from ampc_vo.sim.config import SceneConfig, SimulationConfig, load_sim_config

__all__ = [
    "Measurements", "load_measurements", "save_measurements", "MEASUREMENTS_FILE",
    "LandmarkSet", "sample_landmarks", "occluded", "landmarks_in_view", "occluders_in_view", "visible_landmarks",
    "simulate_measurements", "simulate_capture_times",
    "SimulationResult", "simulate", "simulate_dataset", "simulate_truth", "decimate", "dense_factor",
]

LOGGER = logging.getLogger(__name__)
OCCLUDER_KINDS = ("facade", "box", "pole")
_SURFACE_KINDS = ("facade", "box", "pole")


@dataclass(frozen=True)
class LandmarkSet:
    """World points (L, 3) on the scene's surfaces and the index of the quad each lies on (L,)."""

    points: np.ndarray
    quad_index: np.ndarray


def sample_landmarks(scene: Scene, trajectory: Trajectory, config: SceneConfig, rng: np.random.Generator,
                     road: RoadSurface = FLAT_ROAD) -> LandmarkSet:
    """Sample landmarks on the scene's quads.

    Vertical surfaces (facades, boxes, poles) get ``landmark_density_facade`` points per m^2,
    uniformly over each quad. Road, shoulders and grass get ``landmark_density_ground`` per m^2,
    but only on the parts of those quads within ``ground_landmark_band_m`` of the road's centre
    line (the large grass plane would otherwise waste landmarks far from the route); each ground
    point lies exactly on the topmost ground-level quad at its position (road over shoulder over
    grass), so it matches the rendered surface; on a 3D road (``road`` not flat) ground points
    lie exactly on the road surface model (``road.height``; the tilted quads follow it to a few
    centimetres, see ``scene``).
    """
    from ampc_vo.sim.scene import route_centerline

    points, quad_index = [], []
    for index, quad in enumerate(scene.quads):
        if quad.kind not in _SURFACE_KINDS:
            continue
        count = rng.poisson(config.landmark_density_facade * quad.width * quad.height)
        if count == 0:
            continue
        coordinates = rng.uniform(0.0, 1.0, size=(count, 2)) * np.array([quad.width, quad.height])
        points.append(quad.points(coordinates))
        quad_index.append(np.full(count, index))

    centerline = route_centerline(trajectory.T_world_tractor, config.extension_m)
    band = config.ground_landmark_band_m
    length = float(centerline.arc_length[-1] - centerline.arc_length[0])
    count = rng.poisson(config.landmark_density_ground * 2.0 * band * max(length, 1.0))
    at = rng.integers(0, len(centerline.points), size=count)
    lateral = rng.uniform(-band, band, size=count)
    along = rng.uniform(-1.0, 1.0, size=count)
    ground = centerline.points[at] + lateral[:, None] * centerline.normals[at] + along[:, None] * centerline.tangents[at]
    ground_index = _ground_quad_at(scene, ground[:, :2])
    keep = ground_index >= 0
    ground = ground[keep]
    ground_index = ground_index[keep]
    if road.is_flat:
        ground[:, 2] = np.array([scene.quads[index].origin[2] for index in ground_index])
    else:
        ground[:, 2] = road.height(ground[:, :2])
    points.append(ground)
    quad_index.append(ground_index)
    return LandmarkSet(np.concatenate(points) if points else np.zeros((0, 3)), np.concatenate(quad_index).astype(np.int64) if quad_index else np.zeros(0, np.int64))


def _ground_quad_at(scene: Scene, xy: np.ndarray) -> np.ndarray:
    """Index of the highest horizontal road/ground quad containing each 2-D point (-1 if none)."""
    best = np.full(len(xy), -1, dtype=np.int64)
    best_z = np.full(len(xy), -np.inf)
    for index, quad in enumerate(scene.quads):
        if quad.kind not in ("road", "ground") or abs(quad.normal[2]) < 0.99:
            continue
        relative = xy - quad.origin[:2]
        a = relative @ quad.axis_u[:2]
        b = relative @ quad.axis_v[:2]
        inside = (a >= 0.0) & (a <= quad.width) & (b >= 0.0) & (b <= quad.height) & (quad.origin[2] > best_z)
        best[inside] = index
        best_z[inside] = quad.origin[2]
    return best


@dataclass(frozen=True)
class _Occluders:
    """Occluding quads stacked as arrays for the vectorised ray test."""

    origin: np.ndarray   # (Q, 3)
    axis_u: np.ndarray
    axis_v: np.ndarray
    normal: np.ndarray
    size: np.ndarray     # (Q, 2) width, height
    center: np.ndarray   # (Q, 3)
    radius: np.ndarray   # (Q,) half diagonal
    quad_index: np.ndarray

    @staticmethod
    def from_scene(scene: Scene) -> "_Occluders":
        selected = [index for index, quad in enumerate(scene.quads) if quad.kind in OCCLUDER_KINDS]
        quads = [scene.quads[index] for index in selected]
        if not quads:
            empty = np.zeros((0, 3))
            return _Occluders(empty, empty, empty, empty, np.zeros((0, 2)), empty, np.zeros(0), np.zeros(0, np.int64))
        origin = np.array([quad.origin for quad in quads])
        axis_u = np.array([quad.axis_u for quad in quads])
        axis_v = np.array([quad.axis_v for quad in quads])
        size = np.array([[quad.width, quad.height] for quad in quads])
        center = origin + 0.5 * size[:, :1] * axis_u + 0.5 * size[:, 1:] * axis_v
        return _Occluders(origin, axis_u, axis_v, np.cross(axis_u, axis_v), size, center, 0.5 * np.hypot(size[:, 0], size[:, 1]), np.array(selected))


def occluded(camera_center: np.ndarray, points: np.ndarray, occluders: _Occluders, own_quad: np.ndarray | None = None) -> np.ndarray:
    """True for points (N, 3) whose segment from ``camera_center`` crosses an occluding quad.

    Ray ``c + t (p - c)``; plane hit ``t = n.(o - c) / n.(p - c)``; occluded if some quad has
    ``1e-6 < t < 1 - 1e-6`` with the hit inside the rectangle. A point's own quad (``own_quad``,
    the scene quad index) is skipped. Vectorised over (N points x Q quads).
    """
    if len(points) == 0 or len(occluders.origin) == 0:
        return np.zeros(len(points), dtype=bool)
    direction = points - camera_center                                   # (N, 3)
    denominator = direction @ occluders.normal.T                          # (N, Q)
    numerator = np.einsum("qa,qa->q", occluders.normal, occluders.origin - camera_center)  # (Q,)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = numerator[None, :] / denominator
    candidate = (np.abs(denominator) > 1e-12) & (t > 1e-6) & (t < 1.0 - 1e-6)
    if own_quad is not None:
        candidate &= own_quad[:, None] != occluders.quad_index[None, :]
    rows, columns = np.nonzero(candidate)
    if len(rows) == 0:
        return np.zeros(len(points), dtype=bool)
    hit = camera_center + t[rows, columns, None] * direction[rows]
    relative = hit - occluders.origin[columns]
    a = np.einsum("ka,ka->k", relative, occluders.axis_u[columns])
    b = np.einsum("ka,ka->k", relative, occluders.axis_v[columns])
    inside = (a >= 0.0) & (a <= occluders.size[columns, 0]) & (b >= 0.0) & (b <= occluders.size[columns, 1])
    result = np.zeros(len(points), dtype=bool)
    result[rows[inside]] = True
    return result


def landmarks_in_view(
    camera, T_world_camera: np.ndarray, landmarks: LandmarkSet, landmark_tree: cKDTree, max_range: float, min_range: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Ids (K,) and noise-free pixels (K, 2) of the landmarks in range and in the image (steps 1-2
    of the module docstring; occlusion is not checked)."""
    center = T_world_camera[:3, 3]
    nearby = np.asarray(landmark_tree.query_ball_point(center, max_range), dtype=np.int64)
    if len(nearby) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 2))
    nearby.sort()
    T_camera_world = invert_pose(T_world_camera)
    points_camera = landmarks.points[nearby] @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
    pixels, valid = camera.project(points_camera)
    valid &= points_camera[:, 2] >= min_range
    return nearby[valid], pixels[valid]


def occluders_in_view(occluders: _Occluders, T_world_camera: np.ndarray, max_range: float) -> _Occluders:
    """The occluders that can lie between the camera and a landmark within ``max_range``: near
    enough and not entirely behind the camera (bounding-sphere tests)."""
    center = T_world_camera[:3, 3]
    depth = (occluders.center - center) @ T_world_camera[:3, 2]
    keep = (np.linalg.norm(occluders.center - center, axis=1) <= max_range + occluders.radius) & (depth > -occluders.radius)
    return _Occluders(*(getattr(occluders, name)[keep] for name in ("origin", "axis_u", "axis_v", "normal", "size", "center", "radius", "quad_index")))


def visible_landmarks(
    camera, T_world_camera: np.ndarray, landmarks: LandmarkSet, landmark_tree: cKDTree, occluders: _Occluders,
    max_range: float, min_range: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Ids (K,) and noise-free pixels (K, 2) of all the landmarks one camera sees (module docstring)."""
    ids, pixels = landmarks_in_view(camera, T_world_camera, landmarks, landmark_tree, max_range, min_range)
    nearby = occluders_in_view(occluders, T_world_camera, max_range)
    hidden = occluded(T_world_camera[:3, 3], landmarks.points[ids], nearby, landmarks.quad_index[ids])
    return ids[~hidden], pixels[~hidden]


GRID_COLUMNS, GRID_ROWS = 8, 6  # image grid for spreading new tracks, like a tracker's replenishment


def _spread_order(pixels: np.ndarray, candidates: np.ndarray, occupied_cells: np.ndarray, image_size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """``candidates`` (indices into ``pixels``) ordered so that new tracks fill the emptiest cells
    of a ``GRID_COLUMNS`` x ``GRID_ROWS`` image grid first (random order within a cell).
    ``occupied_cells`` holds the cell index of every already kept track."""
    width, height = image_size
    def cell_of(points: np.ndarray) -> np.ndarray:
        column = np.clip((points[:, 0] + 0.5) * GRID_COLUMNS // width, 0, GRID_COLUMNS - 1).astype(np.int64)
        row = np.clip((points[:, 1] + 0.5) * GRID_ROWS // height, 0, GRID_ROWS - 1).astype(np.int64)
        return row * GRID_COLUMNS + column

    shuffled = rng.permutation(candidates)
    cells = cell_of(pixels[shuffled])
    by_cell = np.argsort(cells, kind="stable")
    sorted_cells = cells[by_cell]
    first_in_cell = np.searchsorted(sorted_cells, sorted_cells, side="left")
    rank = np.empty(len(shuffled), np.int64)
    rank[by_cell] = np.arange(len(shuffled)) - first_in_cell           # k-th candidate of its cell
    rank += np.bincount(occupied_cells, minlength=GRID_COLUMNS * GRID_ROWS)[cells]
    return shuffled[np.argsort(rank, kind="stable")]


def _select_tracks(
    ids: np.ndarray, pixels: np.ndarray, previous_ids: np.ndarray, capacity: int, is_hidden, image_size: tuple[int, int],
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Landmarks to track this frame: the unoccluded continuing ones, then unoccluded new ones up
    to ``capacity``, spread over the image (:func:`_spread_order`). Occlusion
    (``is_hidden(indices) -> bool array``) is only evaluated for candidates that may be kept, in
    batches: the result equals testing all first, at a fraction of the cost.
    Returns ``(ids, pixels, count_continuing)`` with the continuing tracks first."""
    was_tracked = np.isin(ids, previous_ids)
    continuing = np.flatnonzero(was_tracked)
    continuing = continuing[~is_hidden(continuing)]
    slots = max(capacity - len(continuing), 0)
    chosen: list[np.ndarray] = []
    if slots:
        width, height = image_size
        occupied = (np.clip((pixels[continuing, 1] + 0.5) * GRID_ROWS // height, 0, GRID_ROWS - 1) * GRID_COLUMNS
                    + np.clip((pixels[continuing, 0] + 0.5) * GRID_COLUMNS // width, 0, GRID_COLUMNS - 1)).astype(np.int64)
        fresh = _spread_order(pixels, np.flatnonzero(~was_tracked), occupied, image_size, rng)
        found = start = 0
        while found < slots and start < len(fresh):
            batch = fresh[start:start + max(2 * (slots - found), 32)]
            start += len(batch)
            visible = batch[~is_hidden(batch)][: slots - found]
            chosen.append(visible)
            found += len(visible)
    keep = np.concatenate([continuing, np.sort(np.concatenate(chosen))]) if chosen else continuing
    return ids[keep], pixels[keep], len(continuing)


def simulate_measurements(
    trajectory: Trajectory, rig: Rig, landmarks: LandmarkSet, scene: Scene, config: SimulationConfig, rng: np.random.Generator,
    capture_times: dict[str, np.ndarray] | None = None, pose_trajectory: Trajectory | None = None,
    dynamic: "DynamicScene | None" = None, mount_vibration: dict[str, np.ndarray] | None = None,
) -> Measurements:
    """Tracks of every camera over the trajectory (module docstring).

    ``capture_times`` (per camera, (F,) seconds; default: the frame times) say when each camera
    captures each frame; poses between samples come from ``pose_trajectory`` (default
    ``trajectory``; a denser one where available) by SE(3) interpolation (``sim.motion``).
    Visibility and occlusion use the pose at the middle of the readout; the kept tracks' pixels are
    then projected with the rolling shutter (``camera_timing.project_rolling_shutter``: each point
    with the pose at the time of its own row), and tracks leaving the image that way are dropped.
    Cross-camera associations are only those a stereo matcher could find (``sim.associations``).
    ``dynamic`` (``sim.traffic``): moving bodies whose surface landmarks are tracked too (ids after
    the static ones) and whose faces hide what lies behind them. ``mount_vibration`` (per camera,
    (N, 3, 3) over ``pose_trajectory``'s samples, ``attitude.mount_vibration``): each camera is
    projected from its vibrating mount ``T_world_body T_body_camera R_mount`` at every capture and
    row time (``motion.camera_poses``); the measurements' rig keeps the nominal mounts.
    """
    from ampc_vo.sim.associations import association_ids, overlap_groups
    from ampc_vo.sim.camera_timing import project_rolling_shutter
    from ampc_vo.sim.motion import PoseSampler, camera_poses, sample_rotations

    pose_trajectory = trajectory if pose_trajectory is None else pose_trajectory
    samplers = {body: PoseSampler.of(pose_trajectory, body) for body in {camera.body for camera in rig.cameras}}
    mounts = mount_vibration or {}
    capture_times = capture_times or {}
    frame_times = np.asarray(trajectory.timestamps, float)
    tree = cKDTree(landmarks.points)
    static_count = len(landmarks.points)
    occluders = _Occluders.from_scene(scene)
    columns: dict[str, list[np.ndarray]] = {name: [] for name in ("frame", "camera_index", "track_id", "landmark_id", "pixel", "pixel_clean", "is_outlier")}
    active = {camera.name: (np.zeros(0, np.int64), np.zeros(0, np.int64)) for camera in rig.cameras}  # landmark ids, track ids
    camera_timestamps = np.stack([np.asarray(capture_times.get(camera.name, frame_times), float) for camera in rig.cameras], axis=1)
    next_track = 0
    for frame in range(len(trajectory)):
        for camera_index, camera in enumerate(rig.cameras):
            capture = float(camera_timestamps[frame, camera_index])

            def pose_at(times: np.ndarray, camera=camera) -> np.ndarray:
                mount = mounts.get(camera.name)
                R_mount = None if mount is None else sample_rotations(pose_trajectory.timestamps, mount, times)
                return camera_poses(samplers[camera.body](times), camera.T_body_camera, R_mount)

            middle = capture + 0.5 * camera.readout_time
            T_world_camera = pose_at(np.array([middle]))[0]
            ids, clean = landmarks_in_view(camera, T_world_camera, landmarks, tree, config.max_range_m, config.min_range_m)
            nearby = occluders_in_view(occluders, T_world_camera, config.max_range_m)
            moving = _moving_view(camera, T_world_camera, middle, dynamic, static_count, config) if dynamic is not None else None
            if moving is not None:
                ids, clean = np.concatenate([ids, moving.ids]), np.concatenate([clean, moving.pixels])

            def is_hidden(indices: np.ndarray) -> np.ndarray:
                selected = ids[indices]
                static = selected < static_count
                hidden = np.zeros(len(selected), bool)
                hidden[static] = occluded(T_world_camera[:3, 3], landmarks.points[selected[static]], nearby, landmarks.quad_index[selected[static]])
                if moving is not None:
                    points = np.empty((len(selected), 3))
                    points[static] = landmarks.points[selected[static]]
                    points[~static] = moving.points[np.searchsorted(moving.ids, selected[~static])]
                    hidden[~static] |= occluded(T_world_camera[:3, 3], points[~static], nearby)
                    own = np.full(len(selected), -1, np.int64)
                    own[~static] = moving.own_quad[np.searchsorted(moving.ids, selected[~static])]
                    hidden |= occluded(T_world_camera[:3, 3], points, moving.occluders, own)
                return hidden

            previous_ids, previous_tracks = active[camera.name]
            keep_ids, keep_clean, count_continuing = _select_tracks(
                ids, clean, previous_ids, config.max_tracks_per_camera, is_hidden, (camera.width, camera.height), rng)
            if camera.readout_time > 0 and len(keep_ids):
                points = landmarks.points[np.minimum(keep_ids, static_count - 1)] if static_count else np.zeros((len(keep_ids), 3))
                if dynamic is not None and np.any(keep_ids >= static_count):
                    def points_at(times: np.ndarray, keep_ids=keep_ids, points=points) -> np.ndarray:
                        result = points.copy()
                        mask = keep_ids >= static_count
                        times = np.broadcast_to(np.asarray(times, float), mask.shape)
                        result[mask] = dynamic.landmarks_at(keep_ids[mask] - static_count, times[mask])
                        return result
                    keep_clean, in_image, _ = project_rolling_shutter(camera, pose_at, points_at, capture)
                else:
                    keep_clean, in_image, _ = project_rolling_shutter(camera, pose_at, points, capture)
                count_continuing = int(np.count_nonzero(in_image[:count_continuing]))
                keep_ids, keep_clean = keep_ids[in_image], keep_clean[in_image]
            tracks = np.empty(len(keep_ids), np.int64)
            if count_continuing:
                lookup = dict(zip(previous_ids.tolist(), previous_tracks.tolist()))
                tracks[:count_continuing] = [lookup[landmark] for landmark in keep_ids[:count_continuing].tolist()]
            tracks[count_continuing:] = np.arange(next_track, next_track + len(keep_ids) - count_continuing)
            next_track += len(keep_ids) - count_continuing
            active[camera.name] = (keep_ids, tracks)

            noisy = keep_clean + rng.normal(0.0, config.pixel_noise_px, size=keep_clean.shape)
            is_outlier = np.zeros(len(keep_ids), dtype=bool)
            outlier_count = int(round(config.outlier_fraction * len(keep_ids)))
            if outlier_count:
                is_outlier[rng.choice(len(keep_ids), size=outlier_count, replace=False)] = True
                noisy[is_outlier] = rng.uniform([-0.5, -0.5], [camera.width - 0.5, camera.height - 0.5], size=(outlier_count, 2))
            columns["frame"].append(np.full(len(keep_ids), frame, np.int64))
            columns["camera_index"].append(np.full(len(keep_ids), camera_index, np.int64))
            columns["track_id"].append(tracks)
            columns["landmark_id"].append(keep_ids)
            columns["pixel"].append(noisy)
            columns["pixel_clean"].append(keep_clean)
            columns["is_outlier"].append(is_outlier)
    stacked = {name: np.concatenate(parts) if parts else np.zeros(0) for name, parts in columns.items()}
    frame_column, camera_column = stacked["frame"].astype(np.int64), stacked["camera_index"].astype(np.int64)
    track_column, landmark_column = stacked["track_id"].astype(np.int64), stacked["landmark_id"].astype(np.int64)
    outlier_column = stacked["is_outlier"].astype(bool)
    groups = overlap_groups(rig, config.max_range_m)
    all_landmarks, landmark_body = landmarks.points, None
    if dynamic is not None:
        all_landmarks = np.concatenate([landmarks.points, dynamic.landmark_points])
        landmark_body = np.concatenate([np.full(static_count, -1, np.int64), dynamic.landmark_body])
    return Measurements(
        frame=frame_column, camera_index=camera_column, track_id=track_column, landmark_id=landmark_column,
        pixel=stacked["pixel"].reshape(-1, 2), pixel_clean=stacked["pixel_clean"].reshape(-1, 2),
        is_outlier=outlier_column, camera_names=tuple(rig.camera_names),
        landmarks=all_landmarks, timestamps=frame_times.copy(), rig=rig, landmark_body=landmark_body,
        camera_timestamps=camera_timestamps,
        association_id=association_ids(frame_column, camera_column, landmark_column, track_column, outlier_column, groups),
    )


@dataclass(frozen=True)
class _MovingView:
    """Dynamic landmarks one camera sees at one time (ids offset by the static count), their world
    points and noise-free pixels, the moving faces as occluders and each landmark's own face."""

    ids: np.ndarray
    pixels: np.ndarray
    points: np.ndarray
    own_quad: np.ndarray
    occluders: _Occluders


def _moving_view(camera, T_world_camera: np.ndarray, time: float, dynamic: "DynamicScene", static_count: int,
                 config: SimulationConfig) -> _MovingView:
    from ampc_vo.sim.scene import Scene as _Scene

    bodies = dynamic.visible_bodies(camera)
    occluders = _Occluders.from_scene(_Scene(tuple(dynamic.quads_at(time, camera))))
    indices = np.flatnonzero(np.isin(dynamic.landmark_body, bodies))
    points = dynamic.landmarks_at(indices, np.full(len(indices), time))
    T_camera_world = invert_pose(T_world_camera)
    points_camera = points @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
    pixels, valid = camera.project(points_camera)
    valid &= (points_camera[:, 2] >= config.min_range_m) & (np.linalg.norm(points_camera, axis=1) <= config.max_range_m)
    rank = {body: k for k, body in enumerate(bodies)}
    faces = np.cumsum([0] + [len(dynamic.faces[body]) for body in bodies])
    own = np.array([faces[rank[body]] for body in dynamic.landmark_body[indices]], np.int64) + dynamic.landmark_face[indices] if len(indices) else np.zeros(0, np.int64)
    return _MovingView(indices[valid] + static_count, pixels[valid], points[valid], own[valid], occluders)


@dataclass(frozen=True)
class SimulationResult:
    """Everything :func:`simulate` produces (and :func:`simulate_dataset` writes)."""

    config: SimulationConfig
    rig: Rig
    trajectory: Trajectory
    scene: Scene
    landmarks: LandmarkSet
    measurements: Measurements
    images_written: bool = False
    # the same motion sampled at >= 200 Hz (every k-th sample is a frame of ``trajectory``), for
    # per-camera capture times and rolling-shutter rows; the road the wheels stand on; body angles
    dense_trajectory: Trajectory | None = None
    road: RoadSurface = FLAT_ROAD
    body_angles: BodyAngles | None = None
    capture_times: dict[str, np.ndarray] | None = None  # per camera (F,) seconds (``camera_timing.capture_times``)
    dynamic: "DynamicScene | None" = None                # traffic and the trailer box (``sim.traffic``)
    # per camera name, (N_dense, 3, 3) vibration of its mount over dense_trajectory's samples
    # (``T_body_camera @ R_mount``; attitude.mount_vibration), applied to the bearings and images
    mount_vibration: dict[str, np.ndarray] | None = None

    def render_inputs(self) -> dict:
        """The keyword arguments of ``render.render_sequence`` / ``render.sequence_job`` that make the
        images show this simulation's world as the bearings do: capture times, camera settings, the
        dense poses, the moving bodies and the mount vibration."""
        return {"capture_times": self.capture_times, "camera_settings": self.config.cameras, "pose_trajectory": self.dense_trajectory,
                "dynamic_scene": self.dynamic, "mount_vibration": self.mount_vibration}


def simulate(config: SimulationConfig | str | Path, rig: Rig | None = None) -> SimulationResult:
    """Run kinematics, scene, landmarks and measurements for a config (a path or a parsed config)."""
    if not isinstance(config, SimulationConfig):
        config = load_sim_config(config)
    rig = config.load_rig() if rig is None else rig
    if not rig.has_trailer:
        raise ConfigError(f"{config.rig_path}: the simulator needs a rig with a trailer body")
    rng = np.random.default_rng(config.seed)
    dense, road, angles = simulate_truth(config, rig)
    trajectory = decimate(dense, dense_factor(config))
    scene = build_scene(trajectory, rng, config.scene, road=road)
    landmarks = sample_landmarks(scene, trajectory, config.scene, rng, road=road)
    capture_times = simulate_capture_times(config, rig, trajectory.timestamps)
    dynamic = build_dynamic_scene(config.traffic, config.trailer_body, trajectory, rig,
                                  route_centerline(trajectory.T_world_tractor, config.scene.extension_m),
                                  config.scene.landmark_density_facade, np.random.default_rng([config.seed, 17]),
                                  pose_trajectory=dense, road=None if road.is_flat else road)
    mounts = mount_vibration(rig, dense, config.vehicle, np.random.default_rng([config.seed, 23])) if config.vehicle.moves_bodies else None
    measurements = simulate_measurements(trajectory, rig, landmarks, scene, config, rng, capture_times, pose_trajectory=dense, dynamic=dynamic,
                                         mount_vibration=mounts)
    return SimulationResult(config, rig, trajectory, scene, landmarks, measurements, dense_trajectory=dense, road=road, body_angles=angles,
                            capture_times=capture_times, dynamic=dynamic, mount_vibration=mounts)


def dense_factor(config: SimulationConfig) -> int:
    """Samples of the dense trajectory per camera frame: ``ceil(dense_rate_hz / rate_hz)``."""
    return max(int(np.ceil(config.dense_rate_hz / config.rate_hz - 1e-9)), 1)


def decimate(trajectory: Trajectory, step: int) -> Trajectory:
    """Every ``step``-th sample of a trajectory (the camera frames of a dense one)."""
    pick = slice(None, None, step)
    optional = lambda values: None if values is None else values[pick].copy()  # noqa: E731
    return Trajectory(trajectory.timestamps[pick].copy(), trajectory.T_world_tractor[pick].copy(), trajectory.T_world_trailer[pick].copy(),
                      trajectory.hitch_angle[pick].copy(), optional(trajectory.speed), optional(trajectory.curvature), optional(trajectory.arc_length))


def simulate_truth(config: SimulationConfig, rig: Rig) -> tuple[Trajectory, RoadSurface, BodyAngles | None]:
    """The true motion at the dense rate (``dense_factor`` samples per frame): planar kinematics
    (``kinematics``, with the trailer's axle group and the lane's cross-slope), the road along the
    tractor axle's path (``road``) and the 6-DoF poses on it (``attitude.poses_on_road``). A flat
    road without body motion keeps the planar poses, lifted to ``hitch_height``."""
    tractor_axle_x, trailer_axle_x = rig.axle_x("tractor"), rig.axle_x("trailer")
    vehicle, road_config = config.vehicle, config.road
    group = AxleGroup(vehicle.trailer_axles, vehicle.axle_spread_m) if vehicle.trailer_axles > 1 else None
    tilted = road_config.has_profile or road_config.plane_slope != (0.0, 0.0)
    planar = simulate_kinematics(config.route, config.rate_hz, tractor_axle_x, trailer_axle_x, config.initial_hitch_angle, config.duration,
                                 slip=config.tyre_slip, samples_per_frame=dense_factor(config), axle_group=group,
                                 lateral_slope=road_config.lane_slope(config.route.design_curvature, config.route.lane_change_offset)
                                 if tilted and config.tyre_slip > 0.0 else None)
    if not tilted and not road_config.bumps:
        road = FLAT_ROAD
    else:
        path, station, curvature = config.route.design_path((tractor_axle_x, 0.0), config.scene.extension_m + config.scene.ground_margin_m)
        road = road_config.surface(path, station, curvature, config.scene.road_width / 2.0 + config.scene.shoulder_width)
    if road.is_flat and not vehicle.moves_bodies:
        lifted_tractor, lifted_trailer = planar.T_world_tractor.copy(), planar.T_world_trailer.copy()
        lifted_tractor[:, 2, 3] += rig.hitch_height
        lifted_trailer[:, 2, 3] += rig.hitch_height
        return dataclasses.replace(planar, T_world_tractor=lifted_tractor, T_world_trailer=lifted_trailer), road, None
    body_rng = np.random.default_rng([config.seed, 13])
    dense, angles = poses_on_road(planar, road, tractor_axle_x, trailer_axle_x, rig.hitch_height, vehicle, body_rng)
    return dense, road, angles


def simulate_capture_times(config: SimulationConfig, rig: Rig, frame_times: np.ndarray) -> dict[str, np.ndarray]:
    """Capture times of every rig camera (``camera_timing.capture_times``; the config's ``cameras:``
    section), from their own random stream (seeded by ``config.seed``) so that timing does not
    change the landmarks and tracks."""
    from ampc_vo.sim.camera_settings import settings_for
    from ampc_vo.sim.camera_timing import capture_times

    settings = settings_for(config.cameras, rig.camera_names, str(config.rig_path))
    rng = np.random.default_rng([config.seed, 13])
    return {camera.name: capture_times(frame_times, setting, rng, camera.name) for camera, setting in zip(rig.cameras, settings)}


def _renderer():
    """``ampc_vo.sim.render.render_sequence`` if the renderer exists, else ``None``."""
    try:
        from ampc_vo.sim import render  # noqa: PLC0415
    except ImportError as error:
        LOGGER.info("renderer not importable: %s", error)
        return None
    return getattr(render, "render_sequence", None)


def simulate_dataset(config: SimulationConfig | str | Path, out_dir: str | Path, with_images: bool = True, progress: bool = False) -> SimulationResult:
    """Simulate and write a dataset folder (DESIGN 5): ``rig.yaml``, ``groundtruth.csv``,
    ``measurements.npz``, images (if ``with_images`` and the renderer is available) and
    ``frames.csv`` (written last, with empty image paths when there are no images)."""
    from ampc_vo.io.folder import write_dataset

    started = time.perf_counter()
    result = simulate(config)
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"{out_dir}: cannot create the dataset folder ({error.strerror or error}: {error.filename})") from None
    images_written = False
    if with_images:
        render_sequence = _renderer()
        if render_sequence is not None:
            from ampc_vo.sim.render import render_options_from_dict

            options = render_options_from_dict(result.config.render, f"{result.config.source}: render")
            render_sequence(out_dir, result.rig, result.trajectory, result.scene, options=options, progress=progress,
                            **result.render_inputs())
            images_written = True
    rig = rig_with_vignetting(rig_with_trailer_box(result.rig, result.config.trailer_body), result.config.cameras)
    write_dataset(out_dir, rig, result.trajectory.timestamps, groundtruth=result.trajectory,
                  measurements=result.measurements, with_images=images_written,
                  camera_timestamps=_stated_capture_times(result))
    from ampc_vo.sim.wheel_odometry import write_simulated_wheel_speed  # issue 15: wheel_speed.csv

    write_simulated_wheel_speed(out_dir, result.trajectory, result.config.seed)
    LOGGER.info("dataset written to %s in %.1f s", out_dir, time.perf_counter() - started)
    return dataclasses.replace(result, images_written=images_written)


def rig_with_vignetting(rig: Rig, camera_settings: "CameraSettingsTable | None") -> Rig:
    """``rig`` whose cameras state the vignetting their images were rendered with (rig.yaml
    ``vignetting``), as a user's photometric calibration states it; a camera whose rig already
    gives one keeps it."""
    from ampc_vo.sim.camera_settings import CameraSettingsTable, settings_for

    settings = settings_for(camera_settings or CameraSettingsTable(), rig.camera_names)
    cameras = tuple(camera if camera.vignetting or not item.vignetting else dataclasses.replace(camera, vignetting=float(item.vignetting))
                    for camera, item in zip(rig.cameras, settings))
    return dataclasses.replace(rig, cameras=cameras)


def rig_with_trailer_box(rig: Rig, trailer_body: TrailerBodySpec | None) -> Rig:
    """``rig`` whose trailer states the box the simulator rendered (``trailer_body``), as a user
    measures their trailer (rig.yaml ``bodies.trailer.box``); unchanged without one or with a box given."""
    if trailer_body is None or not rig.has_trailer or rig.bodies["trailer"].box is not None:
        return rig
    bottom = trailer_body.floor_height_m - rig.hitch_height
    box = BodyBox(front_x=trailer_body.front_x_m, rear_x=trailer_body.front_x_m - trailer_body.length_m, half_width=0.5 * trailer_body.width_m,
                  bottom_z=bottom, top_z=bottom + trailer_body.height_m)
    bodies = {**rig.bodies, "trailer": dataclasses.replace(rig.bodies["trailer"], box=box)}
    return dataclasses.replace(rig, bodies=bodies)


def _stated_capture_times(result: SimulationResult) -> dict[str, np.ndarray] | None:
    """The capture times frames.csv states: only for cameras that do not capture at the frame time."""
    times = {name: values for name, values in (result.capture_times or {}).items()
             if not np.array_equal(values, result.trajectory.timestamps)}
    return times or None
