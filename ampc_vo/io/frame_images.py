"""Loading all cameras' images of one frame, tolerant of missing or corrupt files.

A missing or corrupt image is ``None`` with a warning (the tracker of that camera re-initialises;
the run goes on). The image frontend reads frames through a :class:`FrameImageReader`: the next
frame's images are read in a background thread while the caller tracks this frame's, and the
cameras of a frame are decoded in parallel threads (``cv2.imread`` / ``cv2.imdecode`` release the
GIL), instead of one after another before tracking. Only the time spent is different: every frame
gets the same images in the same order, and each problem is logged, with the same message, when its
frame is taken (before that frame is tracked), as :func:`load_frame_images` logs it.

A dataset that reads its images from one open file (a recording, :class:`ampc_vo.io.bags.Recording`)
has ``fetch_frame(frame)``: it is called first, in the reading thread, so that the log is read in
one thread and in frame order, and the threads only decode the bytes fetched. When that fetch fails,
the cameras are loaded one after another in the reading thread, so each gets the error it got
before.
"""
from __future__ import annotations

import logging
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ampc_vo.errors import DatasetError

logger = logging.getLogger(__name__)


@dataclass
class FrameImages:
    """All cameras' images of one frame (``None`` where unreadable) and why each missing one is missing."""

    frame: int
    images: dict[str, np.ndarray | None]
    problems: dict[str, DatasetError] = field(default_factory=dict)

    def log_problems(self) -> None:
        """One warning per missing or corrupt image, in camera order."""
        for camera, error in self.problems.items():
            logger.warning("frame %d: %s; camera %s skipped", self.frame, error, camera)


def _image_or_error(dataset: object, frame: int, camera: str) -> np.ndarray | DatasetError:
    """``dataset.load_image(frame, camera)``, or the :class:`DatasetError` it raised (kept as a
    value so that the problems of a frame are logged in camera order by the caller)."""
    try:
        return dataset.load_image(frame, camera)
    except DatasetError as error:
        return error


def _fetched(dataset: object, frame: int) -> bool:
    """Whether the frame's images may be decoded in other threads: a dataset without
    ``fetch_frame`` (one file per image) always; one with it once the fetch succeeded."""
    fetch = getattr(dataset, "fetch_frame", None)
    if fetch is None:
        return True
    try:
        fetch(frame)
    except DatasetError:
        return False
    return True


def read_frame_images(dataset: object, frame: int, decoder: Executor | None = None) -> FrameImages:
    """All cameras' images of one frame, without logging (``dataset`` has ``camera_names`` and
    ``load_image(frame, camera)``: our folder format, KITTI or a recording); with ``decoder`` the
    cameras are decoded in its threads (module docstring), else one after another."""
    cameras = tuple(dataset.camera_names)
    if decoder is not None and _fetched(dataset, frame):
        outcomes = list(decoder.map(lambda camera: _image_or_error(dataset, frame, camera), cameras))
    else:
        outcomes = [_image_or_error(dataset, frame, camera) for camera in cameras]
    images = {camera: None if isinstance(outcome, DatasetError) else outcome for camera, outcome in zip(cameras, outcomes)}
    problems = {camera: outcome for camera, outcome in zip(cameras, outcomes) if isinstance(outcome, DatasetError)}
    return FrameImages(frame, images, problems)


def load_frame_images(dataset: object, frame: int) -> dict[str, np.ndarray | None]:
    """All cameras' images of one frame, read one after another in this thread; a missing or
    corrupt image becomes ``None`` with a warning (module docstring)."""
    read = read_frame_images(dataset, frame)
    read.log_problems()
    return read.images


class FrameImageReader:
    """The images of ``frames`` (a range of consecutive frames), one frame ahead: :meth:`take`
    returns a frame's images and starts reading the next frame's in a background thread, its cameras
    decoded by ``threads`` threads (module docstring). Not for concurrent use: one thread takes
    the frames, in order (a frame taken out of order is read then, without the look-ahead).
    Close it (or use it as a context manager) to stop its threads."""

    def __init__(self, dataset: object, frames: range, threads: int = 1) -> None:
        self.dataset = dataset
        self.frames = frames
        self._reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame-reader")
        self._decoder = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="image-decoder") if threads > 1 else None
        self._ahead: tuple[int, Future[FrameImages]] | None = None

    def _read(self, frame: int) -> Future[FrameImages]:
        return self._reader.submit(read_frame_images, self.dataset, frame, self._decoder)

    def take(self, frame: int) -> FrameImages:
        """The images of ``frame`` (its problems logged now: before the caller tracks it); the
        next frame of ``frames`` is read meanwhile. A reading error other than a missing or corrupt
        image is raised here, for the frame it belongs to."""
        pending = self._ahead[1] if self._ahead is not None and self._ahead[0] == frame else self._read(frame)
        following = frame + 1
        self._ahead = (following, self._read(following)) if following in self.frames else None
        read = pending.result()
        read.log_problems()
        return read

    def close(self) -> None:
        """Stop the threads (a read ahead not yet started is dropped; one under way is waited for)."""
        self._ahead = None
        self._reader.shutdown(wait=True, cancel_futures=True)
        if self._decoder is not None:
            self._decoder.shutdown(wait=True)

    def __enter__(self) -> "FrameImageReader":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
