"""Image frontend: per-camera feature tracking to bearings (DESIGN section 4).

Per camera, :class:`CameraTracker` runs, for every new image:

1. validation of the image (dtype, shape; :class:`~ampc_vo.errors.DatasetError` on bad input) and a
   blank-frame test (an all-black or flat image gives empty observations and a re-initialisation);
1b. the lens's vignetting divided out (rig.yaml ``vignetting``, :func:`flat_field`): KLT assumes a
   patch keeps its grey levels, which a patch moving towards a darker corner does not. A camera
   whose calibration gives none has its fall-off fitted to the grey levels of its first
   ``vignetting_fit_pairs`` image pairs' inlier tracks (:mod:`ampc_vo.frontend.vignetting`), divided
   out from then on when it is at least ``vignetting_min_strength``;
2. KLT tracking (``cv2.calcOpticalFlowPyrLK``, image pyramids) of the previous features with a
   forward-backward check: a track survives if tracking it back lands within ``fb_threshold_px``
   of where it started (fisheye: it must also stay inside the valid image circle); an exposure
   change between the two images beyond ``exposure_min_change`` is measured on the first pass's
   tracks (:func:`~ampc_vo.frontend.vignetting.exposure_ratio`), and KLT runs again against the
   previous image rescaled by it;
2b. road tracks (inside :func:`road_pixel_mask`: rays that meet the calibrated road plane
   z = -hitch_height within ``plane_warp_range_m``) get a second KLT pass
   (:func:`plane_warped_tracks`): the previous image is warped by the frame-to-frame homography of
   the road fitted to the first pass (:func:`road_homography`), and KLT runs from the warped image,
   so the road patch no longer expands and shears between the two images. Translation-only KLT reads such a
   patch's flow short (the ground-plane scale then comes out short: motorway 25 m/s, a cab camera's
   road flow 0.86-0.97 of the truth); it also recovers the near road tracks that move too far for
   the first pass. Tracks the second pass loses keep the first pass's answer (vehicles, kerbs);
3. a sudden-jump test: if most tracks fail at once the camera re-initialises with new ids; then
   the aperture test (``flow_support``): a track whose window is an edge running along its image
   motion (gradient energy along the motion below ``aperture_ratio`` of the largest) is dropped,
   as KLT cannot measure the motion's length there and the track slides along the edge;
4. per-camera outlier rejection on **bearings** (so it works for pinhole and fisheye alike): RANSAC
   over essential matrices from 8 bearing pairs, scored with the Sampson residual on the sphere
   (equal to ``ampc_vo.epipolar.gec_sampson`` with the camera centre at the origin, i.e. paper
   eq. (1) for a single central camera);
5. grid-based replenishment: GFTT corners (``cv2.goodFeaturesToTrack`` on a 2x downscaled image,
   with a mask around existing features, only over the cells that need features) fill the grid
   cells that hold fewer than their share of features (corners only: structure tensor eigenvalue
   ratio ``corner_ratio`` at least ``aperture_ratio``); new features get new ids, unique per camera
   and never reused; crowded cells are thinned (oldest tracks kept) so features stay spread;
6. un-projection of the pixels to unit bearings with the rig's ``Camera.unproject``.

None of the work whose result goes unused is done, and what is done gives the same bits as doing it
all (the frontend's time budget, issue 7): the backward KLT pass runs only for the tracks the
forward pass kept, the aperture test reads only the patches of the tracks that moved and of the new
corners that can still be selected (:func:`select_per_cell` with a test), and the image-sized
arrays of the aperture test and the plane warp are reused from image to image
(:class:`ScratchArrays`: the page faults of fresh ones cost more than the filtering).

:class:`~ampc_vo.frontend.multi_camera.MultiCameraFrontend` runs one tracker per camera;
:mod:`ampc_vo.frontend.stereo` finds cross-camera correspondences of an overlapping pair.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from ampc_vo.config import StereoConfig, TrackerConfig
from ampc_vo.epipolar import ESSENTIAL_SAMPLE, essential_from_bearings, essential_sampson, sampled_essentials
from ampc_vo.errors import DatasetError
from ampc_vo.observations import CameraObservations
from ampc_vo.frontend.vignetting import VignettingFit, exposure_ratio
from ampc_vo.rig import Camera, replace_camera

logger = logging.getLogger(__name__)



@dataclass
class TrackingReport:
    """What one :meth:`CameraTracker.track` call did (for logs, benchmarks and the Rerun viewer)."""

    tracked: int = 0                 # tracks carried over from the previous frame
    lost: int = 0                    # tracks failing KLT / forward-backward / border tests
    edges: int = 0                   # tracks dropped by the aperture test (their patch became an edge)
    rejected: int = 0                # tracks removed by the epipolar RANSAC
    detected: int = 0                # new features
    reinitialised: str = ""          # reason if the camera re-initialised this frame ("blank", "jump", ...)
    rejected_pixels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    # detect, track, reject, unproject; and parts of track: klt (first pass), plane_warp (step 2b),
    # aperture (image gradients and the tracks' test; the new corners' test is part of detect)
    timings_ms: dict[str, float] = field(default_factory=dict)


@contextlib.contextmanager
def _timed(timings_ms: dict[str, float], key: str) -> Iterator[None]:
    """Add the wall time of the block (ms) to ``timings_ms[key]``."""
    start = time.perf_counter()
    try:
        yield
    finally:
        timings_ms[key] = timings_ms.get(key, 0.0) + (time.perf_counter() - start) * 1e3


# ---------------------------------------------------------------------- reused arrays
class ScratchArrays:
    """Arrays reused from one image to the next, by name: one set per :class:`CameraTracker` (not
    shared between threads).

    The aperture test and the plane warp fill image-sized arrays for every image. Allocated afresh,
    such an array is mapped page by page as it is first written, and the page faults took longer
    than the filtering that fills it (Scharr gradients of a 640x480 image on the loaded 2-core
    machine: 0.25 ms into reused arrays, 3.2 ms into freshly mapped ones; the demo's page faults
    per frame of four cameras fell from about 5000 to a few).
    """

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        """A C-contiguous array of ``shape`` and ``dtype`` (contents undefined) in the memory of the
        last one of that ``name``; a larger array (a quarter to spare) where it does not fit."""
        size = math.prod(shape)
        buffer = self._buffers.get(name)
        if buffer is None or buffer.size < size or buffer.dtype != dtype:
            buffer = np.empty(size + size // 4, dtype)
            self._buffers[name] = buffer
        return buffer[:size].reshape(shape)


def _work_array(scratch: ScratchArrays | None, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """``scratch``'s array of ``name`` (:meth:`ScratchArrays.get`), a new one without ``scratch``."""
    return np.empty(shape, dtype) if scratch is None else scratch.get(name, shape, dtype)



