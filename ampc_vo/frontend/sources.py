"""Measurement sources: a dataset folder opened as one stream of frames for the pipeline (issue 7).

One pipeline, two sources of the same measurements (DESIGN section 4): every source yields
:class:`FrameStep`\\ s whose ``observations`` (:class:`FrameObservations`) are all the backend
sees. Which source a folder gets:

- a KITTI odometry folder (``calib.txt`` and left/right image folders, recognised by its files):
  the image frontend on the rigid two-camera rig (:func:`stereo_image_steps`): the left camera is
  tracked, its features are matched into the right image every frame, and both cameras carry them
  as ``landmark_ids`` (cross-camera correspondences keep metric scale on the nearly straight clip:
  the smoother's two-camera GEC and the stereo chord of :mod:`ampc_vo.scale.stereo`). Its default
  config is ``configs/vo/kitti.yaml`` (:func:`default_config_path`); ground truth is compared in
  the left-camera frame (``T_body_reference``, ``GroundTruth.T_tractor_reference``);
- our dataset folder (DESIGN section 5) with images: the image frontend on every rig camera;
- our dataset folder with ``measurements.npz`` and no images (or ``source: bearings``): the
  simulator's bearing measurements replayed;
- a recording (a ROS 1 ``.bag``, a ROS 2 bag folder or an ``.mcap`` file, ``ampc_vo.io.bags``) with
  a rig whose cameras name their topics: the image frontend on its frames (:func:`_open_log`).

Every source carries the wheel speed named by ``scale.wheel_speed_source`` (a log topic or CSV) or
the folder's ``wheel_speed.csv`` (``Sequence.wheel_speed``, ``ampc_vo.io.wheel_speed``).

The config key ``source`` (``auto`` | ``images`` | ``bearings``) forces a choice; a forced source
the folder cannot provide is a :class:`DatasetError` that says what is missing.
"""
from __future__ import annotations

import dataclasses
import functools
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

import numpy as np

from ampc_vo.config import VoConfig
from ampc_vo.io.frame_images import FrameImageReader
from ampc_vo.errors import DatasetError
from ampc_vo.frontend.multi_camera import camera_capture_times, FrontendResult, MultiCameraFrontend
from ampc_vo.frontend.stereo import match_stereo_image, observations_with_stereo
from ampc_vo.frontend.tracker import flat_field
from ampc_vo.observations import FrameObservations
from ampc_vo.rig import Rig, replace_camera
from ampc_vo.frontend.worker import WorkerStartError, stream_in_process

if TYPE_CHECKING:  # evaluation (evo, SciPy) is not imported by the frontend's worker process
    from ampc_vo.io.groundtruth import GroundTruth
    from ampc_vo.io.wheel_speed import WheelSpeed

logger = logging.getLogger(__name__)


@dataclass
class FrameStep:
    """One frame of a source: the observations, and for image sources the images and the
    frontend's details (per-camera reports with rejected features, stereo matches)."""

    observations: FrameObservations
    images: dict[str, np.ndarray | None] | None = None
    frontend: FrontendResult | None = None
    # time spent producing it (waiting for its images, read while the previous frame was tracked, + the
    # frontend), for the timing breakdown
    seconds: float | None = None


@dataclass
class Sequence:
    """An opened dataset: its rig, frame times, ground truth (if any) and a frame stream.

    ``kind``: ``"bearings"``, ``"images"`` or ``"kitti"``. ``steps()`` starts the stream from the
    first frame (each call starts over, with fresh trackers); ``steps(images=False)``: the steps
    without their images (``FrameStep.images`` None), for a consumer that does not show them: a
    frontend process then sends only its small results (1.2 MB less per frame of four 640x480
    cameras). ``T_body_reference``: the frame in which the ground truth is compared (identity: the
    body; KITTI: the left camera).
    """

    path: Path
    kind: str
    rig: Rig
    timestamps: np.ndarray
    truth: GroundTruth | None
    steps: Callable[..., Iterator[FrameStep]]  # steps(images: bool = True)
    T_body_reference: np.ndarray = field(default_factory=lambda: np.eye(4))
    wheel_speed: WheelSpeed | None = None  # rear-axle speed samples (scale.wheel_speed_source)

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])


