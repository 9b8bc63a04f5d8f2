"""Cross-camera correspondences of an overlapping camera pair (KITTI left/right), DESIGN section 4.

:func:`match_stereo` tracks the first camera's features into the second camera's image of the same
frame (KLT with a forward-backward check) and keeps matches whose generalized epipolar error with
the calibrated pair (paper eq. (1)) is small and whose triangulated depth is plausible; they feed the
two-camera epipolar factor (metric scale) and the stereo scale source (:mod:`ampc_vo.scale.stereo`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ampc_vo.config import StereoConfig
from ampc_vo.epipolar import gec_sampson
from ampc_vo.geometry import invert_pose, triangulate_midpoint
from ampc_vo.observations import CameraObservations, FrameObservations
from ampc_vo.rig import Camera
from ampc_vo.frontend.tracker import flat_field_corrected, CameraTracker, as_gray_image, is_blank, track_forward_backward

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class StereoMatches:
    """Cross-camera correspondences of one frame.

    ``observations`` is a :class:`CameraObservations` of the **second** camera whose ``track_ids``
    are the first camera's ids: ``match_tracks(first_obs_at_i, stereo_at_j.observations)`` pairs a
    first-camera bearing at frame i with a second-camera bearing at frame j for the two-camera
    GEC (metric scale). ``depths`` (K,) are triangulated depths along the first camera's ray.
    """

    observations: CameraObservations
    first_pixels: np.ndarray
    depths: np.ndarray

    def __len__(self) -> int:
        return len(self.observations)

    @staticmethod
    def empty(camera: str) -> "StereoMatches":
        return StereoMatches(CameraObservations.empty(camera), np.zeros((0, 2)), np.zeros(0))



def match_stereo(
    first_image: np.ndarray,
    second_image: np.ndarray,
    first: CameraObservations,
    first_camera: Camera,
    second_camera: Camera,
    config: StereoConfig | None = None,
) -> StereoMatches:
    """Find the first camera's features in the second (overlapping) camera's image of the same frame.

    KLT from the first to the second image (started at the same pixel, forward-backward checked,
    compensated for the two cameras' exposure difference, ``exposure_compensation``: KITTI's left
    and right images differ by 2-5 %), then two geometric tests with the known extrinsics
    ``T_first_second``: the Sampson GEC error (``gec_sampson`` with R, t of the camera pair, paper
    eq. (1)) below ``epipolar_threshold_px`` (for a rectified pair this is the same-row test) and a
    triangulated depth within ``[min_depth_m, max_depth_m]`` (cheirality). Images are uint8 grey of
    the same frame.
    """
    config = config or StereoConfig()
    if len(first) == 0:
        return StereoMatches.empty(second_camera.name)
    second_pixels, good = track_forward_backward(first_image, second_image, first.pixels, config, (second_camera.width, second_camera.height))
    if not good.any():
        return StereoMatches.empty(second_camera.name)
    second_bearings = second_camera.unproject(second_pixels[good])
    first_bearings = first.bearings[good]
    T_first_second = invert_pose(first_camera.T_body_camera) @ second_camera.T_body_camera
    focal = max(first_camera.fx, first_camera.fy)
    epipolar_error = np.abs(gec_sampson(first_bearings, second_bearings, T_first_second[:3, :3], T_first_second[:3, 3], np.zeros(3)))
    _, depth = triangulate_midpoint(first_bearings, second_bearings, T_first_second)
    accepted = (epipolar_error < config.epipolar_threshold_px / focal) & (depth >= config.min_depth_m) & (depth <= config.max_depth_m)
    index = np.flatnonzero(good)[accepted]
    observations = CameraObservations(second_camera.name, first.track_ids[index].copy(), second_pixels[index], second_bearings[accepted])
    return StereoMatches(observations, first.pixels[index].copy(), depth[accepted])


def match_stereo_image(tracker: CameraTracker, second_image: np.ndarray | None, first: CameraObservations, second_camera: Camera,
                       config: StereoConfig | None = None, second_flat_field: np.ndarray | None = None) -> StereoMatches:
    """:func:`match_stereo` of a tracked camera's current features into the raw image of a second,
    untracked camera of the same frame (the second camera of a stereo pair is not tracked on its
    own: its observations are the matches; ``second_flat_field``: its :func:`flat_field`, divided
    out as the tracker divides out the first camera's). A missing, blank or unusable second image gives no
    matches (logged); an image of the wrong size raises :class:`DatasetError`."""
    if second_image is None or tracker.previous_image is None or len(first) == 0:
        return StereoMatches.empty(second_camera.name)
    gray = as_gray_image(second_image, second_camera, where=f"camera {second_camera.name}")
    if is_blank(gray, tracker.config.min_contrast):
        logger.warning("camera %s: blank image, no stereo matches this frame", second_camera.name)
        return StereoMatches.empty(second_camera.name)
    return match_stereo(tracker.previous_image, flat_field_corrected(gray, second_flat_field), first, tracker.camera, second_camera, config)


def observations_with_stereo(observations: FrameObservations, stereo: dict[tuple[str, str], StereoMatches]) -> FrameObservations:
    """The frame's observations with cross-camera association (``landmark_ids``) from stereo matches.

    Each first camera of a pair gets ``landmark_ids`` = its track ids; each second camera's
    observations are the matches (:class:`StereoMatches`: the first camera's track ids) with the
    same ``landmark_ids``. So the second camera's "tracks" across frames are the first camera's
    tracks (intra-camera GEC of the second camera), and equal ids in the two cameras at any two
    frames are the same point (cross-camera GEC, two-camera form: metric scale).
    """
    cameras = dict(observations.cameras)
    for (first, second), matches in stereo.items():
        if first in cameras:
            own = cameras[first]
            cameras[first] = CameraObservations(own.camera, own.track_ids, own.pixels, own.bearings, own.track_ids.copy())
        matched = matches.observations
        cameras[second] = CameraObservations(second, matched.track_ids, matched.pixels, matched.bearings, matched.track_ids.copy())
    return FrameObservations(observations.frame, observations.timestamp, cameras)