# ---------------------------------------------------------------------- image checks
def as_gray_image(image: object, camera: Camera | None = None, where: str = "image") -> np.ndarray:
    """A contiguous uint8 (H, W) view of ``image`` or :class:`DatasetError` with a clear message.

    Accepts uint8 grey (H, W), (H, W, 1), BGR (H, W, 3) or BGRA (H, W, 4); uint16 is scaled to 8 bits.
    If ``camera`` is given the size must match its calibration.
    """
    if not isinstance(image, np.ndarray):
        raise DatasetError(f"{where}: expected a numpy image array, got {type(image).__name__}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (3, 4)):
        raise DatasetError(f"{where}: expected an (H, W) grey or (H, W, 3|4) colour image, got shape {image.shape}")
    if image.shape[0] < 16 or image.shape[1] < 16:
        raise DatasetError(f"{where}: image of shape {image.shape} is too small to track features")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise DatasetError(f"{where}: expected a uint8 (or uint16) image, got dtype {image.dtype}")
    if camera is not None and (image.shape[1], image.shape[0]) != (camera.width, camera.height):
        raise DatasetError(
            f"{where}: image is {image.shape[1]}x{image.shape[0]} but camera {camera.name!r} is calibrated "
            f"for {camera.width}x{camera.height}"
        )
    if image.ndim == 3:
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    return np.ascontiguousarray(image)


def valid_pixel_mask(camera: Camera, margin_px: float = 4.0, step: int = 4) -> np.ndarray | None:
    """uint8 mask (255 = usable) of the pixels whose rays the camera model maps back to themselves
    (fisheye: inside the image circle, below the model's maximum incidence), eroded by ``margin_px``.
    ``None`` for an undistorted pinhole camera (every pixel is valid). Sampled every ``step`` px."""
    if camera.model == "pinhole" and not np.any(camera.distortion):
        return None
    columns, rows = np.arange(0, camera.width, step, dtype=float), np.arange(0, camera.height, step, dtype=float)
    grid = np.stack(np.meshgrid(columns, rows), axis=-1).reshape(-1, 2)
    with np.errstate(all="ignore"):
        bearings = camera.unproject(grid)
        finite = np.all(np.isfinite(bearings), axis=1)
        bearings[~finite] = [0.0, 0.0, 1.0]
        reprojected, valid = camera.project(bearings)
        valid &= finite & (np.linalg.norm(reprojected - grid, axis=1) < 0.5)
    coarse = (valid.reshape(len(rows), len(columns)) * 255).astype(np.uint8)
    mask = cv2.resize(coarse, (camera.width, camera.height), interpolation=cv2.INTER_NEAREST)
    radius = int(np.ceil(margin_px + step))
    return cv2.erode(mask, np.ones((2 * radius + 1, 2 * radius + 1), np.uint8))


def road_points(camera: Camera, pixels: np.ndarray, road_z: float) -> np.ndarray:
    """Body-frame points (N, 3) where the rays of ``pixels`` (N, 2) meet the road plane
    ``z = road_z`` of the camera's body frame (``-hitch_height``, DESIGN 1); NaN where a ray does
    not point down (or does not unproject)."""
    with np.errstate(all="ignore"):
        return road_points_of_rays(camera.unproject(pixels) @ camera.R_body_camera.T, camera.center, road_z)


def road_points_of_rays(rays: np.ndarray, centre: np.ndarray, road_z: float) -> np.ndarray:
    """Body-frame points (N, 3) where the body-frame rays (N, 3) from ``centre`` meet the road plane
    ``z = road_z``; NaN where a ray does not point down."""
    with np.errstate(all="ignore"):
        depth = np.where(rays[:, 2] < -1e-6, (road_z - centre[2]) / rays[:, 2], np.nan)
        return centre + depth[:, None] * rays


def road_pixel_mask(camera: Camera, road_z: float, max_range_m: float, step: int = 8) -> np.ndarray | None:
    """uint8 mask (255 = road) of the pixels whose ray meets the road plane ``z = road_z``
    (:func:`road_points`) at most ``max_range_m`` from the camera (horizontally), sampled every
    ``step`` px; ``None`` if no pixel sees the road there (the camera looks up, or sits less than
    0.2 m above the plane)."""
    if float(camera.center[2]) - road_z < 0.2:
        return None
    columns, rows = np.arange(0, camera.width, step, dtype=float), np.arange(0, camera.height, step, dtype=float)
    grid = np.stack(np.meshgrid(columns, rows), axis=-1).reshape(-1, 2)
    with np.errstate(invalid="ignore"):
        road = np.linalg.norm(road_points(camera, grid, road_z)[:, :2] - camera.center[:2], axis=1) <= max_range_m
    if not np.any(road):
        return None
    coarse = (road.reshape(len(rows), len(columns)) * 255).astype(np.uint8)
    return cv2.resize(coarse, (camera.width, camera.height), interpolation=cv2.INTER_NEAREST)


def flat_field(camera: Camera) -> np.ndarray | None:
    """The gain (H, W) float32 that divides a camera's vignetting out of its images (``1 /``
    :meth:`~ampc_vo.rig.Camera.relative_illumination`), or None for a camera without vignetting.

    KLT (``cv2.calcOpticalFlowPyrLK``) assumes a patch keeps its grey levels from one image to the
    next; under vignetting a patch that moves towards the image's edge darkens, and the window
    matches where the brightness, not only the texture, fits: the flow comes out biased, and so do
    everything the tracks measure. The realistic fast motorway (29 m/s, ``vignetting`` 0.6) on raw
    images: metric scale 1.011, ATE 0.35 % of the distance, the tractor cameras' yaw over a 15 degree
    curve 61 % of the truth (tractor_only); divided out: scale 1.0015, ATE 0.08 % (DESIGN 4)."""
    if camera.vignetting <= 0.0:
        return None
    return (1.0 / camera.relative_illumination(step=8)).astype(np.float32)  # smooth: sampled every 8 px (DESIGN 5)


def flat_field_corrected(gray: np.ndarray, gain: np.ndarray | None) -> np.ndarray:
    """``gray`` (uint8) times the :func:`flat_field` ``gain``, rounded and saturated to uint8
    (unchanged for None)."""
    return gray if gain is None else cv2.multiply(gray, gain, dtype=cv2.CV_8U)


def is_blank(gray: np.ndarray, min_contrast: float) -> bool:
    """True for an all-black, saturated or flat image (no trackable texture)."""
    small = gray[::4, ::4]
    return float(small.std()) < min_contrast


# ---------------------------------------------------------------------- KLT and grid helpers
def track_forward_backward(
    previous_image: np.ndarray,
    current_image: np.ndarray,
    previous_pixels: np.ndarray,
    config: "TrackerConfig | StereoConfig",
    image_size: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """KLT from the previous to the current image and back; returns ``(pixels (K, 2), good (K,))``.

    ``good`` is false for tracks that KLT lost in either direction, whose forward-backward error
    exceeds ``fb_threshold_px``, or that end within ``border_px`` of the border of the current
    image (``image_size``). Also the stereo matcher's KLT (``match_stereo``: from the first
    camera's image to the second's).

    KLT assumes a window keeps its grey levels; between two exposures it does not, and the window
    settles where brightness and texture fit together: a 3 % brighter second image reads a shift
    with a median error of 0.34 px against 0.025 px at equal exposure (tests/frontend/test_frontend.py).
    With ``exposure_compensation`` the exposure change of the first pass's tracks, where beyond
    ``exposure_min_change``, rescales the previous image, and KLT runs again against it
    (:func:`_exposure_compensated`; the backward pass then runs against it too). The realistic
    motorway's auto exposure changes by 0.1-0.2 % from one frame to the next (median), up to 0.8-3.2 %;
    KITTI's left and right cameras differ by 2-5 %.
    """
    if len(previous_pixels) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, config.lk_iterations, config.lk_epsilon)
    window = (config.lk_window, config.lk_window)
    start = np.ascontiguousarray(previous_pixels, dtype=np.float32).reshape(-1, 1, 2)
    ended, tracked = _klt_forward(previous_image, current_image, start, config)
    forward = ended.reshape(-1, 2).astype(float)
    good = tracked & _usable_ends(forward, image_size, config.border_px)
    if config.exposure_compensation and good.sum() >= _LEAST_EXPOSURE_TRACKS:
        previous_image, ended, tracked = _exposure_compensated(previous_image, current_image, start, ended, good, config)
        forward = ended.reshape(-1, 2).astype(float)
        good = tracked & _usable_ends(forward, image_size, config.border_px)
    if good.any():
        # The backward pass only for the tracks still in the running (KLT tracks every point on its
        # own, so theirs are the same); it starts at the original pixel, so a shallow pyramid
        # suffices (about half the cost).
        returning = start[good]
        backward, status_backward, _ = cv2.calcOpticalFlowPyrLK(
            current_image, previous_image, ended[good], returning.copy(), winSize=window, maxLevel=min(config.fb_levels, config.lk_levels),
            criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )
        fb_error = np.linalg.norm(backward.reshape(-1, 2) - returning.reshape(-1, 2), axis=1)
        good[good] = (status_backward.ravel() == 1) & (fb_error < config.fb_threshold_px)
    return forward, good


def _klt_forward(previous_image: np.ndarray, current_image: np.ndarray, start: np.ndarray,
                 config: "TrackerConfig | StereoConfig") -> tuple[np.ndarray, np.ndarray]:
    """KLT's forward pass of ``start`` (K, 1, 2) float32 with the config's window, pyramid and
    criteria: ``(ended (K, 1, 2), tracked (K,))``."""
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, config.lk_iterations, config.lk_epsilon)
    ended, status, _ = cv2.calcOpticalFlowPyrLK(previous_image, current_image, start, None, winSize=(config.lk_window, config.lk_window),
                                                maxLevel=config.lk_levels, criteria=criteria)
    return ended, status.ravel() == 1