def _pipelined(frames: range, produce: Callable[[int], FrameStep], in_thread: bool) -> Iterator[FrameStep]:
    """``produce(frame)`` for every frame of ``frames`` in order; with ``in_thread`` the next frame is produced
    (tracked, its images read ahead by a :class:`FrameImageReader`: OpenCV releases the GIL) in a worker
    thread while the caller runs the backend on this one. The frontend's state is only touched by that
    one worker, in frame order."""
    if not in_thread:
        for frame in frames:
            yield produce(frame)
        return
    with ThreadPoolExecutor(max_workers=1) as worker:
        upcoming = worker.submit(produce, frames[0]) if len(frames) else None
        for position in range(len(frames)):
            step = upcoming.result()
            upcoming = worker.submit(produce, frames[position + 1]) if position + 1 < len(frames) else None
            yield step


def _frontend_stream(make_steps: Callable[..., Iterator[FrameStep]], dataset: object, rig: Rig, config: VoConfig,
                     *more: object, images: bool = True) -> Iterator[FrameStep]:
    """``make_steps(dataset, rig, config, *more)`` (``more``: the frames, then any stereo pairs), in
    a worker process when ``config.frontend_worker`` is ``process`` (:func:`ampc_vo.frontend.worker.stream_in_process`: the
    frontend then shares no GIL with the backend). The simulated bearings a dataset may carry
    stay here (the frontend does not need them). Without ``images`` each step's images are dropped
    where it is produced (:func:`_without_images`; in a worker process before it is sent)."""
    if not images:
        make_steps = functools.partial(_without_images, make_steps)
    if config.frontend_worker != "process":
        return make_steps(dataset, rig, config, *more)
    if dataclasses.is_dataclass(dataset) and getattr(dataset, "measurements", None) is not None:
        dataset = dataclasses.replace(dataset, measurements=None)
    return _in_process_or_thread(make_steps, dataset, rig, config, more)


def _without_images(make_steps: Callable[..., Iterator[FrameStep]], *args: object) -> Iterator[FrameStep]:
    """The steps of ``make_steps(*args)`` without their images (in a frontend worker process: not
    pickled across to the consumer)."""
    for step in make_steps(*args):
        yield dataclasses.replace(step, images=None)


def _in_process_or_thread(make_steps: Callable[..., Iterator[FrameStep]], dataset: object, rig: Rig, config: VoConfig,
                          more: tuple) -> Iterator[FrameStep]:
    """The frontend stream in a worker process; where none can be started (no ``/dev/shm`` in a
    container, ...) in a worker thread, with a warning."""
    stream = stream_in_process(make_steps, (dataset, rig, dataclasses.replace(config, frontend_worker="none"), *more))
    try:
        first = next(stream)
    except WorkerStartError as error:
        logger.warning("%s; the frontend runs in a thread instead (slower: frontend_worker thread)", error)
        yield from make_steps(dataset, rig, dataclasses.replace(config, frontend_worker="thread"), *more)
        return
    except StopIteration:
        return
    yield first
    yield from stream


