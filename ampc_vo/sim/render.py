"""Render grey camera images of a textured quad scene by per-pixel ray casting (issue 6, DESIGN 6).

For every pixel the ray of its centre (``Camera.unproject``, pinhole or equidistant fisheye, computed
once per camera) is intersected with the planes of the scene's quads; the nearest hit inside its
rectangle wins (occlusion by depth). The hit's surface coordinates ``(a, b)`` give texture
coordinates; the texture is sampled trilinearly from a mipmap atlas with ``cv2.remap``, the level
chosen from the pixel footprint on the surface (distance times the pixel's angular size, widened by
the incidence angle) so that distant texture does not alias. Pixels whose ray hits nothing see a
sky gradient. Texture coordinates: vertical quads use ``(a, b) / texture_scale`` plus a random
per-quad shift (no two walls look alike); horizontal quads (road, ground) use world ``(x, y)``, so
the strips of a road continue each other without seams.

Speed (``scripts/benchmark_render.py``): pixels are stored tile-major (16x16 tiles). Each quad is
tested against the tiles its projected outline's bounding box covers (quads reaching behind a
pinhole lens are clipped at a near plane first), refined by its bounding sphere against each tile's
cone of rays, by which side of its plane a tile's rays can reach and by the four faces of the cone of
rays through its corners (a tile inside all four sees the quad with every ray: only the depth is
tested there, the rectangle test only on the edge tiles); quads are processed near to far
and skip tiles already filled with nearer surfaces; quads on a few tiles only (far, thin) are
ray-tested in batches of 64 (one numpy pass each). Large quads are split into pieces and collinear
road strips merged; beyond ``detail_distance_m`` blocks of 8 x 8 pieces are tested as one (level of
detail: same hits). Quads under a quarter of a pixel's solid angle are culled (one ray per pixel
would alias them). Sequences are rendered by several (spawned) processes.

Conventions: ``T_world_camera = T_world_body @ T_body_camera`` (DESIGN 1), OpenCV camera axes.
Road quads (``kind == 'road'``) carry painted lane markings along their ``axis_u`` (edge lines and a
dashed centre line, across ``b`` in [0, height]), continuous over consecutive road strips.

Realism (issue 13): cast shadows of walls and boxes on the ground (:func:`shadow_map`, option
``shadows``), substitute road and grass textures (``road_texture: worn_asphalt``, ``grass_texture:
verge``), moving bodies whose faces are prepared once in their own frame and moved per frame
(:meth:`Renderer.moving_bodies`, :func:`move_prepared`: their texture sticks to them). Each camera
image of a sequence is formed by ``sim.camera_effects.form_image`` (rolling shutter, blur, auto
exposure metered by :func:`metered_amplification`, vignetting, noise) at the camera's capture time.

API: :class:`Renderer` (``render``, ``render_float``, ``radiance_and_depth``, ``depth_pass``),
:func:`render_image`, :func:`render_sequence`, :func:`sequence_job` / :func:`render_frame_images`
(the images of one frame as written), :class:`RenderOptions` / :func:`render_options_from_dict`.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import multiprocessing
import os
import zlib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from ampc_vo.errors import ConfigError
from ampc_vo.rig import Camera, Rig
from ampc_vo.sim.scene import Quad, Scene
from ampc_vo.sim.textures import TextureAtlas, build_atlas, load_textures
from ampc_vo.sim.traffic import vehicle_quads

logger = logging.getLogger(__name__)

_FISHEYE_MAX_INCIDENCE = np.deg2rad(100.0)  # same limit as rig.Camera.project
_MIN_HIT_DISTANCE = 1e-3  # m: ray parameter below which a hit is ignored (surfaces at the lens)


# ---------------------------------------------------------------------- options
@dataclass(frozen=True)
class RenderOptions:
    """Renderer settings; the realism switches are filled from the sim config ``render`` section.

    ``sensor_noise_sigma`` grey levels of Gaussian noise; ``exposure_variation`` relative amplitude
    of a smooth per-camera gain change over time; ``motion_blur_samples`` sub-frames averaged over
    ``exposure_time_s``; ``moving_vehicle`` adds a box driving along the road (an outlier source).
    """

    tile_size: int = 16
    max_quad_extent_m: float = 20.0   # quads larger than this are split for culling
    detail_distance_m: float = 100.0  # beyond: blocks of 8x8 pieces tested as one (level of detail; same pixels)
    mip_bias: float = 0.0             # added to the mip level (negative: sharper, more aliasing)
    ground_texture_scale: float = 2.5  # multiplies texture_scale of horizontal quads (coarser ground
                                       # texture: KLT survives the large near-ground image motion)
    incidence_exponent: float = 0.5   # footprint widening 1 / |cos incidence|^k (1: isotropic max)
    sky_zenith: float = 150.0         # grey level of the sky straight up
    sky_horizon: float = 235.0        # grey level of the sky at the horizon
    shading: bool = True              # per-quad brightness from a sun direction and albedo jitter
    road_markings: bool = True
    road_texture: str = ""            # texture of the road surface instead of the scene's (e.g. worn_asphalt)
    grass_texture: str = ""           # texture of the scene's grass beside the road (e.g. verge)
    shadows: bool = False             # cast shadows of walls and boxes on the ground (sun: _SUN_DIRECTION)
    shadow_darkness: float = 0.5      # brightness of the ground in shadow (sky light only)
    sensor_noise_sigma: float = 0.0
    exposure_variation: float = 0.0
    motion_blur_samples: int = 1
    exposure_time_s: float = 0.0
    moving_vehicle: bool = False
    vehicle_lead_m: float = 25.0      # m ahead of the tractor where the vehicle starts
    vehicle_speed_mps: float = -8.0   # along the route; negative: oncoming traffic
    vehicle_lateral_m: float = -3.0   # m from the path centre line (negative: right of the path)
    seed: int = 0
    processes: int = 2
    png_compression: int = 1

    def __post_init__(self) -> None:
        if self.tile_size < 4 or self.max_quad_extent_m <= 0 or self.detail_distance_m < 0 or self.motion_blur_samples < 1:
            raise ConfigError(f"render options: invalid values {self}")


def render_options_from_dict(raw: dict[str, Any] | None, source: str = "render") -> RenderOptions:
    """:class:`RenderOptions` from a mapping (the sim config's ``render`` section); unknown keys fail."""
    if raw is None:
        return RenderOptions()
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: expected a mapping of render options")
    known = {item.name: item for item in fields(RenderOptions)}
    values: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in known:
            raise ConfigError(f"{source}.{key}: unknown render option (known: {', '.join(sorted(known))})")
        default = getattr(RenderOptions(), key)
        try:
            values[key] = type(default)(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{source}.{key}: expected {type(default).__name__}, got {value!r}") from None
    return RenderOptions(**values)


# ---------------------------------------------------------------------- per-camera precomputation
@dataclass(frozen=True)
class CameraRays:
    """Pixel-centre rays of one camera, tile-major: ``tile_planes[:, t, k]`` is the ray of pixel
    ``pixel_index[t, k]``.

    ``pixel_angle`` is the pixel's angular size (radians, sqrt of its solid angle); the tile cones
    (``tile_axis``, ``tile_cos``/``tile_half_angle``) contain every ray of their tile.
    """

    tile_planes: np.ndarray     # (3, T, P) float32 unit rays (camera frame), one plane per component
    pixel_index: np.ndarray     # (T, P) int64 flat image index (tiles at the border repeat pixels)
    image_order: np.ndarray     # (H*W,) int64 position of each image pixel in the flattened tiles
    tile_axis: np.ndarray       # (T, 3) float64
    tile_half_angle: np.ndarray  # (T,) float64
    pixel_angle: np.ndarray     # (H, W) float32
    valid: np.ndarray           # (H, W) bool: inside the lens' field (fisheye image circle)
    rays_planes: np.ndarray     # (3, H, W) float32 unit rays in image order, one plane per component
    camera_axis: np.ndarray     # (3,) mean ray
    camera_half_angle: float
    tile_row: np.ndarray        # (T,) tile grid row
    tile_axis_f32: np.ndarray
    tile_half_angle_f32: np.ndarray
    tile_sin_half: np.ndarray   # (T,) float32 sin(min(half angle, 90 deg))
    tile_beyond_90: np.ndarray  # (T,) bool: some ray of the tile may point behind the lens plane
    tile_col: np.ndarray        # (T,) tile grid column
    tile_rays: np.ndarray       # (T, P, 3) float32 the rays of tile_planes interleaved (one cv2.transform per quad)
    smallest_pixel_angle: float  # min of pixel_angle (sub-pixel culling)


def camera_rays(camera: Camera, tile_size: int = 16) -> CameraRays:
    """Precompute the rays of ``camera`` (once per camera; DESIGN 6)."""
    width, height = camera.width, camera.height
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    pixels = np.stack([u.ravel(), v.ravel()], axis=1)
    rays = camera.unproject(pixels)
    # Angular size: rays half a pixel apart in x and y; sqrt of the spanned solid angle.
    ray_dx = camera.unproject(pixels + [0.5, 0.0]) - camera.unproject(pixels - [0.5, 0.0])
    ray_dy = camera.unproject(pixels + [0.0, 0.5]) - camera.unproject(pixels - [0.0, 0.5])
    pixel_angle = np.sqrt(np.linalg.norm(np.cross(ray_dx, ray_dy), axis=1)).reshape(height, width)
    incidence = np.arccos(np.clip(rays[:, 2], -1.0, 1.0)).reshape(height, width)
    valid = np.ones((height, width), bool) if camera.model == "pinhole" else incidence < _FISHEYE_MAX_INCIDENCE

    tiles_y, tiles_x = -(-height // tile_size), -(-width // tile_size)
    ty, tx, ky, kx = np.meshgrid(np.arange(tiles_y), np.arange(tiles_x), np.arange(tile_size), np.arange(tile_size), indexing="ij")
    rows = np.minimum(ty * tile_size + ky, height - 1)
    cols = np.minimum(tx * tile_size + kx, width - 1)
    pixel_index = (rows * width + cols).reshape(tiles_y * tiles_x, tile_size * tile_size)
    tile_rays = rays[pixel_index]
    axis = tile_rays.mean(axis=1)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    cos_max = np.einsum("tpk,tk->tp", tile_rays, axis).min(axis=1)
    half_angle = np.arccos(np.clip(cos_max, -1.0, 1.0)) + 1e-4
    # Position of every image pixel in the flattened tile arrays (first occurrence is the true one).
    image_order = np.empty(height * width, np.int64)
    flat = pixel_index.ravel()
    image_order[flat[::-1]] = np.arange(flat.size)[::-1]
    camera_axis = rays.mean(axis=0)
    camera_axis /= np.linalg.norm(camera_axis)
    camera_half = float(np.arccos(np.clip((rays @ camera_axis).min(), -1.0, 1.0))) + 1e-3
    return CameraRays(
        pixel_index=pixel_index, image_order=image_order,
        tile_planes=np.ascontiguousarray(tile_rays.transpose(2, 0, 1)).astype(np.float32),
        tile_rays=np.ascontiguousarray(tile_rays, dtype=np.float32),
        smallest_pixel_angle=float(pixel_angle.min()),
        tile_axis=axis, tile_half_angle=half_angle, pixel_angle=pixel_angle.astype(np.float32),
        valid=valid,
        rays_planes=np.ascontiguousarray(rays.reshape(height, width, 3).transpose(2, 0, 1)).astype(np.float32),
        camera_axis=camera_axis, camera_half_angle=camera_half,
        tile_row=np.repeat(np.arange(tiles_y), tiles_x), tile_col=np.tile(np.arange(tiles_x), tiles_y),
        tile_axis_f32=axis.astype(np.float32), tile_half_angle_f32=half_angle.astype(np.float32),
        tile_sin_half=np.sin(np.minimum(half_angle, np.pi / 2)).astype(np.float32),
        tile_beyond_90=np.arccos(np.clip(axis[:, 2], -1.0, 1.0)) + half_angle >= np.deg2rad(89.0),
    )


# ---------------------------------------------------------------------- prepared scene
@dataclass(frozen=True)
class PreparedQuads:
    """Quads split into pieces of at most ``max_quad_extent_m`` and stored as arrays (world frame)."""

    origin: np.ndarray      # (Q, 3)
    axis_u: np.ndarray      # (Q, 3)
    axis_v: np.ndarray      # (Q, 3)
    normal: np.ndarray      # (Q, 3)
    width: np.ndarray       # (Q,)
    height: np.ndarray      # (Q,)
    offset_a: np.ndarray    # (Q,) m: position of the piece in its parent quad (surface coordinates)
    offset_b: np.ndarray
    texture_map: np.ndarray      # (Q, 2, 3) m: texture coordinates = M @ (a, b, 1) (see prepare_quads)
    road_along: np.ndarray       # (Q,) m: along-road coordinate of the piece's a = 0 (continuous along a road)
    texture_scale: np.ndarray    # (Q,)
    texture_index: np.ndarray    # (Q,) int into the atlas
    gain: np.ndarray        # (Q,) brightness factor
    road: np.ndarray        # (Q,) bool: paint lane markings
    horizontal: np.ndarray  # (Q,) bool: texture mapped from world (x, y); receives cast shadows
    road_across: np.ndarray      # (Q,) m: across-road coordinate of the parent's b = 0 edge (from the carriageway's right edge)
    road_width: np.ndarray       # (Q,) m: width of the carriageway the (road) quad belongs to
    centre: np.ndarray      # (Q, 3) bounding sphere
    radius: np.ndarray      # (Q,)
    parent: np.ndarray      # (Q,) int: index of the quad the piece was split from
    piece_u: np.ndarray     # (Q,) int: the piece's column and row in its parent's grid of pieces
    piece_v: np.ndarray

    def __len__(self) -> int:
        return int(self.width.shape[0])


_SUN_DIRECTION = np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])


def _road_chain_offsets(quads: Sequence[Quad]) -> np.ndarray:
    """Along-road coordinate of each road quad's start, continuous over consecutive road quads.

    Roads come as chains of short overlapping strips (``scene.build_scene``; a chain per half of
    the carriageway); the lane-marking dashes must not restart on every strip, and the halves'
    dashes must meet at the centre line. Consecutive road quads whose starts on the carriageway's
    centre line are close chain up: the offset grows by the distance between their starts along
    the previous strip.
    """
    offsets = np.zeros(len(quads))
    previous: tuple[np.ndarray, np.ndarray, float, float] | None = None
    for index, quad in enumerate(quads):
        if quad.kind != "road":
            previous = None
            continue
        road_width = quad.road_width if quad.road_width > 0.0 else quad.height
        start = np.asarray(quad.origin, float) + (0.5 * road_width - quad.road_across) * np.asarray(quad.axis_v, float)
        if previous is not None:
            prev_start, prev_u, prev_offset, prev_width = previous
            step = float((start - prev_start) @ prev_u)
            if 0.0 <= step <= prev_width + 0.5 and np.linalg.norm(start - prev_start - step * prev_u) < 1.0:
                offsets[index] = prev_offset + step
        previous = (start, np.asarray(quad.axis_u, float), offsets[index], quad.width)
    return offsets


def _times(vectors: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``vectors (N, 3) @ matrix`` for a (3, M) matrix or a (3,) vector, as three broadcast products.

    No BLAS call: its thread pool costs more than these small products and oversubscribes the cores
    (with OpenBLAS threads the renderer ran 2-3x slower)."""
    if matrix.ndim == 1:
        return vectors[:, 0] * matrix[0] + vectors[:, 1] * matrix[1] + vectors[:, 2] * matrix[2]
    return vectors[:, 0:1] * matrix[0] + vectors[:, 1:2] * matrix[1] + vectors[:, 2:3] * matrix[2]


def _quad_cone_facets(corners: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Unit inward normals (Q, 4, 3) float32 of the faces of the cone of rays from the camera centre
    through each quad (corners (Q, 4, 3) in order around the quad, centre (Q, 3); camera frame): a
    ray ``d`` meets the quad (at a positive distance) exactly when ``normal . d >= 0`` for all four
    faces. A face whose two corners are nearly in line with the camera centre gets a zero normal
    (no test)."""
    following = np.roll(corners, -1, axis=1)
    normals = np.cross(corners, following)
    length = np.linalg.norm(normals, axis=2, keepdims=True)
    usable = length > 1e-9 * np.linalg.norm(corners, axis=2, keepdims=True) * np.linalg.norm(following, axis=2, keepdims=True)
    normals = np.where(usable, normals / np.maximum(length, 1e-300), 0.0)
    normals *= np.where(np.einsum("qfk,qk->qf", normals, centre) < 0, -1.0, 1.0)[..., None]
    return normals.astype(np.float32)


def _dot_rows(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Row-wise dot products (N,) of two (N, 3) arrays, as three products (the dtype of the inputs)."""
    return first[:, 0] * second[:, 0] + first[:, 1] * second[:, 1] + first[:, 2] * second[:, 2]


_NEAR_PLANE_M = 1e-3


def _clip_polygon_near(points: np.ndarray, z_near: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex polygon (K, 3) to the half-space z >= z_near."""
    output = []
    count = len(points)
    for k in range(count):
        current, following = points[k], points[(k + 1) % count]
        current_in, following_in = current[2] >= z_near, following[2] >= z_near
        if current_in:
            output.append(current)
        if current_in != following_in:
            fraction = (z_near - current[2]) / (following[2] - current[2])
            output.append(current + fraction * (following - current))
    return np.array(output).reshape(-1, 3)


def merge_collinear_strips(quads: Sequence[Quad], tolerance: float = 1e-6) -> list[Quad]:
    """Merge consecutive quads that continue each other along ``axis_u`` on straight stretches.

    Roads and shoulders come as chains of short overlapping strips; on straights consecutive strips
    share their axes and lie on one line, and one long quad renders the same pixels with less
    overdraw. Only horizontal quads of the same kind, texture, scale and height are merged (their
    texture is mapped from world x, y, so it is unchanged).
    """
    merged: list[Quad] = []
    for quad in quads:
        if merged:
            last = merged[-1]
            step = np.asarray(quad.origin, float) - np.asarray(last.origin, float)
            along = float(step @ np.asarray(last.axis_u, float))
            same = (quad.kind == last.kind and quad.texture == last.texture and quad.texture_scale == last.texture_scale
                    and abs(quad.height - last.height) < tolerance
                    and np.allclose(quad.axis_u, last.axis_u, atol=tolerance) and np.allclose(quad.axis_v, last.axis_v, atol=tolerance)
                    and abs(float(np.cross(last.axis_u, last.axis_v)[2])) > 0.9)
            if same and 0.0 < along <= last.width + tolerance and np.linalg.norm(step - along * np.asarray(last.axis_u, float)) < tolerance:
                merged[-1] = Quad(last.origin, last.axis_u, last.axis_v, max(last.width, along + quad.width), last.height,
                                  last.kind, last.texture, last.texture_scale)
                continue
        merged.append(quad)
    return merged


def prepare_quads(quads: Sequence[Quad], atlas: TextureAtlas, options: RenderOptions, seed_offset: int = 0) -> PreparedQuads:
    """Split, shade and index ``quads`` for rendering (pure: same input, same output).

    Texture coordinates (metres, divided by ``texture_scale`` for the texture) are an affine map of
    the surface coordinates: for horizontal quads (road, ground) the world ``(x, y)``, so that
    adjacent strips continue each other's texture seamlessly; for the others ``(a, b)`` plus a random
    per-quad shift, so that quads sharing a texture do not look identical (markers: no shift).
    """
    columns: dict[str, list] = {name: [] for name in PreparedQuads.__dataclass_fields__}
    road_offsets = _road_chain_offsets(quads)
    for parent_index, quad in enumerate(quads):
        if quad.kind == "road" and options.road_texture:
            quad = dataclasses.replace(quad, texture=options.road_texture)
        elif quad.texture == "grass" and options.grass_texture:
            quad = dataclasses.replace(quad, texture=options.grass_texture)
        if quad.texture not in atlas.names:
            raise ConfigError(f"quad {parent_index} ({quad.kind}): texture {quad.texture!r} not in the atlas {atlas.names}")
        if quad.texture_scale <= 0 or quad.width <= 0 or quad.height <= 0:
            raise ConfigError(f"quad {parent_index} ({quad.kind}): width, height and texture_scale must be positive")
        # Seeded by the quad's geometry, not its index: the look does not depend on the scene order.
        geometry = np.concatenate([quad.origin, quad.axis_u, quad.axis_v, [quad.width, quad.height]]).astype(np.float64)
        rng = np.random.default_rng([options.seed, seed_offset, zlib.crc32(geometry.tobytes())])
        axis_u = np.asarray(quad.axis_u, float)
        axis_v = np.asarray(quad.axis_v, float)
        origin = np.asarray(quad.origin, float)
        normal = np.cross(axis_u, axis_v)
        # Boxes (vehicles, the trailer) keep surface coordinates on their roofs too: they may move.
        horizontal = abs(normal[2]) > 0.9 and quad.kind not in ("marker", "box")
        if horizontal:
            texture_map = np.array([[axis_u[0], axis_v[0], origin[0]], [axis_u[1], axis_v[1], origin[1]]])
        elif quad.kind == "marker":
            texture_map = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        else:
            shift = rng.uniform(0.0, quad.texture_scale, 2)
            texture_map = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])
        if not options.shading or quad.kind == "marker":
            gain = 1.0
        elif horizontal:
            gain = 1.0 if quad.kind == "road" else rng.uniform(0.92, 1.05)
        else:  # walls: lit by the sun by orientation, albedo jitter
            gain = (0.72 + 0.3 * abs(float(normal @ _SUN_DIRECTION))) * rng.uniform(0.85, 1.1)
        pieces_u = max(1, math.ceil(quad.width / options.max_quad_extent_m))
        pieces_v = max(1, math.ceil(quad.height / options.max_quad_extent_m))
        piece_w, piece_h = quad.width / pieces_u, quad.height / pieces_v
        for i in range(pieces_u):
            for j in range(pieces_v):
                piece_origin = origin + i * piece_w * axis_u + j * piece_h * axis_v
                columns["origin"].append(piece_origin)
                columns["axis_u"].append(axis_u)
                columns["axis_v"].append(axis_v)
                columns["normal"].append(normal)
                columns["width"].append(piece_w)
                columns["height"].append(piece_h)
                columns["offset_a"].append(i * piece_w)
                columns["offset_b"].append(j * piece_h)
                columns["texture_map"].append(texture_map)
                columns["road_along"].append(road_offsets[parent_index])
                columns["texture_scale"].append(quad.texture_scale * (options.ground_texture_scale if horizontal else 1.0))
                columns["texture_index"].append(atlas.index(quad.texture))
                columns["gain"].append(gain)
                columns["road"].append(quad.kind == "road" and options.road_markings)
                columns["horizontal"].append(horizontal)
                columns["road_across"].append(quad.road_across)
                columns["road_width"].append(quad.road_width if quad.road_width > 0.0 else quad.height)
                columns["centre"].append(piece_origin + 0.5 * piece_w * axis_u + 0.5 * piece_h * axis_v)
                columns["radius"].append(0.5 * math.hypot(piece_w, piece_h))
                columns["parent"].append(parent_index)
                columns["piece_u"].append(i)
                columns["piece_v"].append(j)
    if not columns["width"]:
        empty = {name: np.zeros((0, 3)) for name in ("origin", "axis_u", "axis_v", "normal", "centre")}
        empty.update({name: np.zeros(0) for name in ("width", "height", "offset_a", "offset_b", "road_along", "texture_scale", "gain", "road_across", "road_width", "radius")})
        empty.update({name: np.zeros(0, np.int64) for name in ("texture_index", "parent", "piece_u", "piece_v")})
        return PreparedQuads(**empty, texture_map=np.zeros((0, 2, 3)), road=np.zeros(0, bool), horizontal=np.zeros(0, bool))
    arrays = {name: np.asarray(values) for name, values in columns.items()}
    for name in ("texture_index", "parent", "piece_u", "piece_v"):
        arrays[name] = arrays[name].astype(np.int64)
    arrays["road"] = arrays["road"].astype(bool)
    return PreparedQuads(**arrays)


@dataclass(frozen=True)
class ShadowMap:
    """Where the ground (z = 0) is lit: ``lit`` (H, W) float32 in [0, 1] on a grid of ``resolution``
    metres from world ``origin`` (x, y) (row = y, column = x)."""

    origin: np.ndarray
    resolution: float
    lit: np.ndarray

    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear lit fraction at world points (outside the map: lit)."""
        map_x = ((x - np.float32(self.origin[0])) / np.float32(self.resolution)).astype(np.float32)
        map_y = ((y - np.float32(self.origin[1])) / np.float32(self.resolution)).astype(np.float32)
        lit = cv2.remap(self.lit, map_x.reshape(map_x.shape[0], -1), map_y.reshape(map_y.shape[0], -1), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=1.0)
        return lit.reshape(np.shape(x))


_SHADOW_CASTERS = ("facade", "box", "pole")
_MAX_SHADOW_SIDE = 4096


def shadow_map(quads: Sequence[Quad], sun: np.ndarray, resolution: float = 0.2) -> ShadowMap | None:
    """Cast shadows of walls, boxes and poles on the ground plane z = 0 (a parallel projection along
    the sun direction: each quad's shadow is the convex polygon of its corners moved by
    ``-z / sun_z * sun``), rasterised anti-aliased and softened by about one cell (penumbra).
    Horizontal surfaces at other heights get the z = 0 shadows (exact for a flat world)."""
    sun = np.asarray(sun, float) / np.linalg.norm(sun)
    ground = [quad for quad in quads if quad.kind in ("road", "ground")]
    casters = [quad for quad in quads if quad.kind in _SHADOW_CASTERS]
    if not ground or not casters or sun[2] <= 0.05:
        return None
    corners = np.array([[q.origin, q.origin + q.width * q.axis_u, q.origin + q.width * q.axis_u + q.height * q.axis_v, q.origin + q.height * q.axis_v]
                        for q in casters])                                         # (C, 4, 3)
    shadows = corners[..., :2] - (np.maximum(corners[..., 2:3], 0.0) / sun[2]) * sun[:2]
    extent = np.array([[q.origin, q.origin + q.width * q.axis_u + q.height * q.axis_v] for q in ground]).reshape(-1, 3)[:, :2]
    low, high = extent.min(axis=0), extent.max(axis=0)
    resolution = max(resolution, float(np.max(high - low)) / _MAX_SHADOW_SIDE)
    size = np.ceil((high - low) / resolution).astype(int) + 2
    shade = np.zeros((size[1], size[0]), np.uint8)
    scale = 16  # cv2 sub-pixel shift: 4 fractional bits
    for polygon in shadows:
        points = np.round((polygon - low) / resolution * scale).astype(np.int32)
        cv2.fillConvexPoly(shade, cv2.convexHull(points), 255, lineType=cv2.LINE_AA, shift=4)
    lit = 1.0 - cv2.GaussianBlur(shade.astype(np.float32) / 255.0, (0, 0), 0.7)
    return ShadowMap(low, resolution, lit.astype(np.float32))


def _concat_prepared(first: PreparedQuads, second: PreparedQuads) -> PreparedQuads:
    return PreparedQuads(**{name: np.concatenate([getattr(first, name), getattr(second, name)]) for name in PreparedQuads.__dataclass_fields__})


_BATCH_MAX_TILES = 4   # quads on at most this many tiles are ray-tested in batches
_BATCH_QUADS = 64
_SUBPIXEL_FRACTION = 0.25  # quads below this share of a pixel's solid angle are not rendered
_COARSE_FACTOR = 8  # pieces per side of a coarse block (level of detail beyond detail_distance_m)


def _tiles_in_boxes(box: np.ndarray, tiles_x: int) -> tuple[np.ndarray, np.ndarray]:
    """Every tile of each non-empty box ``(first column, last column, first row, last row)`` (B, 4)
    int of a grid ``tiles_x`` tiles wide, as pairs ``(box index, tile index)``: by box, then by tile."""
    columns = box[:, 1] - box[:, 0] + 1
    counts = columns * (box[:, 3] - box[:, 2] + 1)
    owner = np.repeat(np.arange(len(box)), counts)
    local = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    width = columns[owner]
    return owner, (box[owner, 2] + local // width) * tiles_x + box[owner, 0] + local % width


def _tiles_to_image(values: np.ndarray, rays: CameraRays, shape: tuple[int, int]) -> np.ndarray:
    """Tile-major per-pixel values (T, P) as an image (H, W): a transposed copy when the tiles cover
    the image exactly, else a gather through ``rays.image_order``."""
    height, width = shape
    tile = math.isqrt(values.shape[1])
    if height % tile or width % tile:
        return values.ravel()[rays.image_order].reshape(shape)
    return values.reshape(height // tile, width // tile, tile, tile).transpose(0, 2, 1, 3).reshape(shape)


def coarsen_pieces(pieces: PreparedQuads, factor: int) -> tuple[PreparedQuads, np.ndarray]:
    """Blocks of up to ``factor`` x ``factor`` neighbouring pieces of the same parent merged into one
    piece each (exactly their union: same plane, texture map and shading), and each piece's block."""
    if len(pieces) == 0:
        return pieces, np.zeros(0, np.int64)
    keys = np.stack([pieces.parent, pieces.piece_u // factor, pieces.piece_v // factor], axis=1)
    _, first, block_of_piece = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    block_of_piece = block_of_piece.ravel()
    count = len(first)
    # Pieces are listed by parent, then u, then v: the first piece of a block is its corner.
    width = np.zeros(count)
    np.add.at(width, block_of_piece, np.where(pieces.piece_v % factor == 0, pieces.width, 0.0))
    height = np.zeros(count)
    np.add.at(height, block_of_piece, np.where(pieces.piece_u % factor == 0, pieces.height, 0.0))
    blocks = _select_prepared(pieces, first)
    centre = blocks.origin + 0.5 * width[:, None] * blocks.axis_u + 0.5 * height[:, None] * blocks.axis_v
    return dataclasses.replace(blocks, width=width, height=height, centre=centre, radius=0.5 * np.hypot(width, height)), block_of_piece


def _select_prepared(quads: PreparedQuads, keep: np.ndarray) -> PreparedQuads:
    return PreparedQuads(**{name: getattr(quads, name)[keep] for name in PreparedQuads.__dataclass_fields__})


def move_prepared(quads: PreparedQuads, T_world_body: np.ndarray) -> PreparedQuads:
    """Quads prepared in a body frame, moved rigidly to ``T_world_body``: geometry changes, texture
    coordinates (surface coordinates of non-horizontal quads) and shading stay, so a moving body's
    texture moves with it."""
    R, p = T_world_body[:3, :3], T_world_body[:3, 3]
    return dataclasses.replace(quads, origin=quads.origin @ R.T + p, axis_u=quads.axis_u @ R.T, axis_v=quads.axis_v @ R.T,
                               normal=quads.normal @ R.T, centre=quads.centre @ R.T + p)


def _paint_markings(surface: np.ndarray, along: np.ndarray, across: np.ndarray, road_width: np.ndarray,
                    footprint_across: np.ndarray, footprint_along: np.ndarray) -> np.ndarray:
    """Lane paint in road coordinates (m): solid edge lines 0.35 m inside both edges (0.15 m wide)
    and a dashed centre line (0.12 m wide, 3 m dash, 6 m gap), box-filtered by the pixel footprint."""
    width_px = np.maximum(footprint_across, 1e-3)
    along_px = np.maximum(footprint_along, 1e-3)

    def ramp(value: np.ndarray) -> np.ndarray:
        return np.minimum(np.maximum(value + np.float32(0.5), np.float32(0.0)), np.float32(1.0))

    def band(distance: np.ndarray, half_width: float, pixel: np.ndarray) -> np.ndarray:
        return ramp((np.float32(half_width) - np.abs(distance)) / pixel)

    edge = np.maximum(band(across - np.float32(0.35), 0.075, width_px), band(across - (road_width - np.float32(0.35)), 0.075, width_px))
    phase = along - np.float32(9.0) * np.floor(along / np.float32(9.0))
    dash_along = np.minimum(ramp(phase / along_px), ramp((np.float32(3.0) - phase) / along_px))
    centre = band(across - np.float32(0.5) * road_width, 0.06, width_px) * dash_along
    coverage = np.maximum(edge, centre).astype(np.float32, copy=False)
    return surface + coverage * (np.float32(215.0) - surface)


_OUTLINE_SAMPLES = 8  # points per quad edge for the projected bounding box
_FACET_MARGIN = 1e-4  # rad: a tile is culled or interior to a quad's ray cone only by this much


@dataclass(frozen=True)
class VisibilityBuffer:
    """Result of the depth pass, per pixel (H, W): ray distance (inf: sky), quad index (-1: sky),
    texture coordinates, |cos| of the incidence angle; surface coordinates on request
    (:meth:`surface_coordinates`)."""

    depth: np.ndarray
    quad_id: np.ndarray
    texture_s: np.ndarray  # texture coordinates (m) = the quad's texture map applied to (a, b)
    texture_t: np.ndarray
    cos_incidence: np.ndarray
    quads: "PreparedQuads"
    shade: np.ndarray | None = None  # (H, W) brightness factor of the relief's slopes (None: none in view)
    surface_frame: np.ndarray | None = None  # (Q, 8) camera-frame u, c_a, v, c_b: a = t (d . u) + c_a, b likewise
    rays_planes: np.ndarray | None = None    # (3, H, W) the pixels' unit rays d

    def surface_coordinates(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Surface coordinates ``(a, b)`` (m, in the hit quad's parent) float32 (K,) of the hit pixels
        ``pixels`` (K,) (flat image indices): ``a = t (d . u) + c_a`` with the ray ``d`` and distance ``t``."""
        frame = np.take(np.ascontiguousarray(self.surface_frame.T, dtype=np.float32), self.quad_id.ravel()[pixels], axis=1)  # (8, K)
        t = self.depth.ravel()[pixels]
        d = np.take(self.rays_planes.reshape(3, -1), pixels, axis=1)
        coord_a = t * (d[0] * frame[0] + d[1] * frame[1] + d[2] * frame[2]) + frame[3]
        coord_b = t * (d[0] * frame[4] + d[1] * frame[5] + d[2] * frame[6]) + frame[7]
        return coord_a, coord_b


_RELIEF_RANGE_M = 60.0      # beyond, a bump of a few cm is below a pixel: the quad's plane is kept
_RELIEF_MARCH_STEPS = 8     # samples of the ray's bracket before the false-position refinement
_RELIEF_REFINE_STEPS = 4
_RELIEF_MIN_APPROACH = 1e-3  # |rate| at which a ray nears the plane below which it is left on the plane
_POTHOLE_DARKENING = 0.35   # a pothole's floor is this much darker (exposed, dirty aggregate)


@dataclass(frozen=True)
class ReliefHits:
    """Pixels (flat image indices) whose ray meets the relief (bumps, potholes) on a horizontal quad:
    the ray distance there and the brightness factor of the surface's local slope."""

    pixels: np.ndarray
    depth: np.ndarray
    shade: np.ndarray


def relief_hits(bumps: Sequence[Any], camera_position: np.ndarray, rays_world: np.ndarray, depth: np.ndarray,
                plane_normal: np.ndarray, pixels: np.ndarray, shadow_darkness: float) -> ReliefHits | None:
    """First hits of rays with a horizontal quad's plane raised by the relief ``delta(x, y)``
    (``road.relief_height``; DESIGN 6), for the pixels ``pixels`` (K,) whose rays ``rays_world``
    (K, 3, unit) hit that plane (world normal ``plane_normal`` (K, 3), upwards) at ``depth`` (K,).

    Along the ray ``p(t) = c + t d`` the height above the plane is ``k (t - t0)`` with
    ``k = (n . d) / n_z`` (< 0 from above), so the hit solves ``f(t) = k (t - t0) - delta(p(t)) = 0``.
    The relief lies within ``[delta_lo, delta_hi]``: the first root is in ``[t0 + delta_hi / k,
    t0 + delta_lo / k]``, where ``f`` goes from >= 0 to <= 0. Pixels whose bracket passes no bump
    are left; the others are marched in ``_RELIEF_MARCH_STEPS`` steps to the first sign change and
    refined by false position. Shading: the sunlit part of the brightness (``1 - shadow_darkness``)
    scales with the local normal's ``n . sun`` against the plane's, and a pothole's floor is darker
    by up to ``_POTHOLE_DARKENING`` of its depth fraction."""
    from ampc_vo.sim.road import relief_gradient, relief_height

    if not len(bumps) or not len(pixels):
        return None
    approach = (plane_normal[:, 0] * rays_world[:, 0] + plane_normal[:, 1] * rays_world[:, 1] + plane_normal[:, 2] * rays_world[:, 2]) / plane_normal[:, 2]
    usable = (approach < -_RELIEF_MIN_APPROACH) & (depth < _RELIEF_RANGE_M)
    high, low = _relief_heights(bumps)
    safe = np.where(usable, approach, -1.0)
    t_start, t_stop = depth + high / safe, depth + low / safe
    start = camera_position[:2] + t_start[:, None] * rays_world[:, :2]
    segment = (t_stop - t_start)[:, None] * rays_world[:, :2]
    near = np.zeros(len(pixels), bool)
    near_each = []  # per bump the pixels whose bracket passes it
    segment_length = np.sqrt(segment[:, 0] ** 2 + segment[:, 1] ** 2)
    for bump in bumps:  # distance of the bump's centre from the bracket's xy segment
        reach = _bump_reach(bump)
        relative = np.asarray(bump.center) - start
        # Cheap bound first (the segment lies within its length of its start), exact test after.
        maybe = np.flatnonzero(relative[:, 0] ** 2 + relative[:, 1] ** 2 <= (reach + segment_length) ** 2)
        relative, part = relative[maybe], segment[maybe]
        along = np.clip(np.einsum("kj,kj->k", relative, part) / np.maximum(np.einsum("kj,kj->k", part, part), 1e-12), 0.0, 1.0)
        near_each.append(maybe[np.linalg.norm(relative - along[:, None] * part, axis=1) <= reach])
        near[near_each[-1]] = True
    chosen = np.flatnonzero(usable & near)
    if chosen.size == 0:
        return None
    c, d, k, t0 = camera_position, rays_world[chosen], approach[chosen], depth[chosen]
    row_of = np.full(len(pixels), -1)
    row_of[chosen] = np.arange(len(chosen))
    rows_each = [row_of[close][row_of[close] >= 0] for close in near_each]  # rows of `chosen` near each bump

    def residual(t: np.ndarray) -> np.ndarray:  # f(t) for t (K,) or (K, S); each bump evaluated near its rays only (zero elsewhere)
        shape = t.shape
        t = t.reshape(len(chosen), -1)
        height = np.zeros(t.shape)
        for bump, rows in zip(bumps, rows_each):
            if rows.size:
                xy = c[:2] + t[rows, :, None] * d[rows, None, :2]
                height[rows] += bump.height_at(xy.reshape(-1, 2)).reshape(len(rows), -1)
        return (k[:, None] * (t - t0[:, None]) - height).reshape(shape)

    fractions = np.linspace(0.0, 1.0, _RELIEF_MARCH_STEPS + 1)
    samples = t_start[chosen, None] + fractions[None, :] * (t_stop - t_start)[chosen, None]            # (K, S)
    values = residual(samples)
    values[:, -1] = np.minimum(values[:, -1], 0.0)
    first = np.argmax(values <= 0.0, axis=1)                                                         # first sample at or below
    rows = np.arange(len(chosen))
    upper = np.maximum(first - 1, 0)
    a, b = samples[rows, upper], samples[rows, first]
    fa, fb = values[rows, upper], values[rows, first]
    for _ in range(_RELIEF_REFINE_STEPS):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(fa - fb > 1e-12, a + fa * (b - a) / (fa - fb), b)
        ft = residual(t)
        above = ft > 0.0
        a, fa = np.where(above, t, a), np.where(above, ft, fa)
        b, fb = np.where(above, b, t), np.where(above, fb, ft)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(fa - fb > 1e-12, a + fa * (b - a) / (fa - fb), b)
    xy = c[:2] + t[:, None] * d[:, :2]
    n = plane_normal[chosen]
    slope = -n[:, :2] / n[:, 2:3] + relief_gradient(bumps, xy)
    local = np.column_stack([-slope, np.ones(len(chosen))])
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    lit = np.maximum(local @ _SUN_DIRECTION, 0.0) / np.maximum(n @ _SUN_DIRECTION, 1e-3)
    shade = shadow_darkness + (1.0 - shadow_darkness) * lit
    if low < 0.0:
        shade *= 1.0 - _POTHOLE_DARKENING * np.clip(relief_height(bumps, xy) / low, 0.0, 1.0)
    return ReliefHits(pixels[chosen], t.astype(np.float32), shade.astype(np.float32))


def _bump_reach(bump: Any) -> float:
    """Radius (m) of the disc around a bump's centre that holds it (its half diagonal, 1 mm more)."""
    return 0.5 * math.hypot(bump.length, bump.width) + 1e-3


def _relief_heights(bumps: Sequence[Any]) -> tuple[float, float]:
    """``(highest, lowest)`` the summed relief can reach above its plane (m): the sums of the bumps'
    positive and of their negative heights."""
    heights = np.array([bump.height for bump in bumps])
    return float(np.sum(np.maximum(heights, 0.0))), float(np.sum(np.minimum(heights, 0.0)))


# corner k of a box is (x_lo or x_hi, y_lo or y_hi, z_lo or z_hi) by its bits 0, 1, 2; edges join corners one bit apart
_BOX_CORNER_BITS = (np.arange(8)[:, None] >> np.arange(3)) & 1
_BOX_EDGES = np.array([(k, k | bit) for k in range(8) for bit in (1, 2, 4) if not k & bit])


def relief_footprint(bumps: Sequence[Any], quads: PreparedQuads, camera: Camera, T_world_camera: np.ndarray) -> np.ndarray | None:
    """Pixels (H, W) bool whose rays can meet the relief in :func:`relief_hits`, or None (every
    pixel) for cameras other than an undistorted pinhole.

    A pixel's relief bracket lies within ``[lowest, highest]`` (:func:`_relief_heights`) vertically
    above the plane of the horizontal quad it sees (within ``_RELIEF_RANGE_M``), and it matters only
    over a bump's disc: so inside the box of the disc's square from the lowest of those planes over
    it (plus ``lowest``) to the highest (plus ``highest``). The box, clipped at a near plane, projects
    into the hull of its projected vertices; the pixels are their bounding rectangle, 1 px wider."""
    if camera.model != "pinhole" or np.any(camera.distortion):
        return None
    R, position = np.asarray(T_world_camera[:3, :3], float), np.asarray(T_world_camera[:3, 3], float)
    footprint = np.zeros((camera.height, camera.width), bool)
    reachable = quads.horizontal & (np.linalg.norm(quads.centre - position, axis=1) - quads.radius < _RELIEF_RANGE_M)
    if not reachable.any():
        return footprint
    normal, origin = quads.normal[reachable], quads.origin[reachable]
    highest, lowest = _relief_heights(bumps)
    tilt = (np.abs(normal[:, 0]) + np.abs(normal[:, 1])) / np.abs(normal[:, 2])  # plane height change per m (max over a square)
    for bump in bumps:
        reach, centre = _bump_reach(bump), np.asarray(bump.center, float)
        plane_z = origin[:, 2] - (normal[:, 0] * (centre[0] - origin[:, 0]) + normal[:, 1] * (centre[1] - origin[:, 1])) / normal[:, 2]
        z_range = (float(np.min(plane_z - reach * tilt)) + lowest, float(np.max(plane_z + reach * tilt)) + highest)
        corners = np.column_stack([centre[0] + reach * (2 * _BOX_CORNER_BITS[:, 0] - 1), centre[1] + reach * (2 * _BOX_CORNER_BITS[:, 1] - 1),
                                   np.where(_BOX_CORNER_BITS[:, 2] == 1, z_range[1], z_range[0])])
        points = (corners - position) @ R                                       # camera frame
        first, second = points[_BOX_EDGES[:, 0]], points[_BOX_EDGES[:, 1]]
        crossing = (first[:, 2] >= _NEAR_PLANE_M) != (second[:, 2] >= _NEAR_PLANE_M)
        fraction = (_NEAR_PLANE_M - first[crossing, 2]) / (second[crossing, 2] - first[crossing, 2])
        vertices = np.concatenate([points[points[:, 2] >= _NEAR_PLANE_M], first[crossing] + fraction[:, None] * (second[crossing] - first[crossing])])
        if len(vertices) == 0:
            continue                                                            # behind the camera
        u = np.clip(camera.fx * vertices[:, 0] / vertices[:, 2] + camera.cx, -1.0, camera.width)
        v = np.clip(camera.fy * vertices[:, 1] / vertices[:, 2] + camera.cy, -1.0, camera.height)
        columns = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 2, camera.width)
        rows = max(int(np.floor(v.min())) - 1, 0), min(int(np.ceil(v.max())) + 2, camera.height)
        footprint[rows[0]:rows[1], columns[0]:columns[1]] = True
    return footprint


# ---------------------------------------------------------------------- the renderer
class Renderer:
    """Renders one scene for any camera and pose; caches per-camera rays and the texture atlas."""

    def __init__(self, scene: Scene, textures: TextureAtlas | dict[str, np.ndarray] | None = None,
                 options: RenderOptions | None = None) -> None:
        self.options = options or RenderOptions()
        if textures is None:
            textures = load_textures(seed=self.options.seed)
        self.atlas = textures if isinstance(textures, TextureAtlas) else build_atlas(textures)
        self.quads = prepare_quads(merge_collinear_strips(scene.quads), self.atlas, self.options)
        # Level of detail: far from the camera, blocks of pieces are tested as one (the pieces only
        # help culling near them; hits and texture coordinates are the same, pieces store offsets).
        self.coarse_quads, self._coarse_of_piece = coarsen_pieces(self.quads, _COARSE_FACTOR)
        self.shadows = shadow_map(scene.quads, _SUN_DIRECTION) if self.options.shadows else None
        self.relief = tuple(scene.relief)  # bumps and potholes added to the horizontal quads per pixel (relief_hits)
        self._rays: dict[tuple, CameraRays] = {}
        self._bodies: dict[tuple, tuple] = {}  # moving bodies' faces prepared in their own frames
        self.last_stats: dict[str, int] = {}  # work of the last depth pass (candidates, quads and ray tests)

    def quads_near(self, camera_position: np.ndarray) -> PreparedQuads:
        """The scene's quads for a camera at ``camera_position`` (world): split into pieces where a
        quad comes within ``detail_distance_m``, whole beyond (DESIGN 6)."""
        coarse = self.coarse_quads
        near = np.linalg.norm(coarse.centre - camera_position, axis=1) - coarse.radius < self.options.detail_distance_m
        if near.all():
            return self.quads
        return _concat_prepared(_select_prepared(self.quads, near[self._coarse_of_piece]), _select_prepared(coarse, ~near))

    def rays_of(self, camera: Camera) -> CameraRays:
        key = (camera.name, camera.model, camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy,
               tuple(camera.distortion))
        if key not in self._rays:
            self._rays[key] = camera_rays(camera, self.options.tile_size)
        return self._rays[key]

    # ------------------------------------------------------------------ visibility
    def _candidate_tiles(self, camera: Camera, rays: CameraRays, quads: PreparedQuads,
                         centre: np.ndarray, origin_c: np.ndarray, normal_c: np.ndarray,
                         outline_c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Quads that may be visible and, per quad, the tiles its rays may hit (conservative):
        ``(candidates (C,), tiles (N,), starts (C + 1,), edges (C,))``, the tiles of candidate ``k``
        being ``tiles[starts[k]:starts[k + 1]]``: first its ``edges[k]`` edge tiles, then the
        interior tiles whose every ray meets the quad (each part in increasing order).

        Four tests, all conservative: for quads entirely in front of the lens, the image bounding
        box of their projected outline; the quad's bounding sphere against each tile's ray cone;
        the quad's plane must be reachable from the tile (some ray points towards its side); and
        the tile's ray cone must reach inside each face of the cone of rays through the quad's
        corners (inside all four: an interior tile). The last three are evaluated on the tiles of
        the bounding box only (quad-tile pairs).
        """
        distance = np.linalg.norm(centre, axis=1)
        inside = distance <= quads.radius * 1.0001
        safe_distance = np.maximum(distance, 1e-9)
        angular_radius = np.arcsin(np.clip(quads.radius / safe_distance, 0.0, 1.0))
        cos_axis = _times(centre, rays.camera_axis) / safe_distance
        in_view = inside | (np.arccos(np.clip(cos_axis, -1, 1)) <= rays.camera_half_angle + angular_radius)
        # Sub-pixel culling: a quad subtending less than a quarter of the smallest pixel's solid angle
        # (its area over the squared distance, an upper bound) is hit by one ray per pixel at random
        # rather than imaged (aliasing, not detail; a camera would blur it into its background).
        pixel_solid_angle = rays.smallest_pixel_angle**2
        in_view &= inside | (quads.width * quads.height >= _SUBPIXEL_FRACTION * pixel_solid_angle * safe_distance**2)
        candidates = np.flatnonzero(in_view)
        if candidates.size == 0:
            return candidates, np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0, np.int64)
        # Tile-grid bounding box of the projected outline when all of it is safely in front.
        outline = outline_c[candidates]  # (C, S, 3)
        flat = outline.reshape(-1, 3)
        if camera.model == "pinhole":
            front = flat[:, 2] > 0.05 * np.linalg.norm(flat, axis=1)
        else:
            front = np.arctan2(np.hypot(flat[:, 0], flat[:, 1]), flat[:, 2]) < np.deg2rad(95.0)
        front = front.reshape(outline.shape[:2]).all(axis=1)
        tiles_y, tiles_x = int(rays.tile_row[-1]) + 1, int(rays.tile_col[-1]) + 1
        box = np.zeros((candidates.size, 4))
        box[:] = (0, tiles_x - 1, 0, tiles_y - 1)
        if front.any():
            pixels, _ = camera.project(outline[front].reshape(-1, 3))
            pixels = pixels.reshape(-1, outline.shape[1], 2)
            margin, tile = 2.0, self.options.tile_size
            box[front] = np.stack([
                np.floor((pixels[..., 0].min(axis=1) - margin) / tile), np.floor((pixels[..., 0].max(axis=1) + margin) / tile),
                np.floor((pixels[..., 1].min(axis=1) - margin) / tile), np.floor((pixels[..., 1].max(axis=1) + margin) / tile),
            ], axis=1)
        if camera.model == "pinhole" and not np.any(camera.distortion) and not front.all():
            # Quads reaching behind the lens (ground around the vehicle): clip them at a near plane;
            # an undistorted pinhole maps the clipped polygon's edges to straight segments.
            tile = self.options.tile_size
            for index in np.flatnonzero(~front):
                corners = outline[index, ::_OUTLINE_SAMPLES]
                polygon = _clip_polygon_near(corners, _NEAR_PLANE_M)
                if len(polygon) == 0:
                    box[index] = (1, 0, 1, 0)  # empty
                    continue
                pixels = np.stack([camera.fx * polygon[:, 0] / polygon[:, 2] + camera.cx, camera.fy * polygon[:, 1] / polygon[:, 2] + camera.cy], axis=1)
                pixels = np.clip(pixels, -1e6, 1e6)
                box[index] = (np.floor((pixels[:, 0].min() - 2.0) / tile), np.floor((pixels[:, 0].max() + 2.0) / tile),
                              np.floor((pixels[:, 1].min() - 2.0) / tile), np.floor((pixels[:, 1].max() + 2.0) / tile))
        wide = np.zeros(candidates.size, bool)  # quads that also need the tiles seeing behind the lens
        if camera.model == "fisheye" and not front.all():
            # Clip at a near plane too; the clipped polygon's edges are curves in a fisheye image, so
            # they are sampled densely. Parts behind the lens plane can only appear in tiles whose
            # rays reach beyond 90 degrees of incidence (image corners of very wide lenses).
            tile = self.options.tile_size
            steps = np.linspace(0.0, 1.0, 32, endpoint=False)[:, None]
            for index in np.flatnonzero(~front):
                corners = outline[index, ::_OUTLINE_SAMPLES]
                polygon = _clip_polygon_near(corners, _NEAR_PLANE_M)
                wide[index] = bool(np.any(corners[:, 2] < _NEAR_PLANE_M))
                if len(polygon) == 0:
                    box[index] = (1, 0, 1, 0)  # empty (the wide tiles may still apply)
                    continue
                samples = (polygon[:, None, :] + steps[None] * (np.roll(polygon, -1, axis=0) - polygon)[:, None, :]).reshape(-1, 3)
                pixels, _ = camera.project(samples)
                margin = 4.0
                box[index] = (np.floor((pixels[:, 0].min() - margin) / tile), np.floor((pixels[:, 0].max() + margin) / tile),
                              np.floor((pixels[:, 1].min() - margin) / tile), np.floor((pixels[:, 1].max() + margin) / tile))
        box[:, 0::2] = np.maximum(box[:, 0::2], 0)
        box[:, 1] = np.minimum(box[:, 1], tiles_x - 1)
        box[:, 3] = np.minimum(box[:, 3], tiles_y - 1)
        nonempty = ((box[:, 0] <= box[:, 1]) & (box[:, 2] <= box[:, 3])) | wide
        candidates, box, wide = candidates[nonempty], box[nonempty], wide[nonempty]
        if candidates.size == 0:
            return candidates, np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0, np.int64)
        # Quad-tile pairs of the boxes (quads seeing behind the lens: every tile, kept if in the box or beyond 90 deg).
        pair_box = box.copy()
        pair_box[wide] = (0, tiles_x - 1, 0, tiles_y - 1)
        owner, tile = _tiles_in_boxes(pair_box.astype(np.int64), tiles_x)
        if wide.any():
            col, row = tile % tiles_x, tile // tiles_x
            in_box = (col >= box[owner, 0]) & (col <= box[owner, 1]) & (row >= box[owner, 2]) & (row <= box[owner, 3])
            chosen = ~wide[owner] | in_box | rays.tile_beyond_90[tile]
            owner, tile = owner[chosen], tile[chosen]
        tile_axis = rays.tile_axis_f32[tile]
        # Sphere vs tile cone: angle(axis, centre) <= half_t + radius_q, as cos(angle) >= cos(sum).
        direction = (centre[candidates] / safe_distance[candidates, None]).astype(np.float32)[owner]
        cos_angle = _dot_rows(direction, tile_axis)
        total = rays.tile_half_angle_f32[tile] + angular_radius[candidates].astype(np.float32)[owner]
        keep = (cos_angle >= np.cos(np.minimum(total, np.float32(np.pi)))) | inside[candidates][owner]
        # Plane side: need a ray d of the tile with sign(d.n) == sign(o.n).
        side = np.sign(np.einsum("qk,qk->q", origin_c[candidates], normal_c[candidates]))
        facing = (side[:, None] * normal_c[candidates]).astype(np.float32)[owner]
        toward = _dot_rows(facing, tile_axis)
        keep &= toward > -rays.tile_sin_half[tile]
        owner, tile = owner[keep], tile[keep]
        # Cone faces: the rays that meet a quad form the cone over its four corners. A tile whose ray
        # cone lies wholly outside one face cannot see the quad; one wholly inside all four faces
        # sees it with every ray (its rays need no rectangle test, only the depth).
        facets = _quad_cone_facets(outline_c[candidates, ::_OUTLINE_SAMPLES], centre[candidates])
        facets[inside[candidates]] = 0.0  # camera within the bounding sphere: no test
        tile_axis, sin_half = rays.tile_axis_f32[tile], rays.tile_sin_half[tile]
        facing = np.stack([_dot_rows(facets[owner, face], tile_axis) for face in range(4)])  # (4, N)
        keep = facing.min(axis=0) >= -sin_half - np.float32(_FACET_MARGIN)
        interior = facing[:, keep].min(axis=0) >= sin_half[keep] + np.float32(_FACET_MARGIN)
        owner, tile = owner[keep], tile[keep]
        # Per quad its edge tiles first, then its interior ones (each part in increasing order).
        order = np.lexsort((tile, interior, owner))
        owner, tile = owner[order], tile[order]
        counts = np.bincount(owner, minlength=candidates.size)
        edges = np.bincount(owner[~interior[order]], minlength=candidates.size)
        seen = counts > 0
        return candidates[seen], tile, np.concatenate([[0], np.cumsum(counts[seen])]), edges[seen]

    def depth_pass(self, camera: Camera, T_world_camera: np.ndarray, extra: PreparedQuads | None = None) -> VisibilityBuffer:
        """Nearest hit per pixel (ray casting with a depth test), as a :class:`VisibilityBuffer`."""
        R_world_camera = np.asarray(T_world_camera[:3, :3], float)
        camera_position = np.asarray(T_world_camera[:3, 3], float)
        scene_quads = self.quads_near(camera_position)
        quads = scene_quads if extra is None else _concat_prepared(scene_quads, extra)
        rays = self.rays_of(camera)
        num_tiles, tile_pixels = rays.pixel_index.shape
        depth = np.full((num_tiles, tile_pixels), np.inf, np.float32)
        quad_id = np.full((num_tiles, tile_pixels), -1, np.int32)
        axes_c = np.zeros((0, 3, 3), np.float32)
        plane = np.zeros((0, 3))
        self.last_stats = {"candidates": 0, "quads_tested": 0, "ray_tests": 0}
        if len(quads):
            centre = _times(quads.centre - camera_position, R_world_camera)
            origin_c = _times(quads.origin - camera_position, R_world_camera)
            u_c, v_c, n_c = (_times(axis, R_world_camera) for axis in (quads.axis_u, quads.axis_v, quads.normal))
            steps = np.linspace(0.0, 1.0, _OUTLINE_SAMPLES, endpoint=False)
            w, h = quads.width[:, None, None], quads.height[:, None, None]
            along_u = steps[None, :, None] * w * u_c[:, None, :]
            along_v = steps[None, :, None] * h * v_c[:, None, :]
            o = origin_c[:, None, :]
            outline = np.concatenate([o + along_u, o + w * u_c[:, None, :] + along_v,
                                      o + h * v_c[:, None, :] + w * u_c[:, None, :] - along_u, o + h * v_c[:, None, :] - along_v], axis=1)
            candidates, candidate_tiles, tile_starts, edge_tiles = self._candidate_tiles(camera, rays, quads, centre, origin_c, n_c, outline)
            tile_starts, edge_tiles = tile_starts.tolist(), edge_tiles.tolist()
            nearest = np.linalg.norm(centre[candidates], axis=1) - quads.radius[candidates]
            order = np.argsort(nearest)
            axes_c = np.stack([n_c, u_c, v_c], axis=2).astype(np.float32)  # (Q, 3, 3): columns n, u, v
            frames = np.ascontiguousarray(np.transpose(axes_c, (0, 2, 1)))  # (Q, 3, 3): rows n, u, v
            normal_rows, u_rows, v_rows = frames[:, 0:1], frames[:, 1:2], frames[:, 2:3]  # (Q, 1, 3) each: n, u, v
            plane = np.einsum("qk,qkj->qj", origin_c, np.stack([n_c, u_c, v_c], axis=2))  # o.n, o.u, o.v
            plane_n = plane[:, 0].astype(np.float32)
            half_w, half_h = (0.5 * quads.width).astype(np.float32), (0.5 * quads.height).astype(np.float32)
            centre_u, centre_v = (plane[:, 1] + half_w).astype(np.float32), (plane[:, 2] + half_h).astype(np.float32)
            tile_far = np.full(num_tiles, np.inf, np.float32)  # farthest depth in each tile (occlusion culling)
            tested_quads = tested_pixels = 0
            batch_quads: list[int] = []
            batch_tiles: list[np.ndarray] = []

            def keep_nearer(tiles: np.ndarray, t: np.ndarray, ids: np.ndarray | np.int32, nearer: np.ndarray,
                            current: np.ndarray | None = None) -> None:
                """Write the hits ``t`` (and their quad ids) where ``nearer`` into the tiles' buffers
                (``current``: their depths, ``depth[tiles]``, if already gathered)."""
                current = depth[tiles] if current is None else current
                np.copyto(current, t, where=nearer)
                depth[tiles] = current
                tile_far[tiles] = current.max(axis=1)
                tile_ids = quad_id[tiles]
                np.copyto(tile_ids, ids, where=nearer)
                quad_id[tiles] = tile_ids

            def test_batch() -> None:
                """Ray tests of the batched small quads at once; per tile pixel the nearest hit wins."""
                if not batch_quads:
                    return
                pair_quad = np.repeat(np.array(batch_quads), [tiles.size for tiles in batch_tiles])
                pair_tile = np.concatenate(batch_tiles)
                batch_quads.clear()
                batch_tiles.clear()
                order_by_tile = np.argsort(pair_tile, kind="stable")
                pair_quad, pair_tile = pair_quad[order_by_tile], pair_tile[order_by_tile]
                along = np.matmul(rays.tile_rays[pair_tile], frames[pair_quad].transpose(0, 2, 1))  # (P, pixels, n u v)
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = plane_n[pair_quad, None] / along[..., 0]
                hit = (t > _MIN_HIT_DISTANCE) & (t < depth[pair_tile])
                hit &= np.abs(t * along[..., 1] - centre_u[pair_quad, None]) <= half_w[pair_quad, None]
                hit &= np.abs(t * along[..., 2] - centre_v[pair_quad, None]) <= half_h[pair_quad, None]
                if not hit.any():
                    return
                t = np.where(hit, t, np.float32(np.inf))
                first_of_tile = np.r_[True, pair_tile[1:] != pair_tile[:-1]]
                starts = np.flatnonzero(first_of_tile)
                nearest_t = np.minimum.reduceat(t, starts, axis=0)  # (tiles, pixels)
                winner = hit & (t == nearest_t[np.cumsum(first_of_tile) - 1])
                winner_id = np.maximum.reduceat(np.where(winner, pair_quad[:, None].astype(np.int32), np.int32(-1)), starts, axis=0)
                keep_nearer(pair_tile[starts], nearest_t, winner_id, winner_id >= 0)

            with np.errstate(divide="ignore", invalid="ignore"):  # rays parallel to a quad's plane
                for k in order:
                    q = int(candidates[k])
                    tiles = candidate_tiles[tile_starts[k]:tile_starts[k + 1]]
                    unoccluded = tile_far[tiles] > nearest[k]
                    tiles = tiles[unoccluded]
                    if tiles.size == 0:
                        continue
                    tested_quads += 1
                    tested_pixels += tiles.size * tile_pixels
                    if tiles.size <= _BATCH_MAX_TILES:
                        # Small quads (far away, thin): tested in batches, in order; a batch sees the
                        # depths of the quads before it (occlusion culling between batches only).
                        batch_quads.append(q)
                        batch_tiles.append(tiles)
                        if len(batch_quads) >= _BATCH_QUADS:
                            test_batch()
                        continue
                    test_batch()
                    # Ray components along the quad's normal (cv2.transform by its row); on the edge
                    # tiles (listed first) also along u and v for the rectangle test.
                    tile_rays = rays.tile_rays[tiles]
                    t = plane_n[q] / cv2.transform(tile_rays.reshape(-1, 1, 3), normal_rows[q]).reshape(tiles.size, tile_pixels)
                    current = depth[tiles]
                    hit = (t > _MIN_HIT_DISTANCE) & (t < current)
                    edges = int(np.count_nonzero(unoccluded[:edge_tiles[k]]))
                    if edges:
                        edge_rays = tile_rays[:edges].reshape(-1, 1, 3)
                        t_edge, hit_edge = t[:edges], hit[:edges]
                        for row, middle, half in ((u_rows[q], centre_u[q], half_w[q]), (v_rows[q], centre_v[q], half_h[q])):
                            along = cv2.transform(edge_rays, row).reshape(edges, tile_pixels)  # one row: contiguous output
                            hit_edge &= np.abs(t_edge * along - middle) <= half
                    if hit.any():
                        keep_nearer(tiles, t, np.int32(q), hit, current)
            test_batch()
            self.last_stats = {"candidates": int(candidates.size), "quads_tested": tested_quads, "ray_tests": tested_pixels}
        shape = (camera.height, camera.width)
        depth_image = _tiles_to_image(depth, rays, shape)
        id_image = _tiles_to_image(quad_id, rays, shape)
        relief = self._relief_in_view(camera, np.asarray(T_world_camera, float), depth_image, id_image, quads)
        shade = None
        if relief is not None:
            depth_image.ravel()[relief.pixels] = relief.depth
            shade = np.ones(shape, np.float32)
            shade.ravel()[relief.pixels] = relief.shade
        # Texture coordinates and incidence of the winning quad, per pixel, on whole-image arrays (sky
        # pixels use quad 0 at distance 0 and are ignored by the shading), from one gather of its
        # constants: the texture map composed with the surface coordinates is affine in the hit
        # point t d, s = t (d . S) + c_s with S = M00 u + M01 v.
        hit_image = id_image >= 0
        q = np.maximum(id_image, 0).astype(np.intp)
        t = np.where(hit_image, depth_image, np.float32(0.0))
        ray_x, ray_y, ray_z = rays.rays_planes
        surface_frame = np.zeros((max(len(quads), 1), 8))
        table = np.zeros((max(len(quads), 1), 11))
        if len(quads):
            u_c, v_c, n_c = (axes_c[:, :, column].astype(np.float64) for column in (1, 2, 0))
            const_a, const_b = quads.offset_a - plane[:, 1], quads.offset_b - plane[:, 2]  # a = t (d . u) + const_a
            surface_frame = np.concatenate([u_c, const_a[:, None], v_c, const_b[:, None]], axis=1)
            texture_map = quads.texture_map  # (Q, 2, 3)
            for row in range(2):
                table[:, 4 * row:4 * row + 3] = texture_map[:, row, 0:1] * u_c + texture_map[:, row, 1:2] * v_c
                table[:, 4 * row + 3] = texture_map[:, row, 0] * const_a + texture_map[:, row, 1] * const_b + texture_map[:, row, 2]
            table[:, 8:] = n_c
        column = np.take(np.ascontiguousarray(table.T.astype(np.float32)), q, axis=1)  # (11, H, W): contiguous planes
        texture_s = t * (ray_x * column[0] + ray_y * column[1] + ray_z * column[2]) + column[3]
        texture_t = t * (ray_x * column[4] + ray_y * column[5] + ray_z * column[6]) + column[7]
        cos_incidence = np.abs(ray_x * column[8] + ray_y * column[9] + ray_z * column[10])
        return VisibilityBuffer(depth_image, id_image, texture_s, texture_t, cos_incidence, quads, shade, surface_frame, rays.rays_planes)

    def _relief_in_view(self, camera: Camera, T_world_camera: np.ndarray, depth_image: np.ndarray,
                        id_image: np.ndarray, quads: PreparedQuads) -> ReliefHits | None:
        """:func:`relief_hits` for the scene's bumps within reach of the camera, on the pixels that
        see a horizontal quad within the bumps' footprint (:func:`relief_footprint`)."""
        R_world_camera, camera_position = T_world_camera[:3, :3], T_world_camera[:3, 3]
        bumps = [bump for bump in self.relief
                 if np.hypot(*(np.asarray(bump.center) - camera_position[:2])) < _RELIEF_RANGE_M + max(bump.length, bump.width)]
        if not bumps:
            return None
        footprint = relief_footprint(bumps, quads, camera, T_world_camera)
        if footprint is not None and not footprint.any():
            return None
        flat_ids = id_image.ravel()
        seen = (id_image >= 0) & (depth_image < _RELIEF_RANGE_M)
        pixels = np.flatnonzero(seen if footprint is None else seen & footprint)
        pixels = pixels[quads.horizontal[flat_ids[pixels]]]
        if pixels.size == 0:
            return None
        rays_world = (R_world_camera @ np.take(self.rays_of(camera).rays_planes.reshape(3, -1), pixels, axis=1).astype(np.float64)).T
        return relief_hits(bumps, camera_position, rays_world, depth_image.ravel()[pixels].astype(np.float64),
                           quads.normal[flat_ids[pixels]], pixels, self.options.shadow_darkness)

    # ------------------------------------------------------------------ shading
    def render_float(self, camera: Camera, T_world_camera: np.ndarray, extra_quads: Sequence[Quad] = ()) -> np.ndarray:
        """Noise-free image as float32 grey levels (H, W)."""
        return self._render_float_and_depth(camera, T_world_camera, extra_quads)[0]

    def render_with_depth(self, camera: Camera, T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(uint8 image (H, W), ray distance (H, W) float32, inf where the sky is seen)`` from one
        depth pass (ground truth for tracking checks, ``ampc_vo.tools.klt_survival``)."""
        image, depth = self._render_float_and_depth(camera, T_world_camera, ())
        return to_uint8(image), depth

    def radiance_and_depth(self, camera: Camera, T_world_camera: np.ndarray,
                           extra_quads: Sequence[Quad] | PreparedQuads | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free float32 grey levels (H, W) and ray distance (H, W; inf for the sky), with
        optional extra quads (traffic, the trailer body): what ``camera_effects.form_image`` warps."""
        return self._render_float_and_depth(camera, T_world_camera, extra_quads)

    def prepare_extra(self, extra_quads: Sequence[Quad]) -> PreparedQuads | None:
        """Extra per-frame quads prepared for :meth:`radiance_and_depth`."""
        return prepare_quads(extra_quads, self.atlas, self.options, seed_offset=10**6) if len(extra_quads) else None

    def moving_bodies(self, dynamic: Any, time: float, camera: Camera) -> PreparedQuads | None:
        """The faces of the moving bodies ``camera`` sees at ``time`` (``traffic.DynamicScene``),
        prepared once per body in its own frame and moved to its pose (the texture sticks to the body)."""
        moved = []
        for body in dynamic.visible_bodies(camera):
            key = (id(dynamic), body)
            if key not in self._bodies:  # the scene is kept with its entry: its id cannot be reused
                self._bodies[key] = (dynamic, prepare_quads(dynamic.faces[body], self.atlas, self.options, seed_offset=10**6 + body))
            moved.append(move_prepared(self._bodies[key][1], dynamic.poses(body, np.array([time]))[0]))
        if not moved:
            return None
        result = moved[0]
        for other in moved[1:]:
            result = _concat_prepared(result, other)
        return result

    def _render_float_and_depth(self, camera: Camera, T_world_camera: np.ndarray,
                                extra_quads: Sequence[Quad] | PreparedQuads | None) -> tuple[np.ndarray, np.ndarray]:
        extra = extra_quads if isinstance(extra_quads, PreparedQuads) or extra_quads is None else self.prepare_extra(extra_quads)
        visible = self.depth_pass(camera, T_world_camera, extra)
        quads = visible.quads
        rays = self.rays_of(camera)
        options = self.options
        atlas = self.atlas
        R_world_camera = np.asarray(T_world_camera[:3, :3], float)
        hit = visible.quad_id >= 0
        image = np.empty(hit.shape, np.float32)
        if hit.any():
            # Full-image arrays (sky pixels use quad 0, depth inf, and are overwritten below): no mask gathers.
            q = np.maximum(visible.quad_id, 0).astype(np.intp)
            t = visible.depth
            # Per-quad constants, gathered per pixel in one call (contiguous planes); the road's only on its pixels.
            constants = np.take(np.stack([atlas.size / quads.texture_scale, atlas.level_x[quads.texture_index] + (atlas.pad - 0.5),
                                          quads.gain]).astype(np.float32), q, axis=1)
            texels_per_m, texture_x, gain = constants
            incidence = np.maximum(visible.cos_incidence, np.float32(0.02))
            incidence = np.sqrt(incidence) if options.incidence_exponent == 0.5 else incidence ** np.float32(options.incidence_exponent)
            pixel_m = t * rays.pixel_angle
            footprint_m = pixel_m / incidence
            level = np.log2(np.maximum(footprint_m * texels_per_m, np.float32(1e-6)))
            if options.mip_bias:
                level += np.float32(options.mip_bias)
            np.clip(level, 0.0, atlas.num_levels - 1.0, out=level)
            level0 = level.astype(np.int32)
            fraction = level - level0.astype(np.float32)  # float32 (an int32 operand would make it float64)
            # Wrap once in level-0 texels: the wrapped coordinate of level l is that times 2^-l.
            # Texture rows grow downwards while b grows along axis_v (up on walls): flip t.
            size = np.float32(atlas.size)
            inv_size = np.float32(1.0 / atlas.size)
            s_texels = visible.texture_s * texels_per_m
            t_texels = visible.texture_t * -texels_per_m
            s_texels -= size * np.floor(s_texels * inv_size)
            t_texels -= size * np.floor(t_texels * inv_size)
            # Level l starts at row 2 S (1 - 2^-l) + 2 pad l of the atlas (build_atlas stacks levels),
            # so map_y = 2 S + pad - 0.5 + 2 pad l + (t - 2 S) 2^-l: no per-pixel table lookups.
            level_rows = (level0 * (2 * atlas.pad) + (2 * atlas.size)).astype(np.float32) + np.float32(atlas.pad - 0.5)
            level_scale = np.ldexp(np.float32(1.0), -np.arange(atlas.num_levels, dtype=np.int32))[level0]  # 2^-l: products exact
            map_x0 = s_texels * level_scale
            map_y0 = (t_texels - np.float32(2 * atlas.size)) * level_scale
            samples = []
            for scale, rows in ((np.float32(1.0), level_rows), (np.float32(0.5), level_rows + np.float32(2 * atlas.pad))):
                # The next level (l + 1) beyond the last one is sampled with weight fraction = 0 only.
                map_x, map_y = texture_x + scale * map_x0, rows + scale * map_y0
                samples.append(cv2.remap(atlas.image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
            surface = samples[0] + fraction * (samples[1] - samples[0])
            surface *= gain
            if visible.shade is not None:  # slopes of bumps and potholes
                surface *= visible.shade
            road = np.flatnonzero(hit & quads.road[q]) if quads.road.any() else np.zeros(0, np.intp)
            if road.size:
                road_quads = q.ravel()[road]
                coord_a, coord_b = visible.surface_coordinates(road)
                surface.ravel()[road] = _paint_markings(surface.ravel()[road], coord_a + quads.road_along[road_quads].astype(np.float32),
                                                        coord_b + quads.road_across[road_quads].astype(np.float32),
                                                        quads.road_width[road_quads].astype(np.float32), pixel_m.ravel()[road], footprint_m.ravel()[road])
            if self.shadows is not None:  # horizontal quads: texture coordinates are world (x, y)
                lit = self.shadows.sample(visible.texture_s, visible.texture_t)
                shade = np.float32(options.shadow_darkness) + np.float32(1.0 - options.shadow_darkness) * lit
                surface *= np.where(quads.horizontal[q], shade, np.float32(1.0))
            image = surface
        sky = ~hit
        if sky.any():  # brighter towards the horizon
            up = R_world_camera[2, :].astype(np.float32)  # world z of the rays
            planes = rays.rays_planes
            elevation = np.clip(planes[0][sky] * up[0] + planes[1][sky] * up[1] + planes[2][sky] * up[2], 0.0, 1.0)
            image[sky] = options.sky_horizon + (options.sky_zenith - options.sky_horizon) * np.sqrt(elevation)
        image[~rays.valid] = 0.0
        return image, visible.depth

    def render(self, camera: Camera, T_world_camera: np.ndarray, extra_quads: Sequence[Quad] = ()) -> np.ndarray:
        """uint8 grey image (H, W) of the scene seen by ``camera`` at ``T_world_camera``."""
        return to_uint8(self.render_float(camera, T_world_camera, extra_quads))


def to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def render_image(scene: Scene, camera: Camera, T_world_camera: np.ndarray,
                 textures: TextureAtlas | dict[str, np.ndarray] | None = None,
                 options: RenderOptions | None = None) -> np.ndarray:
    """One uint8 image of ``scene`` (convenience; use :class:`Renderer` for many frames)."""
    return Renderer(scene, textures, options).render(camera, T_world_camera)


# ---------------------------------------------------------------------- realism effects
def exposure_gain(options: RenderOptions, timestamp: float, camera_index: int) -> float:
    """Smooth exposure/gain change per camera: ``1 + 1.5 * amplitude * mean of three sines`` with
    random periods (2-12 s) and phases, a deterministic function of time (any frame order)."""
    if options.exposure_variation <= 0:
        return 1.0
    rng = np.random.default_rng([options.seed, 7919, camera_index])
    periods = rng.uniform(2.0, 12.0, 3)
    phases = rng.uniform(0, 2 * np.pi, 3)
    return float(1.0 + options.exposure_variation * np.mean(np.sin(2 * np.pi * timestamp / periods + phases)) * 1.5)


def apply_sensor_effects(image: np.ndarray, options: RenderOptions, timestamp: float, frame: int, camera_index: int) -> np.ndarray:
    """The render options' exposure variation and Gaussian noise (``sensor_noise_sigma``, seeded by
    frame and camera); returns uint8. The camera model of ``sim.camera_effects`` comes first."""
    image = image * np.float32(exposure_gain(options, timestamp, camera_index))
    if options.sensor_noise_sigma > 0:
        rng = np.random.default_rng([options.seed, frame, camera_index])
        image = image + rng.normal(0.0, options.sensor_noise_sigma, image.shape).astype(np.float32)
    return to_uint8(image)


def vehicle_pose(trajectory: Any, frame_time: float, options: RenderOptions) -> np.ndarray:
    """Pose of the moving vehicle: on the tractor's path, ``vehicle_lead_m`` ahead at t = 0, moving at
    ``vehicle_speed_mps`` along it and ``vehicle_lateral_m`` to the side (heading flipped if oncoming)."""
    positions = trajectory.T_world_tractor[:, :3, 3]
    steps = np.linalg.norm(np.diff(positions[:, :2], axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    s = options.vehicle_lead_m + options.vehicle_speed_mps * frame_time
    index = int(np.clip(np.searchsorted(arc, s) - 1, 0, len(arc) - 1))
    T = trajectory.T_world_tractor[index].copy()
    beyond = s - arc[index]  # straight extrapolation past the ends of the tractor's path
    T[:3, 3] = positions[index] + beyond * T[:3, 0] + T[:3, 1] * options.vehicle_lateral_m
    T[2, 3] = 0.0
    if options.vehicle_speed_mps < 0:
        T[:3, :2] = -T[:3, :2]
    return T


# ---------------------------------------------------------------------- sequences
_WORKER: dict[str, Any] = {}


@dataclass(frozen=True)
class SequenceJob:
    """What every frame of :func:`render_sequence` needs (sent once to each worker process)."""

    rig: Rig
    trajectory: Any                  # frames (timestamps) and, without pose_trajectory, the poses
    pose_trajectory: Any             # sampled at any time (sim.motion.sample_poses)
    capture_times: dict[str, np.ndarray]
    settings: tuple                  # CameraSettings per rig camera
    amplification: dict[str, np.ndarray]  # per camera (F,) exposure x gain (auto exposure)
    dynamic_scene: Any               # None or an object with quads_at(time, camera) -> list[Quad]
    out_dir: Path
    mount_vibration: dict[str, np.ndarray] | None = None  # per camera (N, 3, 3) over pose_trajectory's samples
    vignetting: dict[str, np.ndarray] | None = None  # per camera with vignetting (H, W) factor (camera_effects.vignetting_factor)


def _camera_pose_at(job: SequenceJob, camera: Camera):
    """``times -> T_world_camera``: the body pose at each time on the camera's vibrating mount
    (``sim.motion.camera_poses``, DESIGN 6)."""
    from ampc_vo.sim.motion import camera_poses, sample_poses, sample_rotations

    mount = (job.mount_vibration or {}).get(camera.name)

    def pose_at(times: np.ndarray) -> np.ndarray:
        times = np.asarray(times, float)
        R_mount = None if mount is None else sample_rotations(job.pose_trajectory.timestamps, mount, times)
        return camera_poses(sample_poses(job.pose_trajectory, camera.body, times), camera.T_body_camera, R_mount)
    return pose_at


def _extra_quads(renderer: Renderer, job: SequenceJob, camera: Camera, time: float) -> PreparedQuads | None:
    """Prepared moving quads at ``time``: the render options' moving vehicle and the job's moving bodies."""
    parts = []
    if renderer.options.moving_vehicle:
        parts.append(renderer.prepare_extra(vehicle_quads(vehicle_pose(job.trajectory, time, renderer.options))))
    if job.dynamic_scene is not None:
        parts.append(renderer.moving_bodies(job.dynamic_scene, time, camera))
    parts = [part for part in parts if part is not None]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else _concat_prepared(parts[0], parts[1])


def padded_camera(camera: Camera, margin: int) -> Camera:
    """The camera with ``margin`` more pixels on every side (same model, principal point shifted)."""
    if margin <= 0:
        return camera
    from ampc_vo.rig import replace_camera

    return replace_camera(camera, width=camera.width + 2 * margin, height=camera.height + 2 * margin,
                          cx=camera.cx + margin, cy=camera.cy + margin)


def render_frame_images(renderer: Renderer, job: SequenceJob, frame: int) -> dict[str, np.ndarray]:
    """uint8 images of every rig camera at one frame of a :class:`SequenceJob` (``camera_effects.form_image``
    with the camera's capture time, settings and metered exposure, then the render options' effects)."""
    from ampc_vo.sim.camera_effects import form_image

    options = renderer.options
    timestamp = float(job.trajectory.timestamps[frame])
    images = {}
    for camera_index, camera in enumerate(job.rig.cameras):
        settings = job.settings[camera_index]
        capture = float(job.capture_times[camera.name][frame])

        def render_with_depth(T_world_camera: np.ndarray, time: float, margin: int, camera=camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            padded = padded_camera(camera, margin)
            radiance, depth = renderer.radiance_and_depth(padded, T_world_camera, _extra_quads(renderer, job, camera, time))
            return radiance, depth, renderer.rays_of(padded).rays_planes

        vignetting = (job.vignetting or {}).get(camera.name)
        rng = np.random.default_rng([options.seed, frame, camera_index, 13])
        amplification = float(job.amplification[camera.name][frame]) if job.amplification else 1.0
        image, _ = form_image(camera, render_with_depth, _camera_pose_at(job, camera), capture, settings, amplification, rng, vignetting)
        images[camera.name] = apply_sensor_effects(image, options, timestamp, frame, camera_index)
    return images


def _render_frame(renderer: Renderer, job: SequenceJob, frame: int) -> None:
    for name, image in render_frame_images(renderer, job, frame).items():
        path = job.out_dir / "images" / name / f"{frame:06d}.png"
        cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, renderer.options.png_compression])


def _worker_init(renderer: Renderer, job: SequenceJob) -> None:
    cv2.setNumThreads(1)
    _WORKER.update(renderer=renderer, job=job)


def _worker_frame(frame: int) -> int:
    _render_frame(_WORKER["renderer"], _WORKER["job"], frame)
    return frame


def image_paths(rig: Rig, frame: int) -> list[str]:
    """Relative image paths of one frame, in rig camera order (``images/<camera>/<frame:06d>.png``)."""
    return [f"images/{camera.name}/{frame:06d}.png" for camera in rig.cameras]


_METER_SCALE = 8  # the auto-exposure meter renders at 1/8 of the resolution


_METER_INTERVAL_S = 0.2


def _meter_frames(times: np.ndarray) -> np.ndarray:
    """Indices of the frames the auto-exposure meter renders: the first, then each frame at least
    ``_METER_INTERVAL_S`` after the previous metered one, and the last."""
    if len(times) == 0:
        return np.zeros(0, np.int64)
    chosen, last = [], -np.inf
    for index, time in enumerate(times):
        if time - last >= _METER_INTERVAL_S - 1e-9:
            chosen.append(index)
            last = time
    if chosen[-1] != len(times) - 1:
        chosen.append(len(times) - 1)
    return np.array(chosen, np.int64)


def metered_amplification(renderer: Renderer, job: SequenceJob) -> dict[str, np.ndarray]:
    """Per camera (F,) exposure x gain from auto exposure (``camera_effects.auto_exposure``): the
    brightness is metered on 1/8-resolution renderings at the middle of the readout (with
    vignetting) every ``_METER_INTERVAL_S`` (interpolated between; the loop's time constant is longer),
    in frame order (the loop reacts to the previous frame)."""
    from ampc_vo.rig import replace_camera
    from ampc_vo.sim.camera_effects import auto_exposure, vignetting_factor

    result = {}
    frames = len(job.trajectory)
    for camera, settings in zip(job.rig.cameras, job.settings):
        if not settings.auto_exposure:
            result[camera.name] = np.ones(frames)
            continue
        scale = _METER_SCALE
        small = replace_camera(camera, width=max(camera.width // scale, 8), height=max(camera.height // scale, 6),
                               fx=camera.fx / scale, fy=camera.fy / scale, cx=(camera.cx + 0.5) / scale - 0.5, cy=(camera.cy + 0.5) / scale - 0.5)
        meter = vignetting_factor(renderer.rays_of(small).rays_planes[2], settings.vignetting)
        times = np.asarray(job.capture_times[camera.name], float) + 0.5 * camera.readout_time
        # Metered at most every _METER_INTERVAL_S (the loop's lag is longer), linear in time between.
        metered = _meter_frames(times)
        poses = _camera_pose_at(job, camera)(times[metered])
        brightness = np.array([float(np.mean(renderer.render_float(small, pose, _extra_quads(renderer, job, camera, float(time))) * meter))
                               for pose, time in zip(poses, times[metered])])
        result[camera.name] = auto_exposure(np.interp(times, times[metered], brightness), times, settings)
    return result


def sequence_job(renderer: Renderer, rig: Rig, trajectory: Any, out_dir: str | Path = ".", capture_times: dict[str, np.ndarray] | None = None,
                 camera_settings: Any = None, pose_trajectory: Any = None, dynamic_scene: Any = None,
                 mount_vibration: dict[str, np.ndarray] | None = None) -> SequenceJob:
    """Everything the frames of a sequence need (arguments as :func:`render_sequence`), with the
    auto exposure metered over the whole sequence (:func:`metered_amplification`) and each
    camera's vignetting factor (computed once)."""
    from ampc_vo.sim.camera_effects import vignetting_factor
    from ampc_vo.sim.camera_settings import CameraSettingsTable, settings_for

    options = renderer.options
    settings = settings_for(camera_settings or CameraSettingsTable(), rig.camera_names)
    if options.exposure_time_s > 0:  # the render options' blur applies to cameras without their own exposure
        settings = [dataclasses.replace(item, exposure_s=options.exposure_time_s, motion_blur_samples=options.motion_blur_samples)
                    if item.exposure_s == 0 else item for item in settings]
    frame_times = np.asarray(trajectory.timestamps, float)
    vignetting = {camera.name: vignetting_factor(renderer.rays_of(camera).rays_planes[2], item.vignetting)
                  for camera, item in zip(rig.cameras, settings) if item.vignetting > 0}
    job = SequenceJob(rig, trajectory, trajectory if pose_trajectory is None else pose_trajectory,
                      {camera.name: np.asarray((capture_times or {}).get(camera.name, frame_times), float) for camera in rig.cameras},
                      tuple(settings), {}, dynamic_scene, Path(out_dir), mount_vibration, vignetting)
    return dataclasses.replace(job, amplification=metered_amplification(renderer, job))


def render_sequence(out_dir: str | Path, rig: Rig, trajectory: Any, scene: Scene,
                    options: RenderOptions | None = None, progress: bool = True,
                    renderer: Renderer | None = None, capture_times: dict[str, np.ndarray] | None = None,
                    camera_settings: Any = None, pose_trajectory: Any = None, dynamic_scene: Any = None,
                    mount_vibration: dict[str, np.ndarray] | None = None) -> list[list[str]]:
    """Render every camera at every frame of ``trajectory`` into ``out_dir/images/<camera>/<frame:06d>.png``.

    ``trajectory`` needs ``timestamps`` (F,) and ``pose(body)`` -> (F, 4, 4) (``io.groundtruth.Trajectory``).
    Each camera's image is captured at its ``capture_times`` (default: the frame times) and formed
    by ``sim.camera_effects.form_image`` (rolling shutter, motion blur, auto exposure, vignetting,
    noise) with its settings from ``camera_settings`` (a ``CameraSettingsTable``; default: ideal);
    poses between samples are interpolated from ``pose_trajectory`` (default ``trajectory``), each
    camera on its vibrating mount where ``mount_vibration`` gives its rotations over those samples.
    ``dynamic_scene.quads_at(time, camera)`` adds moving quads (traffic, the trailer body).
    Frames are spread over ``options.processes`` worker processes (spawned: forking a process whose
    OpenCV thread pool has run deadlocks the children). Returns the relative image
    paths per frame (rig camera order), as ``frames.csv`` lists them.
    """
    options = options or RenderOptions()
    out_dir = Path(out_dir)
    for camera in rig.cameras:
        (out_dir / "images" / camera.name).mkdir(parents=True, exist_ok=True)
    renderer = renderer or Renderer(scene, None, options)
    for camera in rig.cameras:  # precompute rays once (the workers receive them with the renderer)
        renderer.rays_of(camera)
    job = sequence_job(renderer, rig, trajectory, out_dir, capture_times, camera_settings, pose_trajectory, dynamic_scene, mount_vibration)
    frames = range(len(trajectory))
    processes = max(1, min(options.processes, os.cpu_count() or 1, len(frames)))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(frames), desc="render", unit="frame")
    if processes == 1:
        for frame in frames:
            _render_frame(renderer, job, frame)
            if bar is not None:
                bar.update(1)
    else:
        context = multiprocessing.get_context("spawn")
        with context.Pool(processes, initializer=_worker_init, initargs=(renderer, job)) as pool:
            for _ in pool.imap_unordered(_worker_frame, frames, chunksize=4):
                if bar is not None:
                    bar.update(1)
    if bar is not None:
        bar.close()
    return [image_paths(rig, frame) for frame in frames]