def _usable_ends(pixels: np.ndarray, image_size: tuple[int, int], border: float) -> np.ndarray:
    """(K,) true where KLT's answer (K, 2) is finite and at least ``border`` px inside the image."""
    width, height = image_size
    inside = (pixels[:, 0] >= border) & (pixels[:, 0] <= width - 1 - border) & (pixels[:, 1] >= border) & (pixels[:, 1] <= height - 1 - border)
    return inside & np.all(np.isfinite(pixels), axis=1)


_LEAST_EXPOSURE_TRACKS = 8  # exposure_ratio: fewer tracks than this measure no exposure change
_EXPOSURE_ROUNDS = 2  # _exposure_compensated: at most this many rounds of measuring and tracking again


def _exposure_compensated(previous_image: np.ndarray, current_image: np.ndarray, start: np.ndarray, ended: np.ndarray, good: np.ndarray,
                          config: "TrackerConfig | StereoConfig") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KLT of ``start`` (K, 1, 2) run again against the previous image brought to the current image's
    exposure, where the first pass (``ended``, ``good``) shows an exposure change: returns
    ``(previous image, ended (K, 1, 2), tracked (K,))``, the inputs unchanged where it shows none.

    The exposure change g is measured (:func:`exposure_ratio`) at the first pass's tracks ``good``;
    beyond ``exposure_min_change`` (a change of the logarithm) the previous image is rescaled by it
    and KLT runs again for every track, lost ones included (a change of 20 % loses half of them and
    throws the rest by 1.6-2 px). KLT under an exposure change takes part of it up into the track's
    position, so the measure at the first pass's tracks reads a little short (2 % as 1.9 %); measured
    again at the new tracks, the rest is taken up in one more round when it is still beyond
    ``exposure_min_change`` (at most ``_EXPOSURE_ROUNDS`` rounds)."""
    tracked = good.copy()
    gain, original = 1.0, previous_image
    for _ in range(_EXPOSURE_ROUNDS):
        if tracked.sum() < _LEAST_EXPOSURE_TRACKS:
            break
        change = exposure_ratio(previous_image, current_image, start.reshape(-1, 2)[tracked], ended.reshape(-1, 2)[tracked])
        if abs(math.log(change)) <= config.exposure_min_change:
            break
        gain *= change
        previous_image = cv2.convertScaleAbs(original, alpha=gain)
        ended, tracked = _klt_forward(previous_image, current_image, start, config)
    return previous_image, ended, tracked


def plane_warped_tracks(
    previous_image: np.ndarray,
    current_image: np.ndarray,
    previous_pixels: np.ndarray,
    tracked: np.ndarray,
    good: np.ndarray,
    on_plane: np.ndarray,
    config: TrackerConfig,
    image_size: tuple[int, int],
    scratch: ScratchArrays | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Second KLT pass for the tracks of a plane (the road): returns ``(pixels (K, 2), good (K,))``.

    ``tracked``, ``good``: the first pass (:func:`track_forward_backward`) of ``previous_pixels``;
    ``on_plane`` (K,): the tracks in the plane's image region. The frame-to-frame homography ``H``
    of the plane is fitted to the first pass's good plane tracks (:func:`road_homography`: MAGSAC++,
    ``plane_warp_threshold_px``, passing over a plane that moves with the camera); KLT then runs
    from the previous image warped by ``H`` to the current image, starting at ``H p``
    (``plane_warp_levels`` pyramid levels: the prediction is close). In the warped image the plane's
    patches have the current image's scale and shear, so the translation-only window model of KLT
    holds (it reads an expanding patch's flow short otherwise). A plane track the second pass
    tracks replaces the first pass's answer, also where the first pass lost it (near road points at
    speed), if it lands within ``plane_warp_threshold_px`` of the homography refitted to the second
    pass (on the plane); one it loses or that lands off the plane keeps the first pass's answer (a
    vehicle on the road, or the road when a vehicle close ahead filled the region and gave the
    homography). Fewer than ``plane_warp_min_tracks`` good plane tracks or inliers: the first pass
    unchanged. ``scratch``: the warped image goes into its array (a tracker's :class:`ScratchArrays`).
    """
    fit = good & on_plane
    if fit.sum() < config.plane_warp_min_tracks:
        return tracked, good
    homography = road_homography(previous_pixels[fit].astype(np.float64), tracked[fit].astype(np.float64), config)
    if homography is None:
        return tracked, good
    plane = np.flatnonzero(on_plane)

    def moved(homography: np.ndarray) -> np.ndarray:
        return cv2.perspectiveTransform(previous_pixels[plane].reshape(-1, 1, 2).astype(np.float64), homography).reshape(-1, 2)

    predicted = moved(homography)
    width, height = image_size
    warped = cv2.warpPerspective(previous_image, homography, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE,
                                 dst=_work_array(scratch, "warped", previous_image.shape, previous_image.dtype))
    second_config = dataclasses.replace(config, lk_levels=min(config.plane_warp_levels, config.lk_levels))
    visible = np.all(np.isfinite(predicted), axis=1)
    visible &= (predicted[:, 0] >= 0) & (predicted[:, 0] <= width - 1) & (predicted[:, 1] >= 0) & (predicted[:, 1] <= height - 1)
    refined, refined_good = np.zeros((len(plane), 2)), np.zeros(len(plane), bool)
    if visible.any():
        refined[visible], refined_good[visible] = track_forward_backward(warped, current_image, predicted[visible], second_config, image_size)
    # the plane's tracks only: the homography refitted to the second pass (the first pass's tracks
    # were read short, so its homography misplaces the near ones by a few pixels), and a track off it
    # (a vehicle, when the road's is the fitted plane; the road, when a vehicle close ahead filled the
    # region) keeps the first pass's answer
    near = refined_good & (np.linalg.norm(refined - predicted, axis=1) <= 4.0 * config.plane_warp_threshold_px)
    if near.sum() >= config.plane_warp_min_tracks:
        refitted = _plane_fit(previous_pixels[plane[near]].astype(np.float64), refined[near].astype(np.float64), config.plane_warp_threshold_px, 0)
        if refitted is not None:
            predicted = moved(refitted[0])
    refined_good &= np.linalg.norm(refined - predicted, axis=1) <= config.plane_warp_threshold_px
    tracked, good = tracked.copy(), good.copy()
    tracked[plane[refined_good]] = refined[refined_good]
    good[plane[refined_good]] = True
    return tracked, good


