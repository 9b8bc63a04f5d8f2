"""Image formation of one simulated camera: rolling shutter, motion blur, auto exposure, vignetting,
shot and read noise (issue 13; the renderer of ``sim.render`` supplies the noise-free radiance).

An image of camera ``c`` captured at ``t_c`` (``camera_timing``) is formed as:

1. **Rolling shutter** (rig.yaml ``readout_time``): the image is split into bands of whole tiles;
   band ``b`` is rendered with the pose at the time of its centre row ``t_c + readout r_b / (H - 1)``
   (DESIGN 5). The number of bands follows the motion: the image motion over the readout,
   ``f (|rotation| + |translation| / near_depth)`` with ``near_depth`` the camera's height above
   the road, divided by ``band_tolerance_px`` (so that within a band the pose error moves no pixel by
   more than about that), at most one band per tile row.
2. **Motion blur**: each band is the mean of ``n`` renderings at times spread evenly over the
   exposure, centred on the row time (the stated row time is the middle of its exposure, so a blurred
   point's centroid is where the measurement projects it). ``n`` follows the motion over the
   exposure like the bands, at most ``motion_blur_samples``.
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

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ampc_vo.rig import Camera
from ampc_vo.sim.camera_settings import CameraSettings
from ampc_vo.sim.camera_timing import row_time

__all__ = ["vignetting_factor", "auto_exposure", "expose", "image_motion_px", "band_rows", "blur_offsets",
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
    electrons_per_level = settings.full_well_e / (255.0 * gain)
    electrons = np.maximum(signal, 0.0) * np.float32(electrons_per_level)
    noise = np.sqrt(electrons) * rng.standard_normal(electrons.shape, dtype=np.float32)
    if settings.read_noise_e > 0:
        noise += np.float32(settings.read_noise_e) * rng.standard_normal(electrons.shape, dtype=np.float32)
    return (electrons + noise) / np.float32(electrons_per_level)


def image_motion_px(camera: Camera, T_start: np.ndarray, T_end: np.ndarray, near_depth_m: float) -> float:
    """Largest image motion (pixels) between two camera poses for points at least ``near_depth_m``
    away: ``f (rotation angle + |translation| / near_depth)`` (small-motion bound)."""
    rotation = T_start[:3, :3].T @ T_end[:3, :3]
    angle = math.acos(float(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))
    shift = float(np.linalg.norm(T_end[:3, 3] - T_start[:3, 3]))
    return max(camera.fx, camera.fy) * (angle + shift / max(near_depth_m, 0.1))


def band_rows(height: int, tile: int, bands: int) -> list[tuple[int, int]]:
    """``bands`` row ranges of whole tiles covering ``height`` rows (fewer if there are fewer tile rows)."""
    tile_rows = -(-height // tile)
    bands = int(np.clip(bands, 1, tile_rows))
    edges = np.round(np.linspace(0, tile_rows, bands + 1)).astype(int) * tile
    return [(int(a), int(min(b, height))) for a, b in zip(edges[:-1], edges[1:]) if a < height]


def blur_offsets(samples: int, exposure_s: float) -> np.ndarray:
    """Times of ``samples`` sub-exposures relative to the row time (centred, evenly spread)."""
    if samples <= 1 or exposure_s <= 0:
        return np.zeros(1)
    return ((np.arange(samples) + 0.5) / samples - 0.5) * exposure_s


@dataclass(frozen=True)
class ImageFormation:
    """How one image is formed (the numbers an image's rendering used; for tests and reports)."""

    bands: list[tuple[int, int]]
    band_times: np.ndarray      # (B,) centre-row time of each band
    blur_samples: int
    exposure_s: float            # the actual exposure time of the image
    amplification: float


RenderRows = Callable[[np.ndarray, tuple[int, int], float], np.ndarray]  # (T_world_camera, rows, time) -> float32 rows


def form_image(camera: Camera, render_rows: RenderRows, pose_at: Callable[[np.ndarray], np.ndarray], capture_time: float,
               settings: CameraSettings, amplification: float, rng: np.random.Generator, tile: int = 16,
               near_depth_m: float = 2.0, band_tolerance_px: float = 1.5, vignetting: np.ndarray | None = None,
               ) -> tuple[np.ndarray, ImageFormation]:
    """Float grey image (H, W) of one capture (module docstring, steps 1-5) and how it was formed.

    ``render_rows(T_world_camera, rows, time)`` renders image rows ``rows`` seen from a pose at
    ``time`` (the time selects the traffic's positions); ``pose_at(times) -> (N, 4, 4)``."""
    exposure_relative, _ = split_amplification(amplification, settings)
    exposure_s = settings.exposure_s * exposure_relative
    if camera.readout_time > 0:
        ends = pose_at(np.array([capture_time, capture_time + camera.readout_time]))
        bands = band_rows(camera.height, tile, math.ceil(image_motion_px(camera, ends[0], ends[1], near_depth_m) / band_tolerance_px))
    else:
        bands = [(0, camera.height)]
    centre_rows = np.array([0.5 * (first + stop - 1) for first, stop in bands])
    band_times = row_time(camera, capture_time, centre_rows) if camera.readout_time > 0 else np.full(len(bands), float(capture_time))
    samples = 1
    if exposure_s > 0 and settings.motion_blur_samples > 1:
        ends = pose_at(np.array([band_times[0] - 0.5 * exposure_s, band_times[0] + 0.5 * exposure_s]))
        samples = int(np.clip(math.ceil(image_motion_px(camera, ends[0], ends[1], near_depth_m) / band_tolerance_px), 1, settings.motion_blur_samples))
    offsets = blur_offsets(samples, exposure_s)
    image = np.empty((camera.height, camera.width), np.float32)
    for (first, stop), band_time in zip(bands, band_times):
        times = band_time + offsets
        poses = pose_at(times)
        accumulated = None
        for T_world_camera, time in zip(poses, times):
            part = render_rows(T_world_camera, (first, stop), float(time))
            accumulated = part if accumulated is None else accumulated + part
        image[first:stop] = accumulated / np.float32(len(times))
    formed = expose(image, amplification, settings, rng, vignetting)
    return formed, ImageFormation(bands, band_times, samples, exposure_s, amplification)


def mean_brightness(images: Sequence[np.ndarray]) -> float:
    """Mean grey level of images (the auto-exposure meter)."""
    return float(np.mean([np.mean(image) for image in images]))
