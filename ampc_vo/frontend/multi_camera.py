"""All cameras of the rig: one :class:`~ampc_vo.frontend.tracker.CameraTracker` per camera,
images in, :class:`~ampc_vo.observations.FrameObservations` out (DESIGN section 4)."""
from __future__ import annotations

import dataclasses
import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Iterator, Protocol

import numpy as np

from ampc_vo.config import StereoConfig, TrackerConfig
from ampc_vo.errors import ConfigError, DatasetError
from ampc_vo.io.frame_images import load_frame_images
from ampc_vo.observations import FrameObservations
from ampc_vo.rig import Rig
from ampc_vo.frontend.tracker import CameraTracker, TrackingReport
from ampc_vo.frontend.stereo import StereoMatches, match_stereo

logger = logging.getLogger(__name__)


@dataclass
class FrontendResult:
    """Observations of one frame plus per-camera reports and stereo matches (if configured)."""

    observations: FrameObservations
    reports: dict[str, TrackingReport]
    stereo: dict[tuple[str, str], "StereoMatches"] = field(default_factory=dict)


class MultiCameraFrontend:
    """One :class:`CameraTracker` per rig camera; images in, :class:`FrameObservations` out.

    ``stereo_pairs``: (first, second) camera names of overlapping views (KITTI: ("left", "right"))
    matched every frame with :func:`match_stereo`. ``threads`` > 1 tracks cameras in parallel
    (OpenCV releases the GIL).
    """

    def __init__(
        self,
        rig: Rig,
        config: TrackerConfig | None = None,
        camera_configs: dict[str, TrackerConfig] | None = None,
        stereo_pairs: tuple[tuple[str, str], ...] = (),
        stereo_config: "StereoConfig | None" = None,
        threads: int = 1,
    ) -> None:
        camera_configs = camera_configs or {}
        unknown = set(camera_configs) - set(rig.camera_names)
        if unknown:
            raise ConfigError(f"frontend: configs for unknown cameras {sorted(unknown)}; rig has {rig.camera_names}")
        for pair in stereo_pairs:
            for name in pair:
                if name not in rig.camera_names:
                    raise ConfigError(f"frontend: stereo pair {pair} names unknown camera {name!r}")
        self.rig = rig
        self.trackers = {camera.name: CameraTracker(camera, camera_configs.get(camera.name, config), road_z=rig.ground_z) for camera in rig.cameras}
        self.stereo_pairs = tuple(tuple(pair) for pair in stereo_pairs)
        self.stereo_config = stereo_config or StereoConfig()
        self._executor = ThreadPoolExecutor(max_workers=threads) if threads > 1 else None

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown()
            self._executor = None

    def __enter__(self) -> "MultiCameraFrontend":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def process_with_details(self, frame: int, timestamp: float, images: dict[str, np.ndarray | None],
                             camera_timestamps: dict[str, float] | None = None) -> FrontendResult:
        """Track every camera (a missing entry counts as a missing image) and match stereo pairs;
        ``camera_timestamps``: the capture time of each camera's image (default: ``timestamp``)."""
        unknown = set(images) - set(self.trackers)
        if unknown:
            raise DatasetError(f"frame {frame}: images for unknown cameras {sorted(unknown)}")
        names = list(self.trackers)
        if self._executor is not None:
            results = list(self._executor.map(lambda name: self.trackers[name].track(images.get(name)), names))
        else:
            results = [self.trackers[name].track(images.get(name)) for name in names]
        cameras = dict(zip(names, results))
        if camera_timestamps:
            cameras = {name: dataclasses.replace(observations, timestamp=float(camera_timestamps[name])) if name in camera_timestamps else observations
                       for name, observations in cameras.items()}
        stereo = {}
        for first, second in self.stereo_pairs:
            tracker_first, tracker_second = self.trackers[first], self.trackers[second]
            if len(cameras[first]) == 0 or tracker_second.previous_image is None or tracker_second.last_report.reinitialised:
                stereo[(first, second)] = StereoMatches.empty(second)
                continue
            stereo[(first, second)] = match_stereo(
                tracker_first.previous_image, tracker_second.previous_image, cameras[first],
                tracker_first.camera, tracker_second.camera, self.stereo_config,
            )
        reports = {name: self.trackers[name].last_report for name in names}
        return FrontendResult(FrameObservations(frame, float(timestamp), cameras), reports, stereo)

    def process(self, frame: int, timestamp: float, images: dict[str, np.ndarray | None],
                camera_timestamps: dict[str, float] | None = None) -> FrameObservations:
        """:meth:`process_with_details` without the details."""
        return self.process_with_details(frame, timestamp, images, camera_timestamps).observations


class ImageDataset(Protocol):
    """What :func:`track_dataset` needs: ``io.folder.Dataset`` and ``io.kitti.KittiDataset``."""

    timestamps: np.ndarray

    @property
    def camera_names(self) -> tuple[str, ...]: ...

    def __len__(self) -> int: ...

    def load_image(self, frame: int, camera: str) -> np.ndarray: ...


def track_dataset(dataset: ImageDataset, frontend: MultiCameraFrontend, start: int = 0, stop: int | None = None) -> Iterator[FrontendResult]:
    """Run ``frontend`` over the frames ``[start, stop)`` of an image dataset, one
    :class:`FrontendResult` per frame (``.observations`` is what the backend consumes)."""
    stop = len(dataset) if stop is None else min(stop, len(dataset))
    for frame in range(start, stop):
        yield frontend.process_with_details(frame, float(dataset.timestamps[frame]), load_frame_images(dataset, frame), camera_capture_times(dataset, frame))


def camera_capture_times(dataset: object, frame: int) -> dict[str, float] | None:
    """Per-camera capture times of one frame when the dataset has them (``camera_timestamps``)."""
    times = getattr(dataset, "camera_timestamps", None)
    return {name: float(values[frame]) for name, values in times.items()} if times else None