def image_steps(dataset: object, rig: Rig, config: VoConfig, frames: range,
                stereo_pairs: tuple[tuple[str, str], ...] = ()) -> Iterator[FrameStep]:
    """The image frontend over the ``frames`` of ``dataset`` (``camera_names``,
    ``timestamps``, ``load_image``); a missing or corrupt image is logged and that camera re-initialises. With
    ``config.threads`` > 1 cameras are tracked in parallel, and decoded in parallel; the next frame's
    images are read while this one is tracked (:class:`FrameImageReader`); with
    ``config.frontend_worker`` thread the next frame is tracked while the backend works on this one
    (:func:`_pipelined`; for ``process`` see :func:`_frontend_stream`)."""
    with (MultiCameraFrontend(rig, config.frontend, stereo_pairs=stereo_pairs, stereo_config=config.stereo, threads=config.threads) as frontend,
          FrameImageReader(dataset, frames, config.threads) as reader):

        def produce(frame: int) -> FrameStep:
            started = time.perf_counter()
            read = reader.take(frame)
            result = frontend.process_with_details(frame, float(dataset.timestamps[frame]), read.images, camera_capture_times(dataset, frame))
            return FrameStep(result.observations, read.images, result, time.perf_counter() - started)

        yield from _pipelined(frames, produce, config.frontend_worker == "thread")


def stereo_image_steps(dataset: object, rig: Rig, config: VoConfig, frames: range,
                       stereo_pairs: tuple[tuple[str, str], ...]) -> Iterator[FrameStep]:
    """The image frontend over the ``frames`` of a rig with overlapping pairs
    (KITTI): the first camera of each pair
    (and any camera in no pair) is tracked; the second camera is not tracked on its own, its
    observations are the first camera's features found in its image (:func:`match_stereo_image`),
    with the first camera's track ids; both carry ``landmark_ids`` = those ids
    (:func:`observations_with_stereo`), the cross-camera association the smoother's two-camera GEC
    and :mod:`ampc_vo.scale.stereo` use. About half the tracking cost of tracking both cameras."""
    seconds = {second for _, second in stereo_pairs}
    flat_fields = {second: flat_field(rig.camera(second)) for second in seconds}
    tracked = dataclasses.replace(rig, cameras=tuple(camera for camera in rig.cameras if camera.name not in seconds))
    with MultiCameraFrontend(tracked, config.frontend, threads=config.threads) as frontend, FrameImageReader(dataset, frames, config.threads) as reader:

        def produce(frame: int) -> FrameStep:
            started = time.perf_counter()
            images = reader.take(frame).images
            result = frontend.process_with_details(frame, float(dataset.timestamps[frame]), {name: images.get(name) for name in frontend.trackers},
                                                   camera_capture_times(dataset, frame))
            stereo = {}
            for first, second in stereo_pairs:
                tracker = frontend.trackers[first]
                if flat_fields[second] is None and tracker.vignetting > 0.0:
                    # the pair's second camera has the first's lens: its fitted fall-off (frontend/vignetting.py)
                    flat_fields[second] = flat_field(replace_camera(rig.camera(second), vignetting=tracker.vignetting))
                stereo[(first, second)] = match_stereo_image(tracker, images.get(second), result.observations.cameras[first],
                                                             rig.camera(second), config.stereo, flat_fields[second])
            observations = observations_with_stereo(result.observations, stereo)
            return FrameStep(observations, images, FrontendResult(observations, result.reports, stereo), time.perf_counter() - started)

        yield from _pipelined(frames, produce, config.frontend_worker == "thread")


def _bearing_steps(measurements: object, rig: Rig, frames: range) -> Iterator[FrameStep]:
    for frame in frames:
        yield FrameStep(measurements.observations(frame, rig))


def frame_selection(count: int, start: int = 0, stop: int | None = None, where: str = "dataset") -> range:
    """The frames ``[start, stop)`` of a dataset of ``count`` frames (``stop`` beyond the end: to the
    end; ``None``: all); :class:`DatasetError` when the selection is empty or negative."""
    stop = count if stop is None else min(stop, count)
    if start < 0 or stop < 0:
        raise DatasetError(f"{where}: frame numbers start at 0, got start {start}, stop {stop}")
    if start >= stop:
        raise DatasetError(f"{where}: no frames selected: start {start}, stop {stop} (the dataset has frames 0 to {count - 1})")
    return range(start, stop)


