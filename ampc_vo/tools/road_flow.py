"""How well KLT reads the road's flow: the frontend's plane-warped second pass against plain KLT.

One image of a camera that sees the road is warped by the exact road-plane motion of a forward
move of the body (the plane ``z = -hitch_height`` of DESIGN 1; every pixel whose ray meets it moves,
the rest stays), so the true flow of every road pixel is known and no renderer, traffic or shutter
effect is in the way. :func:`road_flow_ratios` tracks GFTT corners of the road region
(:func:`~ampc_vo.frontend.tracker.road_pixel_mask`) with plain KLT
(:func:`~ampc_vo.frontend.tracker.track_forward_backward`) and with the second pass
(:func:`~ampc_vo.frontend.tracker.plane_warped_tracks`), and returns each track's flow along the
true flow over the true flow's length (1 = right, < 1 = short) with the road point's distance
ahead. ``scripts/measure_road_flow.py`` prints them binned by distance.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ampc_vo.config import TrackerConfig
from ampc_vo.frontend.tracker import as_gray_image, plane_warped_tracks, road_pixel_mask, road_points, track_forward_backward
from ampc_vo.rig import Camera


@dataclass(frozen=True)
class RoadFlow:
    """Tracks of one warped image pair: distance of each road point along the body's x axis (m),
    true flow length (px) and, per tracker, the flow ratio (NaN where the tracker lost the track)."""

    distance_m: np.ndarray
    flow_px: np.ndarray
    plain_ratio: np.ndarray
    warped_ratio: np.ndarray


def warp_by_forward_move(camera: Camera, gray: np.ndarray, road_z: float, forward_m: float) -> np.ndarray:
    """``gray`` as the camera sees it after its body moved ``forward_m`` along x over a flat road
    (road pixels resampled bicubically from where their road point was; other pixels unchanged)."""
    columns, rows = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    pixels = np.column_stack([columns.ravel(), rows.ravel()])
    points_after = road_points(camera, pixels, road_z)
    points_before = points_after + [forward_m, 0.0, 0.0]
    with np.errstate(invalid="ignore"):
        source, visible = camera.project(np.nan_to_num((points_before - camera.center) @ camera.R_body_camera, nan=-1.0))
    use = visible & np.all(np.isfinite(points_after), axis=1)
    map_x = np.where(use, source[:, 0], pixels[:, 0]).reshape(camera.height, camera.width).astype(np.float32)
    map_y = np.where(use, source[:, 1], pixels[:, 1]).reshape(camera.height, camera.width).astype(np.float32)
    return cv2.remap(gray, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)


def road_flow_ratios(camera: Camera, image: np.ndarray, road_z: float, forward_m: float,
                     config: TrackerConfig = TrackerConfig(), max_corners: int = 600) -> RoadFlow:
    """Plain and plane-warped KLT on ``image`` and its :func:`warp_by_forward_move` (see module)."""
    first = as_gray_image(image, camera)
    second = warp_by_forward_move(camera, first, road_z, forward_m)
    mask = road_pixel_mask(camera, road_z, config.plane_warp_range_m)
    if mask is None:
        empty = np.zeros(0)
        return RoadFlow(empty, empty, empty, empty)
    corners = cv2.goodFeaturesToTrack(first, max_corners, 0.005, 6, mask=mask)
    corners = np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2).astype(float)
    points = road_points(camera, corners, road_z)
    truth, visible = camera.project(np.nan_to_num((points - [forward_m, 0.0, 0.0] - camera.center) @ camera.R_body_camera, nan=-1.0))
    size = (camera.width, camera.height)
    plain, plain_good = track_forward_backward(first, second, corners, config, size)
    warped, warped_good = plane_warped_tracks(first, second, corners, plain, plain_good, np.ones(len(corners), bool), config, size)
    flow = truth - corners
    length = np.linalg.norm(flow, axis=1)
    keep = visible & np.all(np.isfinite(points), axis=1) & (length > 1.0)

    def ratio(tracked: np.ndarray, good: np.ndarray) -> np.ndarray:
        value = np.sum((tracked - corners) * flow, axis=1) / np.maximum(length, 1e-9) ** 2
        return np.where(good, value, np.nan)[keep]

    return RoadFlow(points[keep, 0], length[keep], ratio(plain, plain_good), ratio(warped, warped_good))