_STREAMING_THRESHOLDS = 3.0  # road_homography: the rest of the road region "streams past" beyond this many thresholds


def road_homography(previous_pixels: np.ndarray, tracked: np.ndarray, config: TrackerConfig) -> np.ndarray | None:
    """The frame-to-frame homography of the road among the road region's first-pass tracks
    ``previous_pixels`` -> ``tracked`` (K, 2), or None (fewer than ``plane_warp_min_tracks``
    inliers). A robust fit (``plane_warp_threshold_px``) finds the largest plane, which is not
    always the road's. A surface moving with the camera covers the road region in some views: the trailer's
    side in a mirror camera (motorway: two thirds of the mirror's road-region tracks, flowing 1 px
    per frame against the road's 23 px), a vehicle keeping pace ahead. When the plane found barely
    moves (its inliers' median flow within the threshold) while the rest streams past (median flow
    beyond three thresholds), the road is the plane of the rest: fitted again on those.

    The fits are OpenCV's MAGSAC++ (``cv2.USAC_MAGSAC``; Barath et al., CVPR 2020): it scores and
    refines a model by weighting each track by its residual (marginalised over the noise scale up to
    the threshold) instead of counting the tracks within a hard threshold, so the near road tracks
    that the first pass read a few pixels short pull the fit less (realistic motorway on images: ATE
    0.63 -> 0.50 %, against plain RANSAC), at less cost (0.15 against 0.39 ms for 90 tracks)."""
    threshold, least = config.plane_warp_threshold_px, config.plane_warp_min_tracks
    largest = _plane_fit(previous_pixels, tracked, threshold, least)
    if largest is None:
        return None
    homography, inliers = largest
    rest = ~inliers
    if rest.sum() >= least:
        flow = np.linalg.norm(tracked - previous_pixels, axis=1)
        if np.median(flow[inliers]) <= threshold and np.median(flow[rest]) > _STREAMING_THRESHOLDS * threshold:
            streaming = _plane_fit(previous_pixels[rest], tracked[rest], threshold, least)
            return None if streaming is None else streaming[0]  # None: no plane streams past, the first pass stays
    return homography


