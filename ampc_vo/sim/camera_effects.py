"""Image formation of one simulated camera: rolling shutter, motion blur, auto exposure, vignetting,
shot and read noise (issue 13; the renderer of ``sim.render`` supplies the noise-free radiance).

An image of camera ``c`` captured at ``t_c`` (``camera_timing``) is formed as:

1. **Rolling shutter** (rig.yaml ``readout_time``): row ``r`` shows the scene at
   ``t_c + readout r / (H - 1)`` (DESIGN 5). The image is rendered once, with the pose of the middle
   row, with depth; every surface point is then moved by the camera's motion (first order: the
   velocity at the middle row, :func:`camera_velocity`) to where the camera sees it at the time of the
   row it lands in (the fixed point of ``camera_timing``, here on a 4-pixel grid) and the image is
   warped accordingly (backward map by fixed-point inversion, ``cv2.remap``).
2. **Motion blur**: the mean of ``motion_blur_samples`` copies of that image shifted along each
   pixel's image velocity over the exposure, centred on the row time (the stated row time is the
   middle of its exposure, so a blurred point's centroid is where the measurement projects it).
3. **Vignetting**: the radiance is multiplied by ``1 - s (1 - cos^4 alpha)``, ``alpha`` the angle
   of the pixel's ray to the optical axis (the natural cos^4 fall-off; Ray, *Applied Photographic
   Optics*, 2002, ch. 17), ``s`` = ``vignetting``.
4. **Exposure and gain**: the signal is ``radiance x e x g`` with the relative exposure ``e <= 1``
   (1 = ``exposure_ms``) and the analogue gain ``g <= max_gain``; auto exposure (:func:`auto_exposure`)
   sets ``e g`` from the previous frame's brightness.
5. **Noise**: ``N = signal / 255 x full_well_e / g`` electrons collected; shot noise is Poisson in
   ``N`` (Gaussian with variance ``N``), read noise Gaussian with ``read_noise_e`` electrons; the
   grey level is ``(N + noise) x g x 255 / full_well_e``, clipped and rounded to uint8 (the photon
   transfer model of EMVA standard 1288, release 4.0, sec. 2). So the grey-level variance is
   ``(255 g / full_well_e) DN + (255 g read_noise_e / full_well_e)^2``.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable, Sequence

import cv2
import numpy as np

from ampc_vo.rig import Camera
from ampc_vo.sim.camera_settings import CameraSettings

__all__ = ["vignetting_factor", "auto_exposure", "split_amplification", "expose", "blur_offsets", "camera_velocity",
           "ImageFormation", "form_image"]

_MIN_EXPOSURE = 0.02  # shortest exposure relative to exposure_ms (auto exposure in bright light)


def vignetting_factor(cos_alpha: np.ndarray, strength: float) -> np.ndarray:
    """``1 - s (1 - cos^4 alpha)`` (float32, the shape of ``cos_alpha``: the z component of each
    pixel's unit ray; module docstring, step 3)."""
    cos_alpha = np.clip(np.asarray(cos_alpha, np.float32), 0.0, 1.0)
    return (1.0 - np.float32(strength) * (1.0 - cos_alpha**4)).astype(np.float32)


def auto_exposure(brightness: np.ndarray, times: np.ndarray, settings: CameraSettings) -> np.ndarray:
    """(F,) total amplification ``e g`` per frame from the unit-exposure mean brightness (F,).

    The loop aims the mean grey level at ``target_grey``: the wanted amplification of frame ``k``
    is ``A*_k = target / brightness_k``; the camera applies ``log A_k = log A_{k-1} + a (log A*_{k-1}
    - log A_{k-1})`` with ``a = 1 - exp(-dt / exposure_time_constant_s)``: it reacts to the previous
    frame, with a first-order lag (it enters a tunnel or shadow dark and recovers). Limits:
    ``_MIN_EXPOSURE <= A <= max_gain``. Without auto exposure: 1."""
    brightness = np.asarray(brightness, float)
    if not settings.auto_exposure or len(brightness) == 0:
        return np.ones(len(brightness))
    wanted = np.log(np.clip(settings.target_grey / np.maximum(brightness, 1e-3), _MIN_EXPOSURE, settings.max_gain))
    amplification = np.empty(len(brightness))
    amplification[0] = wanted[0]
    for k in range(1, len(brightness)):
        dt = max(float(times[k] - times[k - 1]), 0.0)
        rate = 1.0 - math.exp(-dt / settings.exposure_time_constant_s) if settings.exposure_time_constant_s > 0 else 1.0
        amplification[k] = amplification[k - 1] + rate * (wanted[k - 1] - amplification[k - 1])
    return np.exp(amplification)


def split_amplification(amplification: float, settings: CameraSettings) -> tuple[float, float]:
    """``(relative exposure e, gain g)`` with ``e g = amplification``: exposure first (up to 1), then gain."""
    exposure = float(np.clip(amplification, _MIN_EXPOSURE, 1.0))
    return exposure, float(np.clip(amplification / exposure, 1.0, settings.max_gain))


def expose(radiance: np.ndarray, amplification: float, settings: CameraSettings, rng: np.random.Generator,
           vignetting: np.ndarray | None = None) -> np.ndarray:
    """Float grey levels after vignetting, exposure, gain and shot/read noise (steps 3-5), not yet
    clipped or quantised."""
    exposure, gain = split_amplification(amplification, settings)
    signal = radiance * np.float32(exposure * gain)
    if vignetting is not None:
        signal = signal * vignetting
    if settings.full_well_e <= 0:
        return signal
    # Shot (variance N) and read noise (variance r^2) are independent Gaussians: one draw of variance N + r^2.
    levels_per_electron = np.float32(255.0 * gain / settings.full_well_e)
    variance = np.maximum(signal, 0.0) * levels_per_electron + np.float32(settings.read_noise_e**2) * levels_per_electron**2
    return signal + np.sqrt(variance) * rng.standard_normal(signal.shape, dtype=np.float32)


def blur_offsets(samples: int, exposure_s: float) -> np.ndarray:
    """Times of ``samples`` sub-exposures relative to the row time (centred, evenly spread)."""
    if samples <= 1 or exposure_s <= 0:
        return np.zeros(1)
    return ((np.arange(samples) + 0.5) / samples - 0.5) * exposure_s


def camera_velocity(pose_at: Callable[[np.ndarray], np.ndarray], time: float, step: float = 0.005) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The camera's pose ``T_world_camera`` at ``time`` and its linear and angular velocity ``(v,
    omega)`` in its own frame (central difference of ``T_world_camera``: ``T(time)^-1 T(time + dt)
    ~ exp(dt [v, omega])``), from one call of ``pose_at``."""
    middle, before, after = pose_at(np.array([time, time - step, time + step]))
    delta = np.linalg.solve(before, after)
    rotation = delta[:3, :3]
    angle = math.acos(float(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))
    axis = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]])
    omega = axis * (0.5 * angle / math.sin(angle) if angle > 1e-9 else 0.5) / (2 * step)
    velocity = middle[:3, :3].T @ (after[:3, 3] - before[:3, 3]) / (2 * step)
    return middle, velocity, omega


@dataclass(frozen=True)
class ImageFormation:
    """How one image was formed (for tests and reports)."""

    render_time: float           # the time of the rendered (middle-row) pose
    readout_time: float
    blur_samples: int
    exposure_s: float            # the actual exposure time of the image
    amplification: float
    max_shift_px: float          # largest rolling-shutter displacement in the image


_GRID_STEP = 4  # px between the points on which the motion field is computed exactly


def _point_motion(points: np.ndarray, finite: np.ndarray, velocity: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``omega x X + v`` (N, 3) for camera-frame points X: they change at minus this rate as the
    camera moves (directions to the sky, ``finite`` false, only rotate)."""
    return np.cross(omega, points) + np.where(finite[:, None], velocity, 0.0)