KITTI_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "vo" / "kitti.yaml"


def default_config_path(path: str | Path | None) -> Path | None:
    """The VO config a dataset folder runs with when none is given: ``configs/vo/kitti.yaml`` for a
    KITTI folder (car at 10 Hz, stereo scale), else ``None`` (the built-in defaults,
    ``configs/vo/default.yaml``). ``None`` too when the file is not there (installed package)."""
    if path is None:
        return None
    from ampc_vo.io.kitti import is_kitti_folder

    if Path(path).is_dir() and is_kitti_folder(path) and KITTI_CONFIG.is_file():
        return KITTI_CONFIG
    return None


def open_sequence(path: str | Path, config: VoConfig, start: int = 0, stop: int | None = None,
                  rig: Rig | str | Path | None = None, progress: bool | None = None,
                  dropped_cameras: tuple[str, ...] = ()) -> Sequence:
    """Open a dataset folder, KITTI folder or recording as a :class:`Sequence` (module docstring)
    of its frames ``[start, stop)`` (default: all; frames keep their numbers, the ground truth stays
    whole). ``rig`` (a :class:`Rig` or a rig.yaml path) is needed for a recording, whose cameras it
    names by topic; ``progress``: a progress bar over a long recording's index pass;
    ``dropped_cameras``: rig cameras to run without (:func:`without_cameras`)."""
    from ampc_vo.io.bags import is_log
    from ampc_vo.io.wheel_speed import load_wheel_speed

    if is_log(path):
        sequence = _open_log(Path(path), config, start, stop, rig, progress)
    else:
        if rig is not None:
            logger.warning("%s: --rig is for recordings; a folder runs with its own rig.yaml (the rig given is ignored)", path)
        sequence = _open_folder(path, config, start, stop)
    if dropped_cameras:
        sequence = without_cameras(sequence, dropped_cameras)
    wheel_speed = load_wheel_speed(config.scale.wheel_speed_source, path)
    if wheel_speed is not None:
        logger.info("%s: wheel speed, %d samples over %.1f s", path, len(wheel_speed), wheel_speed.timestamps[-1] - wheel_speed.timestamps[0])
    return dataclasses.replace(sequence, wheel_speed=wheel_speed)


def without_cameras(sequence: Sequence, names: list[str] | tuple[str, ...]) -> Sequence:
    """``sequence`` as if the rig cameras ``names`` were not there (an ablation, or a camera known to
    be broken): the rig without them, and their observations and images dropped from every frame
    (an image source still decodes and tracks them: the frontend's per-camera state is left as it
    is). :class:`DatasetError` for a name the rig does not have or when no tractor camera is left
    (the tractor's motion, the frame of every estimate, would be unmeasured)."""
    dropped = set(names)
    unknown = sorted(dropped - set(sequence.rig.camera_names))
    if unknown:
        raise DatasetError(f"{sequence.path}: no camera {', '.join(unknown)} in the rig; its cameras are {', '.join(sequence.rig.camera_names)}")
    cameras = tuple(camera for camera in sequence.rig.cameras if camera.name not in dropped)
    if not any(camera.body == "tractor" for camera in cameras):
        raise DatasetError(f"{sequence.path}: without {', '.join(sorted(dropped))} no tractor camera is left")
    rig = dataclasses.replace(sequence.rig, cameras=cameras)
    logger.info("%s: running without cameras %s (left: %s)", sequence.path, ", ".join(sorted(dropped)), ", ".join(rig.camera_names))

    def steps(images: bool = True) -> Iterator[FrameStep]:
        stream = sequence.steps(images=images)
        try:
            for step in stream:
                observations = dataclasses.replace(step.observations, cameras={name: camera for name, camera in step.observations.cameras.items() if name not in dropped})
                images = None if step.images is None else {name: image for name, image in step.images.items() if name not in dropped}
                yield dataclasses.replace(step, observations=observations, images=images)
        finally:
            close = getattr(stream, "close", None)
            if close is not None:
                close()

    return dataclasses.replace(sequence, rig=rig, steps=steps)