def _plane_fit(previous_pixels: np.ndarray, tracked: np.ndarray, threshold: float, least: int) -> tuple[np.ndarray, np.ndarray] | None:
    """MAGSAC++ homography (:func:`road_homography`) of ``previous_pixels`` -> ``tracked`` and its
    inlier mask (K,), or None when it fails or has fewer than ``least`` inliers."""
    homography, inliers = cv2.findHomography(previous_pixels, tracked, cv2.USAC_MAGSAC, threshold)
    if homography is None or inliers is None or int(inliers.sum()) < least:
        return None
    return homography, inliers.ravel().astype(bool)


def image_gradients(gray: np.ndarray, scratch: ScratchArrays | None = None) -> np.ndarray:
    """Scharr gradients (H, W, 2) float32 of a grey image: the input of :func:`corner_ratio` and
    :func:`flow_support` (computed once per image); in ``scratch``'s arrays if given (the result
    then lives until the next call with the same ``scratch``)."""
    height, width = gray.shape
    image = _work_array(scratch, "float_image", (height, width), np.float32)
    np.copyto(image, gray, casting="unsafe")
    derivatives = [
        cv2.Scharr(image, cv2.CV_32F, dst=_work_array(scratch, name, (height, width), np.float32), dx=dx, dy=1 - dx)
        for name, dx in (("gradient_x", 1), ("gradient_y", 0))
    ]
    return cv2.merge(derivatives, dst=_work_array(scratch, "gradients", (height, width, 2), np.float32))


@functools.cache
def _window_offsets(window: int) -> tuple[np.ndarray, np.ndarray]:
    """x and y offsets (1, window * window) float32 of a ``window`` x ``window`` patch's pixels from
    its centre, row by row (read-only: shared by every call)."""
    offsets = np.arange(window, dtype=np.float32) - np.float32((window - 1) / 2)
    offset_y, offset_x = np.meshgrid(offsets, offsets, indexing="ij")
    shared = offset_x.reshape(1, -1).copy(), offset_y.reshape(1, -1).copy()
    for offsets_along in shared:
        offsets_along.flags.writeable = False
    return shared