def _points_at(points: np.ndarray, motion: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Camera-frame points (N, 3) at ``dt`` (N,) after the rendered pose (first order in the motion:
    ``X(dt) = X - dt (omega x X + v)``, ``motion`` from :func:`_point_motion`)."""
    return points - dt[:, None] * motion


@functools.lru_cache(maxsize=4)
def _pixel_grids(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixel columns and rows (H, W) float32 and both divided by ``_GRID_STEP`` (the motion grid's
    coordinates); cached per image size, not to be written to."""
    columns, rows = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    grids = (columns, rows, columns / np.float32(_GRID_STEP), rows / np.float32(_GRID_STEP))
    for grid in grids:
        grid.flags.writeable = False
    return grids


WARP_MARGIN_PX = 16  # the warped image is rendered this much larger on every side (its sources near the edges)


def form_image(camera: Camera, render_with_depth: Callable[[np.ndarray, float, int], tuple[np.ndarray, np.ndarray, np.ndarray]],
               pose_at: Callable[[np.ndarray], np.ndarray], capture_time: float, settings: CameraSettings, amplification: float,
               rng: np.random.Generator, vignetting: np.ndarray | None = None) -> tuple[np.ndarray, ImageFormation]:
    """Float grey image (H, W) of one capture and how it was formed (module docstring, steps 1-5).

    ``render_with_depth(T_world_camera, time, margin) -> (radiance, ray distance (inf: sky), unit rays
    (3, ...))`` renders the scene (with the traffic at ``time``) for the camera enlarged by ``margin``
    pixels on every side (the principal point shifted by ``margin``); ``pose_at(times) -> (N, 4, 4)``.
    The image is rendered once, at the middle row's time, and warped: each
    surface point (from the depth) is moved with the camera's motion to where the camera sees it
    at its own row's time (rolling shutter) and along its image motion over the exposure (blur). The
    motion field is exact (fixed point, first order in the motion over the readout) on a 4-pixel
    grid and interpolated between: at depth edges the warp smears over a few pixels, and moving
    traffic is neither distorted nor blurred by its own motion.
    """
    exposure_relative, _ = split_amplification(amplification, settings)
    exposure_s = settings.exposure_s * exposure_relative
    readout = camera.readout_time
    middle = capture_time + 0.5 * readout
    samples = settings.motion_blur_samples if exposure_s > 0 else 1
    if readout <= 0 and samples <= 1:
        radiance = render_with_depth(pose_at(np.array([middle]))[0], middle, 0)[0]
        return expose(radiance, amplification, settings, rng, vignetting), ImageFormation(middle, readout, 1, exposure_s, amplification, 0.0)
    margin = WARP_MARGIN_PX
    T_middle, velocity, omega = camera_velocity(pose_at, middle)
    radiance, depth, rays = render_with_depth(T_middle, middle, margin)
    radiance = radiance.astype(np.float32, copy=False)  # cv2.remap interpolates float64 at 1/32 px steps, float32 exactly
    height, width = camera.height, camera.width
    # Exact motion field on a grid of pixels: rolling-shutter target and image velocity.
    grid_v, grid_u = np.mgrid[0:height:_GRID_STEP, 0:width:_GRID_STEP]
    distance = depth[grid_v + margin, grid_u + margin].astype(np.float64).ravel()
    finite = np.isfinite(distance)
    directions = rays[:, grid_v + margin, grid_u + margin].reshape(3, -1).T.astype(np.float64)
    points = directions * np.where(finite, distance, 1.0)[:, None]
    source = np.stack([grid_u.ravel(), grid_v.ravel()], axis=1).astype(np.float64)
    target = source.copy()
    dt = np.zeros(len(points))
    motion = _point_motion(points, finite, velocity, omega)
    if readout > 0:
        for _ in range(4):  # fixed point: the row a point lands in sets its time (camera_timing)
            dt = capture_time + readout * np.clip(target[:, 1], 0, height - 1) / (height - 1) - middle
            target, valid = camera.project(_points_at(points, motion, dt))
        target = np.where(valid[:, None] & np.isfinite(target), target, source)
    step = 1e-3
    ahead, valid_ahead = camera.project(_points_at(points, motion, dt + step))
    behind, valid_behind = camera.project(_points_at(points, motion, dt - step))
    image_velocity = np.where((valid_ahead & valid_behind)[:, None], (ahead - behind) / (2 * step), 0.0)
    shape = grid_u.shape

    columns, rows, coarse_u, coarse_v = _pixel_grids(width, height)

    # Shift and image velocity as one 4-channel field (cv2.remap is faster on 4 channels than on 2),
    # bilinear between the grid points (pixel k * step).
    motion_field = np.stack([target[:, 0] - source[:, 0], target[:, 1] - source[:, 1], image_velocity[:, 0], image_velocity[:, 1]],
                            axis=-1).reshape(*shape, 4).astype(np.float32)
    fields = cv2.remap(motion_field, coarse_u, coarse_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)   # (H, W, 4)
    # Backward map: the source pixel p of each target pixel q solves p + shift(p) = q.
    map_u, map_v = columns - fields[..., 0], rows - fields[..., 1]
    for _ in range(2):
        at = cv2.remap(fields, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        map_u, map_v = columns - at[..., 0], rows - at[..., 1]
    blur_px = float(np.max(np.hypot(image_velocity[:, 0], image_velocity[:, 1]))) * exposure_s if len(image_velocity) else 0.0
    samples = int(np.clip(math.ceil(blur_px), 1, samples))  # about one sample per pixel of blur
    offsets = blur_offsets(samples, exposure_s)
    if np.any(offsets):
        velocity_at = cv2.remap(fields, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[..., 2:]
        image = np.zeros((height, width), np.float32)
        for offset in offsets:  # the point seen at q at row time + offset came from p - velocity * offset
            image += cv2.remap(radiance, map_u + np.float32(margin) - velocity_at[..., 0] * np.float32(offset),
                               map_v + np.float32(margin) - velocity_at[..., 1] * np.float32(offset),
                               cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        image /= np.float32(len(offsets))
    else:  # no blur: the rolling-shutter warp only
        image = cv2.remap(radiance, map_u + np.float32(margin), map_v + np.float32(margin), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    max_shift = float(np.max(np.hypot(target[:, 0] - source[:, 0], target[:, 1] - source[:, 1]))) if len(target) else 0.0
    return expose(image, amplification, settings, rng, vignetting), ImageFormation(middle, readout, len(offsets), exposure_s, amplification, max_shift)


def mean_brightness(images: Sequence[np.ndarray]) -> float:
    """Mean grey level of images (the auto-exposure meter)."""
    return float(np.mean([np.mean(image) for image in images]))
