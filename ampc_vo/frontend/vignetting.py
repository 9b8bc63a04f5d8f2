"""A camera's vignetting measured from its own tracks, for cameras whose calibration gives none
(DESIGN 4, step 1b).

A static, matte scene point keeps its radiance from frame to frame; what changes its grey level
between two images is the exposure (one gain per image) and the lens: the share of light it passes
at the point's pixel, ``V(alpha) = 1 - s (1 - cos^4 alpha)`` (the fall-off model of
:meth:`ampc_vo.rig.Camera.relative_illumination`, ``alpha`` the ray's angle to the optical axis).
For a track from pixel ``p`` to ``p'`` the log ratio of its patch's mean grey levels is
``log I'(p') - log I(p) = e + log V_s(p') - log V_s(p) + noise`` with ``e`` the exposure change of
that image pair. Tracks moving towards the edge darken, tracks moving inwards brighten: over a few
dozen image pairs of any drive both occur, and the strength ``s`` is the one that explains them
(the per-pair exposure ``e`` is the mean of each pair's residuals). This is the radial part of
online photometric calibration (Bergmann, Wang, Cremers, "Online Photometric Calibration of Auto
Exposure Video for Realtime Visual Odometry and SLAM", RA-L 2018), with the fall-off constrained to
one parameter.

The same grey-level ratios of one image pair give its exposure change (:func:`exposure_ratio`),
which the tracker's KLT compensates (``tracker.track_forward_backward``): a cheaper sampled mean of
the same square, as it runs for every image pair.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ampc_vo.rig import Camera

_STRENGTHS = np.linspace(0.0, 0.95, 96)  # the strengths tried (the fit is a 1-D search)
_PATCH_PX = 47  # side of the box whose mean grey level a track carries: KLT places a track where its 15 px
                # window's grey levels fit best, which moves it to take up part of the fall-off; over a box this
                # much larger the mean hardly depends on that offset (fitted strength for a true 0.6, synthetic
                # texture: box 7 px 0.00, 15 px 0.29, 31 px 0.54, 47 px 0.58; realistic motorway 0.56-0.63)
_DARKEST, _BRIGHTEST = 12.0, 243.0  # patch means outside: clipped or too noisy in the log
_LEAST_MOTION_PX = 2.0  # image pairs whose tracks moved less (median) are not used
_TRIMMED_SHARE = 0.8   # the fit uses the 80 % of tracks the best strength explains best (moving objects, shadows, specular spots)


def box_means(gray: np.ndarray) -> np.ndarray:
    """Mean grey level (H, W) float32 of the ``_PATCH_PX`` square around every pixel."""
    return cv2.blur(gray.astype(np.float32), (_PATCH_PX, _PATCH_PX), borderType=cv2.BORDER_REPLICATE)


def patch_means(gray: np.ndarray, pixels: np.ndarray, box: np.ndarray | None = None) -> np.ndarray:
    """Mean grey level (N,) of the ``_PATCH_PX`` square around each pixel (N, 2), bilinear between
    pixels (``box``: :func:`box_means` of ``gray`` if already computed)."""
    box = box_means(gray) if box is None else box
    points = np.asarray(pixels, np.float32).reshape(-1, 1, 2)
    return cv2.remap(box, points[..., 0], points[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel().astype(float)


def fit_vignetting_strength(log_ratio: np.ndarray, cos4_before: np.ndarray, cos4_after: np.ndarray, pair: np.ndarray) -> float:
    """The strength ``s`` in [0, 0.95] (module docstring) that best explains tracks' log grey-level
    ratios ``log_ratio`` (N,) between their pixels' ``cos^4`` before and after (N,), ``pair`` (N,)
    the index of each track's image pair (its own exposure change): the trimmed least squares over
    a grid of strengths 0.01 apart."""
    pair = np.unique(np.asarray(pair), return_inverse=True)[1]
    counts = np.bincount(pair).astype(float)
    strengths = _STRENGTHS[:, None]
    residual = log_ratio[None] - (np.log1p(-strengths * (1.0 - cos4_after[None])) - np.log1p(-strengths * (1.0 - cos4_before[None])))
    exposure = np.stack([np.bincount(pair, row, minlength=len(counts)) for row in residual]) / counts
    squared = (residual - exposure[:, pair]) ** 2
    kept = int(max(1, _TRIMMED_SHARE * squared.shape[1]))
    cost = np.partition(squared, kept - 1, axis=1)[:, :kept].sum(axis=1)
    return float(_STRENGTHS[int(np.argmin(cost))])


@dataclass
class VignettingFit:
    """Collects one camera's track pairs (:meth:`add`) until ``pairs`` image pairs in motion have been seen,
    then gives the fitted strength (:attr:`strength`; None before). Used by the tracker of a camera
    whose calibration gives no vignetting."""

    camera: Camera
    pairs: int
    strength: float | None = None
    _log_ratio: list[np.ndarray] = field(default_factory=list)
    _cos4_before: list[np.ndarray] = field(default_factory=list)
    _cos4_after: list[np.ndarray] = field(default_factory=list)
    _last: tuple[np.ndarray, np.ndarray] | None = None  # the last image added and its box_means (the next pair's previous)

    @property
    def tracks(self) -> int:
        """Track pairs collected so far."""
        return int(sum(len(part) for part in self._log_ratio))

    def add(self, previous_gray: np.ndarray, previous_pixels: np.ndarray, gray: np.ndarray, pixels: np.ndarray) -> float | None:
        """Add the tracks from ``previous_pixels`` in ``previous_gray`` to ``pixels`` (N, 2) in
        ``gray`` (raw images: nothing divided out); returns the strength once fitted."""
        if self.strength is not None or len(pixels) == 0:
            return self.strength
        if np.median(np.linalg.norm(np.asarray(pixels) - np.asarray(previous_pixels), axis=1)) < _LEAST_MOTION_PX:
            return None  # at rest the tracks keep their pixels: no fall-off to see (a long standstill would fit noise)
        previous_box = self._last[1] if self._last is not None and self._last[0] is previous_gray else None
        box = box_means(gray)
        self._last = (gray, box)
        before, after = patch_means(previous_gray, previous_pixels, previous_box), patch_means(gray, pixels, box)
        usable = (before > _DARKEST) & (before < _BRIGHTEST) & (after > _DARKEST) & (after < _BRIGHTEST)
        if usable.sum() >= 10:  # a pair with fewer says little about its own exposure
            self._log_ratio.append(np.log(after[usable] / before[usable]))
            self._cos4_before.append(self.camera.cos4_off_axis(np.asarray(previous_pixels)[usable]))
            self._cos4_after.append(self.camera.cos4_off_axis(np.asarray(pixels)[usable]))
        if len(self._log_ratio) >= self.pairs:
            pair = np.concatenate([np.full(len(part), index) for index, part in enumerate(self._log_ratio)])
            self.strength = fit_vignetting_strength(np.concatenate(self._log_ratio), np.concatenate(self._cos4_before),
                                                    np.concatenate(self._cos4_after), pair)
            self._last = None
        return self.strength


_EXPOSURE_TRACKS = 100  # exposure_ratio: at most this many tracks (evenly spread over the list) measure it
_EXPOSURE_BOX_SAMPLES = 12  # exposure_ratio reads the _PATCH_PX square on this many samples a side
_DARKEST_MEAN, _BRIGHTEST_MEAN = 8.0, 240.0  # exposure_ratio: square means outside this range do not scale with the exposure


def window_means(gray: np.ndarray, pixels: np.ndarray, window: float, samples: int) -> np.ndarray:
    """Mean grey level (K,) of the ``window`` px square centred on each (sub-pixel) pixel (K, 2), read
    on a ``samples`` x ``samples`` grid spread over it, interpolated bilinearly; the border replicated."""
    offsets = np.linspace(-(window - 1) / 2.0, (window - 1) / 2.0, samples, dtype=np.float32)
    pixels = np.asarray(pixels, np.float32)
    columns = np.repeat(pixels[:, 0, None] + offsets, samples, axis=0).reshape(len(pixels), -1)  # (K, samples^2), rows of offsets
    rows = np.repeat(pixels[:, 1, None] + offsets, samples, axis=1).reshape(len(pixels), -1)
    patches = cv2.remap(gray, columns, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return patches.astype(np.float64).mean(axis=1)


def exposure_ratio(previous_image: np.ndarray, current_image: np.ndarray, previous_pixels: np.ndarray, current_pixels: np.ndarray) -> float:
    """The exposure change g between two images (current = g x previous in the grey levels) measured
    on tracks ``previous_pixels`` -> ``current_pixels`` (K, 2): the median over (at most
    ``_EXPOSURE_TRACKS`` of) the tracks of the ratio of the mean grey levels of a 47 px square around
    them (:func:`window_means`). The square is much larger than KLT's window because KLT, under an
    exposure change, takes part of it up into the track's position: over its own 15 px window a 2 %
    change reads as 0.9-1.6 %, over 47 px as 1.9-2.0 % (as for the fall-off above). The
    median passes over moving objects, occlusions and the squares that saturate or are nearly black
    (left out); 1.0 when no track is usable. One gain per image, as in the fall-off fit's model."""
    step = max(1, len(previous_pixels) // _EXPOSURE_TRACKS)
    before = window_means(previous_image, previous_pixels[::step], _PATCH_PX, _EXPOSURE_BOX_SAMPLES)
    after = window_means(current_image, current_pixels[::step], _PATCH_PX, _EXPOSURE_BOX_SAMPLES)
    usable = (before > _DARKEST_MEAN) & (after > _DARKEST_MEAN) & (before < _BRIGHTEST_MEAN) & (after < _BRIGHTEST_MEAN)
    if not usable.any():
        return 1.0
    return float(np.exp(np.median(np.log(after[usable] / before[usable]))))