def structure_tensors(gradients: np.ndarray, pixels: np.ndarray, window: int,
                      scratch: ScratchArrays | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel (N, 2), the structure tensor ``(gxx, gxy, gyy)`` (each (N,)) of the ``window`` x
    ``window`` patch around it (``gradients`` of :func:`image_gradients`, bilinear at sub-pixel
    positions); the patches in ``scratch``'s arrays if given. The float32 gradients are multiplied
    in float64 (exactly) and each sum runs over a contiguous row in patch order."""
    count, samples = len(pixels), window * window
    offset_x, offset_y = _window_offsets(window)
    points = np.asarray(pixels, np.float32)
    map_x = np.add(points[:, 0:1], offset_x, out=_work_array(scratch, "map_x", (count, samples), np.float32))
    map_y = np.add(points[:, 1:2], offset_y, out=_work_array(scratch, "map_y", (count, samples), np.float32))
    patch = cv2.remap(gradients, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE,
                      dst=_work_array(scratch, "patch", (count, samples, 2), np.float32))
    along_x, along_y, product = patch[..., 0], patch[..., 1], _work_array(scratch, "product", (count, samples), np.float64)
    gxx = np.multiply(along_x, along_x, out=product, dtype=np.float64).sum(1)
    gxy = np.multiply(along_x, along_y, out=product, dtype=np.float64).sum(1)
    gyy = np.multiply(along_y, along_y, out=product, dtype=np.float64).sum(1)
    return gxx, gxy, gyy


def _eigenvalues(gxx: np.ndarray, gxy: np.ndarray, gyy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smaller and larger eigenvalue of the symmetric 2x2 tensors ``[[gxx, gxy], [gxy, gyy]]``."""
    half_trace = 0.5 * (gxx + gyy)
    spread = np.sqrt(np.maximum(half_trace**2 - (gxx * gyy - gxy**2), 0.0))
    return half_trace - spread, half_trace + spread


def corner_ratio(gray: np.ndarray, pixels: np.ndarray, window: int, gradients: np.ndarray | None = None,
                 scratch: ScratchArrays | None = None) -> np.ndarray:
    """Per pixel (N, 2), the structure tensor of the ``window`` x ``window`` patch around it
    (Scharr gradients, bilinear at sub-pixel positions; ``gradients``: :func:`image_gradients` of
    ``gray`` if already computed; ``scratch``: as in :func:`structure_tensors`): its smaller
    eigenvalue over its larger, in [0, 1]; 0 for a flat patch. Near 0 is an edge (the aperture
    problem: KLT cannot measure the motion along it), near 1 a corner or isotropic texture (Shi and
    Tomasi, CVPR 1994)."""
    if len(pixels) == 0:
        return np.zeros(0)
    smallest, largest = _eigenvalues(*structure_tensors(image_gradients(gray) if gradients is None else gradients, pixels, window, scratch))
    return np.where(largest > 0, smallest / np.maximum(largest, 1e-12), 0.0)


def flow_support(gray: np.ndarray, pixels: np.ndarray, displacement: np.ndarray, window: int,
                 gradients: np.ndarray | None = None, scratch: ScratchArrays | None = None) -> np.ndarray:
    """Per pixel (N, 2) with its image motion ``displacement`` (N, 2): the gradient energy of its
    ``window`` patch along the motion over the largest along any direction (``d^T G d / |d|^2 /
    lambda_max`` of the structure tensor G; ``gradients``, ``scratch`` as in :func:`corner_ratio`),
    in [0, 1]; 1 where the motion is below a pixel (no direction to test). Near 0: the patch is an
    edge running along the motion (aperture problem: KLT cannot measure the motion's length there
    and the track slides along the edge). Only the patches of the pixels that moved are read (half
    the tracks of the realistic motorway's cameras move less than a pixel per frame)."""
    dx, dy = np.asarray(displacement, float).reshape(-1, 2).T
    squared = dx**2 + dy**2
    support = np.ones(len(squared))
    moving = squared >= 1.0
    if not moving.any():
        return support
    dx, dy, squared = dx[moving], dy[moving], squared[moving]
    gxx, gxy, gyy = structure_tensors(image_gradients(gray) if gradients is None else gradients, np.asarray(pixels)[moving], window, scratch)
    _, largest = _eigenvalues(gxx, gxy, gyy)
    along = (gxx * dx**2 + 2 * gxy * dx * dy + gyy * dy**2) / np.maximum(squared, 1e-12)
    support[moving] = along / np.maximum(largest, 1e-12)
    return support


def grid_cells(pixels: np.ndarray, image_size: tuple[int, int], rows: int, cols: int) -> np.ndarray:
    """Flat grid-cell index (K,) of each pixel for a ``rows`` x ``cols`` grid over the image."""
    width, height = image_size
    column = np.clip((pixels[:, 0] * cols / width).astype(int), 0, cols - 1)
    row = np.clip((pixels[:, 1] * rows / height).astype(int), 0, rows - 1)
    return row * cols + column


def select_per_cell(candidate_cells: np.ndarray, quota: np.ndarray,
                    passes: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Indices (ascending) of candidates to keep: the first ``quota[cell]`` candidates of each cell,
    in input order (GFTT returns corners by decreasing quality, so these are the best of each cell).

    With ``passes`` (candidate indices -> boolean mask), the first ``quota[cell]`` that pass it: it is
    asked about each cell's next candidates, as many as the cell still lacks, round after round, so
    the candidates behind a cell's quota are not tested (the aperture test of new corners: GFTT
    returned some 500 corners per camera frame on the demo for some 50 places).
    """
    if len(candidate_cells) == 0:
        return np.zeros(0, int)
    order = np.argsort(candidate_cells, kind="stable")
    sorted_cells = candidate_cells[order]
    rank = np.empty(len(order), int)  # each candidate's place among its cell's candidates
    rank[order] = np.arange(len(sorted_cells)) - np.searchsorted(sorted_cells, sorted_cells, side="left")
    if passes is None:
        return np.flatnonzero(rank < quota[candidate_cells])
    lacking, tested, kept = np.array(quota, int), np.zeros(len(quota), int), []
    while True:
        batch = np.flatnonzero((rank >= tested[candidate_cells]) & (rank < (tested + lacking)[candidate_cells]))
        if len(batch) == 0:
            return np.sort(np.concatenate(kept)) if kept else np.zeros(0, int)
        kept.append(batch[passes(batch)])
        tested += lacking
        lacking -= np.bincount(candidate_cells[kept[-1]], minlength=len(quota))


def detection_mask(pixels: np.ndarray, image_size: tuple[int, int], radius: float) -> np.ndarray:
    """uint8 mask (255 = free) blocking a neighbourhood of about ``radius`` around each pixel.

    Vectorised: pixels mark cells of side ``radius / 2`` on a coarse grid, dilated by one cell and
    scaled up to the image (blocked zone between radius/2 and 1.5 radius from a feature).
    """
    width, height = image_size
    cell = max(radius / 2.0, 1.0)
    coarse_w, coarse_h = int(np.ceil(width / cell)), int(np.ceil(height / cell))
    blocked = np.zeros((coarse_h, coarse_w), np.uint8)
    if len(pixels):
        ix = np.clip((pixels[:, 0] / cell).astype(int), 0, coarse_w - 1)
        iy = np.clip((pixels[:, 1] / cell).astype(int), 0, coarse_h - 1)
        blocked[iy, ix] = 1
        blocked = cv2.dilate(blocked, np.ones((3, 3), np.uint8))
    free = ((1 - blocked) * 255).astype(np.uint8)
    return cv2.resize(free, (width, height), interpolation=cv2.INTER_NEAREST)


# ---------------------------------------------------------------------- RANSAC on bearings
def epipolar_inliers(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    threshold_rad: float,
    iterations: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Boolean inlier mask (N,) of a RANSAC essential-matrix fit on unit bearings.

    Hypotheses come from random 8-point samples (all evaluated at once, vectorised); the score is
    the Sampson-normalised residual of paper eq. (1) with the camera at the origin
    (:func:`essential_sampson`, approximately radians). The best hypothesis is refitted on its
    inliers. Works for any central camera model because it never leaves the unit sphere.
    """
    count = len(bearings_i)
    if count < ESSENTIAL_SAMPLE + 1:
        return np.ones(count, bool)
    essentials = sampled_essentials(bearings_i, bearings_j, rng, iterations)
    inliers = np.abs(essential_sampson(essentials, bearings_i, bearings_j)) < threshold_rad  # (H, N)
    mask = inliers[int(np.argmax(inliers.sum(axis=1)))]
    if mask.sum() >= ESSENTIAL_SAMPLE:
        refined = essential_from_bearings(bearings_i[mask], bearings_j[mask])
        refined_mask = np.abs(essential_sampson(refined, bearings_i, bearings_j)) < threshold_rad
        if refined_mask.sum() >= mask.sum():
            mask = refined_mask
    return mask


# ---------------------------------------------------------------------- one camera
class CameraTracker:
    """KLT tracker of one camera: holds its last image, features and id counter (no globals)."""

    def __init__(self, camera: Camera, config: TrackerConfig | None = None, road_z: float | None = None) -> None:
        """``road_z``: the road plane's z in the camera's body frame (``Rig.ground_z``); with it and
        ``config.plane_warp`` the road tracks get the plane-warped second pass (None: no road known)."""
        self.camera = camera
        self.config = config or TrackerConfig()
        self._rng = np.random.default_rng(self.config.seed)
        self._next_id = 0
        self._pixels = np.zeros((0, 2))
        self._bearings = np.zeros((0, 3))
        self._ids = np.zeros(0, np.int64)
        self._empty_cells_after_detection = 0
        self._valid_mask = valid_pixel_mask(camera, self.config.border_px)
        self._flat_field = flat_field(camera)  # None without vignetting
        # no vignetting in the calibration: fitted to the first tracks (frontend/vignetting.py)
        self._vignetting_fit = (VignettingFit(camera, self.config.vignetting_fit_pairs)
                                if camera.vignetting <= 0.0 and self.config.vignetting_fit_pairs > 0 else None)
        self._road_mask = (road_pixel_mask(camera, road_z, self.config.plane_warp_range_m)
                           if road_z is not None and self.config.plane_warp else None)
        self.last_report = TrackingReport()
        self.previous_image: np.ndarray | None = None  # grey image of the last tracked frame (stereo, viz)
        self._scratch = ScratchArrays()  # the aperture test's and the plane warp's arrays, reused per image

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.camera.width, self.camera.height)

    @property
    def next_id(self) -> int:
        """The id the next new feature will get (ids are never reused)."""
        return self._next_id

    def reset(self, reason: str = "") -> None:
        """Forget all tracks (ids already issued stay retired)."""
        if reason:
            logger.warning("camera %s: re-initialising tracking (%s)", self.camera.name, reason)
        self.previous_image = None
        self._pixels = np.zeros((0, 2))
        self._bearings = np.zeros((0, 3))
        self._ids = np.zeros(0, np.int64)

    def _new_ids(self, count: int) -> np.ndarray:
        ids = np.arange(self._next_id, self._next_id + count, dtype=np.int64)
        self._next_id += count
        return ids

    def track(self, image: np.ndarray | None) -> CameraObservations:
        """Track features into ``image`` and return this frame's observations.

        ``None`` (a missing image) or a blank image gives empty observations, a warning and a
        re-initialisation at the next good image. Raises :class:`DatasetError` only for images of
        the wrong type or size.
        """
        config = self.config
        report = TrackingReport(timings_ms={"detect": 0.0, "track": 0.0, "reject": 0.0, "unproject": 0.0})
        self.last_report = report
        if image is None:
            report.reinitialised = "missing image"
            self.reset(report.reinitialised)
            return CameraObservations.empty(self.camera.name)
        gray = as_gray_image(image, self.camera, where=f"camera {self.camera.name}")
        if is_blank(gray, config.min_contrast):
            report.reinitialised = "blank image"
            self.reset(f"blank image (contrast below {config.min_contrast})")
            self.previous_image = gray
            return CameraObservations.empty(self.camera.name)

        clock = time.perf_counter()
        gray = flat_field_corrected(gray, self._flat_field)
        with _timed(report.timings_ms, "aperture"):
            gradients = image_gradients(gray, self._scratch) if config.aperture_ratio > 0 else None  # the aperture test's, once per image
        pixels, ids = np.zeros((0, 2)), np.zeros(0, np.int64)
        if self.previous_image is not None and len(self._pixels):
            with _timed(report.timings_ms, "klt"):
                tracked, good = track_forward_backward(self.previous_image, gray, self._pixels, config, self.image_size)
            if self._road_mask is not None:
                with _timed(report.timings_ms, "plane_warp"):
                    column, row = np.round(self._pixels).astype(int).T
                    on_road = self._road_mask[np.clip(row, 0, self.camera.height - 1), np.clip(column, 0, self.camera.width - 1)] > 0
                    tracked, good = plane_warped_tracks(self.previous_image, gray, self._pixels, tracked, good, on_road, config, self.image_size,
                                                        self._scratch)
            if self._valid_mask is not None:  # tracks that leave the image circle (fisheye) are lost
                inside = np.zeros(len(tracked), bool)
                column, row = np.round(tracked[good]).astype(int).T
                inside[good] = self._valid_mask[row, column] > 0
                good &= inside
            report.tracked, report.lost = int(good.sum()), int((~good).sum())
            if len(self._pixels) >= config.jump_min_tracks and good.sum() < config.jump_fraction * len(self._pixels):
                report.reinitialised = "jump"
                self.reset(f"sudden jump: only {int(good.sum())} of {len(self._pixels)} tracks survived")
                report.tracked = 0
            else:
                if gradients is not None:  # tracks on an edge along their motion would slide along it
                    corner = np.zeros(len(tracked), bool)
                    with _timed(report.timings_ms, "aperture"):
                        support = flow_support(gray, tracked[good], tracked[good] - self._pixels[good], config.lk_window, gradients, self._scratch)
                    corner[good] = support >= config.aperture_ratio
                    report.edges = int((good & ~corner).sum())
                    good &= corner
                pixels, ids = tracked[good], self._ids[good]
                previous_bearings, previous_pixels = self._bearings[good], self._pixels[good]
        report.timings_ms["track"] = (time.perf_counter() - clock) * 1e3

        clock = time.perf_counter()
        bearings = self.camera.unproject(pixels) if len(pixels) else np.zeros((0, 3))
        report.timings_ms["unproject"] += (time.perf_counter() - clock) * 1e3

        clock = time.perf_counter()
        stored = gray  # the image the next frame tracks from
        if len(pixels) >= config.min_tracks_for_ransac:
            threshold = config.ransac_threshold_px / max(self.camera.fx, self.camera.fy)
            inliers = epipolar_inliers(previous_bearings, bearings, threshold, config.ransac_iterations, self._rng)
            report.rejected = int((~inliers).sum())
            report.rejected_pixels = pixels[~inliers]
            pixels, ids, bearings, previous_pixels = pixels[inliers], ids[inliers], bearings[inliers], previous_pixels[inliers]
            fitting = self._vignetting_fit is not None and self._vignetting_fit.strength is None
            if fitting and self._fit_vignetting(previous_pixels, gray, pixels):
                stored = flat_field_corrected(gray, self._flat_field)  # tracked raw; the next frame's previous image without the fall-off
        if len(pixels):
            thinned = self._thin_crowded_cells(pixels, ids)
            pixels, ids, bearings = pixels[thinned], ids[thinned], bearings[thinned]
        report.timings_ms["reject"] = (time.perf_counter() - clock) * 1e3

        clock = time.perf_counter()
        if self._needs_features(pixels):
            new_pixels = self._detect(gray, pixels, gradients)
            report.detected = len(new_pixels)
            if len(new_pixels):
                pixels = np.concatenate([pixels, new_pixels])
                ids = np.concatenate([ids, self._new_ids(len(new_pixels))])
                report.timings_ms["detect"] = (time.perf_counter() - clock) * 1e3
                clock = time.perf_counter()
                bearings = np.concatenate([bearings, self.camera.unproject(new_pixels)])
                report.timings_ms["unproject"] += (time.perf_counter() - clock) * 1e3
            else:
                report.timings_ms["detect"] = (time.perf_counter() - clock) * 1e3
            self._empty_cells_after_detection = self._empty_cells(pixels)
        if len(pixels) == 0:
            logger.warning("camera %s: no features found in frame", self.camera.name)

        self._pixels, self._bearings, self._ids = pixels, bearings, ids
        self.previous_image = stored
        return CameraObservations(self.camera.name, ids.copy(), pixels.copy(), bearings)

    @property
    def vignetting(self) -> float:
        """The vignetting strength divided out of this camera's images: the calibrated one, the
        fitted one once fitted (0 when the fit stays below ``vignetting_min_strength``), else 0."""
        if self.camera.vignetting > 0.0:
            return self.camera.vignetting
        strength = self._vignetting_fit.strength if self._vignetting_fit is not None else None
        return strength if strength is not None and strength >= self.config.vignetting_min_strength else 0.0

    def _fit_vignetting(self, previous_pixels: np.ndarray, gray: np.ndarray, pixels: np.ndarray) -> bool:
        """Feed this frame's inlier tracks to the vignetting fit; True when it has just been fitted
        above ``vignetting_min_strength`` (``_flat_field`` then divides it out)."""
        strength = self._vignetting_fit.add(self.previous_image, previous_pixels, gray, pixels)
        if strength is None:
            return False
        if strength >= self.config.vignetting_min_strength:
            self._flat_field = flat_field(replace_camera(self.camera, vignetting=strength))
            logger.info("camera %s: vignetting fitted to %d tracks: strength %.2f, divided out from here on",
                        self.camera.name, self._vignetting_fit.tracks, strength)
            return True
        logger.info("camera %s: vignetting fitted to %d tracks: strength %.2f, below %.2f: left in the images",
                    self.camera.name, self._vignetting_fit.tracks, strength, self.config.vignetting_min_strength)
        return False

    def _thin_crowded_cells(self, pixels: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Indices (in input order) of the tracks to keep: at most ``max_per_cell_factor`` times a
        cell's share per cell, the oldest (lowest id) first, so features stay spread over the grid."""
        config = self.config
        cells = config.grid_rows * config.grid_cols
        cap = max(int(config.max_per_cell_factor * np.ceil(config.max_features / cells)), 1)
        by_age = np.argsort(ids, kind="stable")
        kept = select_per_cell(grid_cells(pixels[by_age], self.image_size, config.grid_rows, config.grid_cols), np.full(cells, cap))
        return np.sort(by_age[kept])

    def _empty_cells(self, pixels: np.ndarray) -> int:
        config = self.config
        cells = config.grid_rows * config.grid_cols
        if len(pixels) == 0:
            return cells
        return int(cells - np.count_nonzero(np.bincount(grid_cells(pixels, self.image_size, config.grid_rows, config.grid_cols), minlength=cells)))

    def _needs_features(self, pixels: np.ndarray) -> bool:
        """Replenish when fewer than ``replenish_ratio * max_features`` tracks remain, or when grid
        cells emptied since the last detection (cells without texture, e.g. sky, do not re-trigger)."""
        if len(pixels) < self.config.replenish_ratio * self.config.max_features:
            return True
        return self._empty_cells(pixels) > self._empty_cells_after_detection

    def _detect(self, gray: np.ndarray, existing: np.ndarray, gradients: np.ndarray | None = None) -> np.ndarray:
        """GFTT corners that fill under-populated grid cells (grid-based replenishment); with
        ``gradients`` (:func:`image_gradients` of ``gray``) only corners passing the aperture test."""
        config = self.config
        cells = config.grid_rows * config.grid_cols
        per_cell = int(np.ceil(config.max_features / cells))
        occupied = np.bincount(grid_cells(existing, self.image_size, config.grid_rows, config.grid_cols), minlength=cells) if len(existing) else np.zeros(cells, int)
        quota = np.maximum(per_cell - occupied, 0)
        # empty cells get their share even beyond max_features (by at most 10 %; crowded cells are
        # thinned in track(), so the total stays close to max_features)
        empty_share = int(np.count_nonzero(occupied == 0)) * per_cell
        budget = max(config.max_features - len(existing), min(empty_share, config.max_features // 10))
        if budget <= 0 or quota.sum() == 0:
            return np.zeros((0, 2))
        # Only the bounding box of the cells that need features is searched (GFTT's cost is per pixel).
        width, height = self.image_size
        needy_rows, needy_cols = np.nonzero(quota.reshape(config.grid_rows, config.grid_cols))
        x0 = int(needy_cols.min() * width / config.grid_cols)
        x1 = int(np.ceil((needy_cols.max() + 1) * width / config.grid_cols))
        y0 = int(needy_rows.min() * height / config.grid_rows)
        y1 = int(np.ceil((needy_rows.max() + 1) * height / config.grid_rows))
        mask = detection_mask(existing, self.image_size, config.min_distance_px)
        if self._valid_mask is not None:
            mask = cv2.bitwise_and(mask, self._valid_mask)
        mask = mask[y0:y1, x0:x1]
        region = gray[y0:y1, x0:x1]
        scale = config.detect_downscale
        for _ in range(scale // 2):  # each pyrDown halves the size (Gaussian-filtered)
            region = cv2.pyrDown(region)
        if scale > 1:
            mask = cv2.resize(mask, (region.shape[1], region.shape[0]), interpolation=cv2.INTER_NEAREST)
        corners = cv2.goodFeaturesToTrack(
            np.ascontiguousarray(region), maxCorners=int(min(4 * quota.sum(), 4 * config.max_features)),
            qualityLevel=config.quality_level, minDistance=config.min_distance_px / scale, mask=np.ascontiguousarray(mask),
            blockSize=config.block_size,
        )
        if corners is None:
            return np.zeros((0, 2))
        # pixel k of a 2x-downscaled image covers full-size pixels 2k and 2k+1 (centre 2k + 0.5)
        corners = corners.reshape(-1, 2).astype(float) * scale + (scale - 1) / 2.0 + [x0, y0]
        border = config.border_px
        inside = (corners[:, 0] >= border) & (corners[:, 0] <= width - 1 - border) & (corners[:, 1] >= border) & (corners[:, 1] <= height - 1 - border)
        corners = corners[inside]
        corner_cells = grid_cells(corners, self.image_size, config.grid_rows, config.grid_cols)

        def is_corner(candidates: np.ndarray) -> np.ndarray:  # the aperture test: no new features on edges
            return corner_ratio(gray, corners[candidates], config.lk_window, gradients, self._scratch) >= config.aperture_ratio

        keep = select_per_cell(corner_cells, quota, is_corner if gradients is not None else None)
        keep = keep[np.argsort(occupied[corner_cells[keep]] > 0, kind="stable")]  # empty cells first
        return corners[keep][:budget]