def _open_log(path: Path, config: VoConfig, start: int, stop: int | None, rig: Rig | str | Path | None, progress: bool | None) -> Sequence:
    """A recording (``ampc_vo.io.bags``) through the image frontend; :class:`DatasetError` without a rig."""
    from ampc_vo.io.bags import read_recording
    from ampc_vo.rig import load_rig

    if rig is None:
        raise DatasetError(f"{path}: a recording needs a rig (--rig RIG.yaml) whose cameras name their topics")
    if config.source == "bearings":
        raise DatasetError(f"{path}: a recording has images only; source 'bearings' cannot be used")
    rig = rig if isinstance(rig, Rig) else load_rig(rig)
    recording = read_recording(path, rig, progress)
    frames = frame_selection(len(recording), start, stop, str(path))
    logger.info("%s: recording, %d frames of cameras %s (image frontend)", path, len(frames), ", ".join(recording.camera_names))
    return Sequence(path, "images", rig, recording.timestamps[frames.start:frames.stop], None,
                    lambda images=True: _frontend_stream(image_steps, recording, rig, config, frames, images=images))


def _open_folder(path: str | Path, config: VoConfig, start: int, stop: int | None) -> Sequence:
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such dataset folder")
    if not path.is_dir():
        raise DatasetError(f"{path}: not a folder (expected a dataset folder or a KITTI odometry folder)")
    from ampc_vo.io.kitti import is_kitti_folder

    if is_kitti_folder(path):
        return _open_kitti(path, config, start, stop)
    from ampc_vo.io.folder import read_dataset
    from ampc_vo.io.groundtruth import groundtruth_of

    dataset = read_dataset(path, load_measurements_file=config.source != "images", allow_missing_images=config.source != "bearings")
    frames = frame_selection(len(dataset), start, stop, str(path))
    timestamps = dataset.timestamps[frames.start:frames.stop]
    truth = groundtruth_of(dataset)
    use_images = config.source == "images" or (config.source == "auto" and dataset.has_images)
    if use_images:
        if not dataset.has_images:
            raise DatasetError(f"{path}: source 'images' asked for, but frames.csv lists no images for some camera")
        logger.info("%s: %d frames of images from cameras %s (image frontend)", path, len(frames), ", ".join(dataset.camera_names))
        return Sequence(path, "images", dataset.rig, timestamps, truth, lambda images=True: _frontend_stream(image_steps, dataset, dataset.rig, config, frames, images=images))
    if dataset.measurements is None:
        raise DatasetError(f"{path}: no images and no measurements.npz: nothing to run on")
    measurements = dataset.measurements
    logger.info("%s: %d frames of simulated bearing measurements", path, len(frames))
    return Sequence(path, "bearings", dataset.rig, timestamps, truth, lambda images=True: _bearing_steps(measurements, dataset.rig, frames))


def _open_kitti(path: Path, config: VoConfig, start: int, stop: int | None) -> Sequence:
    from ampc_vo.io.kitti import LEFT, RIGHT, load_kitti

    if config.source == "bearings":
        raise DatasetError(f"{path}: a KITTI folder has images only; source 'bearings' cannot be used")
    dataset = load_kitti(path)
    frames = frame_selection(len(dataset), start, stop, str(path))
    logger.info("%s: KITTI folder, %d stereo frames", path, len(frames))
    return Sequence(path, "kitti", dataset.rig, dataset.timestamps[frames.start:frames.stop], dataset.truth,
                    lambda images=True: _frontend_stream(stereo_image_steps, dataset, dataset.rig, config, frames, ((LEFT, RIGHT),), images=images),
                    T_body_reference=dataset.T_body_left_camera)
