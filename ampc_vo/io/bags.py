"""Recordings read without ROS (issue 15): ROS 1 ``.bag`` files, ROS 2 bag folders (sqlite3 or MCAP
storage) and bare ``.mcap`` files, through the ``rosbags`` library.

A :class:`Recording` presents the interface the image frontend reads our dataset folder through
(:class:`ampc_vo.io.folder.Dataset`): ``rig``, ``timestamps``, ``camera_names``,
``camera_timestamps``, ``__len__`` and ``load_image(frame, camera)``. Each rig camera names the
topic of its images (rig.yaml camera key ``topic``) carrying ``sensor_msgs/Image`` (mono8/16, bgr8/16,
rgb8/16, bgra, rgba, 8UC1/3/4, 16UC1, yuv422 (UYVY) and yuv422_yuy2, Bayer mosaics bayer_rggb8/16 and the
other three patterns, demosaiced) or ``sensor_msgs/CompressedImage`` (JPEG, PNG); each image's header stamp
is its capture time (DESIGN section 5: the cameras need not be synchronised; a camera whose driver
leaves the stamps unset gets the log's receive times, with a warning: :func:`capture_times`).

Frames (:func:`group_frames`): the camera with the most images (among those at the slowest rate)
is the reference; its stamps (with
gaps of dropped images filled at its median period, and extended at that period where other
cameras have images before its first or after its last) are the frame timestamps. Every other camera's
phase offset to it (the median of its stamps' offsets to the nearest reference stamp, in
(-P/2, P/2]) is removed and each image goes to the frame nearest in time; each camera keeps its own
stamp in ``camera_timestamps`` (a frame that has no image of a camera gets the reference time plus
that camera's offset, and ``load_image`` raises :class:`DatasetError`, which the frontend logs and
recovers from: that camera re-initialises). Messages out of order in the log are sorted by stamp;
duplicate stamps, dropped images, a camera that starts late or stops early are logged once per
camera; a camera without a topic, a topic missing from the log, or a camera whose stamps do not
overlap the reference's (another clock) are a :class:`DatasetError`.

The log is indexed once (header stamps read from the serialised messages, no image decoded) with a
progress bar over its duration; images are fetched per frame by their log time (all cameras of a
frame at once, :meth:`Recording.fetch_frame`, in one thread) and decoded on demand (the cameras may
be decoded in parallel threads, ``ampc_vo.io.frame_images``). A :class:`Recording` pickles without
its open reader (the frontend worker process reopens the log).
"""
from __future__ import annotations

import logging
import struct
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ampc_vo.errors import DatasetError
from ampc_vo.rig import Rig

LOGGER = logging.getLogger(__name__)

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE_TYPE, COMPRESSED_IMAGE_TYPE)
LOG_SUFFIXES = (".bag", ".mcap", ".db3")
PROGRESS_MIN_MESSAGES = 500  # index pass over more messages than this shows a progress bar
# raw encodings (sensor_msgs/image_encodings.h): (numpy dtype, channels, OpenCV conversion to grey or None)
_ENCODINGS = {"mono8": (np.uint8, 1, None), "8UC1": (np.uint8, 1, None), "mono16": (np.uint16, 1, None), "16UC1": (np.uint16, 1, None),
              "bgr8": (np.uint8, 3, "COLOR_BGR2GRAY"), "8UC3": (np.uint8, 3, "COLOR_BGR2GRAY"), "rgb8": (np.uint8, 3, "COLOR_RGB2GRAY"),
              "bgra8": (np.uint8, 4, "COLOR_BGRA2GRAY"), "8UC4": (np.uint8, 4, "COLOR_BGRA2GRAY"), "rgba8": (np.uint8, 4, "COLOR_RGBA2GRAY"),
              "bgr16": (np.uint16, 3, "COLOR_BGR2GRAY"), "rgb16": (np.uint16, 3, "COLOR_RGB2GRAY"),
              "bgra16": (np.uint16, 4, "COLOR_BGRA2GRAY"), "rgba16": (np.uint16, 4, "COLOR_RGBA2GRAY"),
              # YUV 4:2:2, two bytes per pixel: ROS "yuv422" is UYVY, "yuv422_yuy2" is YUYV (the grey image is the Y bytes)
              "yuv422": (np.uint8, 2, "COLOR_YUV2GRAY_UYVY"), "uyvy": (np.uint8, 2, "COLOR_YUV2GRAY_UYVY"),
              "yuv422_yuy2": (np.uint8, 2, "COLOR_YUV2GRAY_YUY2"), "yuyv": (np.uint8, 2, "COLOR_YUV2GRAY_YUY2")}
# raw Bayer mosaics of colour cameras without on-board demosaicing, demosaiced to grey. ROS names the
# pattern by its first row from the top left, OpenCV by the second row's second and third pixels:
# ROS bayer_rggb is OpenCV's BayerBG (as cv_bridge converts them; tests/io/test_bags.py checks it)
_BAYER_PATTERNS = {"rggb": "COLOR_BayerBG2GRAY", "bggr": "COLOR_BayerRG2GRAY", "gbrg": "COLOR_BayerGR2GRAY", "grbg": "COLOR_BayerGB2GRAY"}
for _pattern, _conversion in _BAYER_PATTERNS.items():
    _ENCODINGS[f"bayer_{_pattern}8"] = (np.uint8, 1, _conversion)
    _ENCODINGS[f"bayer_{_pattern}16"] = (np.uint16, 1, _conversion)
_SIXTEEN_BIT = tuple(name for name, (dtype, _, _) in _ENCODINGS.items() if dtype == np.uint16)


def is_log(path: str | Path) -> bool:
    """A ROS 1 bag, a bare MCAP or sqlite3 file, or a ROS 2 bag folder (``metadata.yaml``)."""
    path = Path(path)
    if path.is_file():
        return path.suffix in LOG_SUFFIXES
    return path.is_dir() and (path / "metadata.yaml").is_file()


def log_name(path: str | Path) -> str:
    """The name of a log without its suffix (``drive_03.bag`` -> ``drive_03``)."""
    path = Path(path)
    return path.stem if path.is_file() else path.name


def open_reader(path: str | Path):
    """An opened ``rosbags`` ``AnyReader`` on ``path`` (message definitions from the log, else ROS 2
    Humble's); :class:`DatasetError` when the file is not a readable log."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such log (expected a .bag file, a .mcap file or a ROS 2 bag folder)")
    if not is_log(path):
        raise DatasetError(f"{path}: not a recording (expected a ROS 1 .bag, a .mcap file or a ROS 2 bag folder with metadata.yaml)")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as error:  # rosbags raises its own error types and struct/OS errors on corrupt files
        raise DatasetError(f"{path}: cannot read the log ({type(error).__name__}: {error})") from None
    return reader


def header_stamp(rawdata: bytes | memoryview, ros2: bool) -> float:
    """Header stamp (s) of a serialised message that starts with ``std_msgs/Header``, without
    deserialising it: ROS 1 ``seq, secs, nsecs`` (little endian); ROS 2 CDR after the 4-byte
    encapsulation header (byte 1: 1 = little endian) ``sec, nanosec``."""
    if ros2:
        order = "<" if rawdata[1] == 1 else ">"
        sec, nanosec = struct.unpack_from(order + "iI", rawdata, 4)
    else:
        sec, nanosec = struct.unpack_from("<II", rawdata, 4)
    return sec + 1e-9 * nanosec


def topic_connections(reader, topics: list[str], types: tuple[str, ...], path: Path, what: str) -> dict[str, list]:
    """The connections of each topic; :class:`DatasetError` naming the log's topics of ``types``
    when one is missing or of another type."""
    found: dict[str, list] = {}
    for connection in reader.connections:
        found.setdefault(connection.topic, []).append(connection)
    for topic in topics:
        if topic not in found:
            available = sorted(name for name, conns in found.items() if conns[0].msgtype in types)
            raise DatasetError(f"{path}: {what} topic {topic!r} is not in the log (topics of type {', '.join(types)}: {available or 'none'})")
        msgtype = found[topic][0].msgtype
        if msgtype not in types:
            raise DatasetError(f"{path}: {what} topic {topic!r} carries {msgtype}, expected {' or '.join(types)}")
    return {topic: found[topic] for topic in topics}


def scan_stamps(reader, connections: list, path: Path, progress: bool | None = None, desc: str = "index") -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per topic: header stamps (s) and log times (ns) of its messages, in log order, with a
    progress bar over the log's duration (``progress`` None: when the log is long)."""
    stamps: dict[str, list[float]] = {c.topic: [] for c in connections}
    logtimes: dict[str, list[int]] = {c.topic: [] for c in connections}
    count = sum(c.msgcount for c in connections)
    bar = None
    if progress or (progress is None and count > PROGRESS_MIN_MESSAGES):
        from tqdm import tqdm

        bar = tqdm(total=round(reader.duration * 1e-9, 1), desc=f"{desc} {path.name}", unit="s log", leave=False)
    start, shown = reader.start_time, 0.0
    try:
        for connection, logtime, rawdata in reader.messages(connections=connections):
            try:
                stamps[connection.topic].append(header_stamp(rawdata, reader.is2))
            except struct.error:
                raise DatasetError(f"{path}: {connection.topic}: message at log time {logtime * 1e-9:.3f} s is truncated") from None
            logtimes[connection.topic].append(logtime)
            if bar is not None and (logtime - start) * 1e-9 - shown >= 0.1:
                bar.update(round((logtime - start) * 1e-9 - shown, 1))
                shown = round((logtime - start) * 1e-9, 1)
    except DatasetError:
        raise
    except Exception as error:
        raise DatasetError(f"{path}: cannot read the log's messages ({type(error).__name__}: {error})") from None
    finally:
        if bar is not None:
            bar.close()
    return {topic: (np.array(stamps[topic], dtype=float), np.array(logtimes[topic], dtype=np.int64)) for topic in stamps}


# ---------------------------------------------------------------------- frame grouping
@dataclass(frozen=True)
class FrameGrouping:
    """Frames of unsynchronised cameras (module docstring). ``timestamps`` (F,); per camera:
    ``indices`` (F,) into that camera's sorted images (-1: none in that frame), ``offsets`` its
    phase offset to the reference camera (s), and ``reference`` the reference camera's name."""

    timestamps: np.ndarray
    indices: dict[str, np.ndarray]
    offsets: dict[str, float]
    reference: str


def _period(stamps: np.ndarray) -> float:
    steps = np.diff(stamps)
    steps = steps[steps > 0]
    return float(np.median(steps)) if len(steps) else 1.0


def _filled_reference(stamps: np.ndarray, period: float) -> np.ndarray:
    """The reference camera's stamps with each gap longer than 1.5 periods (dropped images)
    filled at equal steps near ``period``."""
    times = [stamps[:1]]
    for previous, current in zip(stamps[:-1], stamps[1:]):
        missing = int(round((current - previous) / period)) - 1
        if missing >= 1 and current - previous > 1.5 * period:
            times.append(previous + (current - previous) * np.arange(1, missing + 1) / (missing + 1))
        times.append(np.array([current]))
    return np.concatenate(times)


def _assign(times: np.ndarray, timestamps: np.ndarray, offset: float, period: float) -> np.ndarray:
    """Per frame, the index of the camera image nearest to frame time + ``offset`` (within half a
    period; -1: none)."""
    shifted = times - offset
    frame_of = np.clip(np.searchsorted(timestamps, shifted), 1, len(timestamps) - 1) if len(timestamps) > 1 else np.zeros(len(times), dtype=np.int64)
    if len(timestamps) > 1:
        frame_of = np.where(np.abs(shifted - timestamps[frame_of - 1]) <= np.abs(shifted - timestamps[frame_of]), frame_of - 1, frame_of)
    distance = np.abs(shifted - timestamps[frame_of])
    index = np.full(len(timestamps), -1, dtype=np.int64)
    best = np.full(len(timestamps), np.inf)
    for image in np.flatnonzero(distance < 0.5 * period):
        frame = frame_of[image]
        if distance[image] < best[frame]:
            index[frame], best[frame] = image, distance[image]
    return index


def _phase_offset(times: np.ndarray, timestamps: np.ndarray, period: float, name: str, reference: str, where: str) -> float:
    """A camera's capture offset to the reference camera's frame times: the median offset of its
    stamps to the nearest frame time, in (-P/2, P/2]; near P/2 the sign that puts more images into
    frames. :class:`DatasetError` when its stamps do not overlap the frames at all (another clock)."""
    if times[-1] < timestamps[0] - period or times[0] > timestamps[-1] + period:
        raise DatasetError(f"{where}: camera {name!r}: its stamps [{times[0]:.3f}, {times[-1]:.3f}] s do not overlap the reference camera "
                           f"{reference!r}'s [{timestamps[0]:.3f}, {timestamps[-1]:.3f}] s (another clock?)")
    nearest = timestamps[np.clip(np.searchsorted(timestamps, times), 1, len(timestamps) - 1) - 1]
    following = timestamps[np.clip(np.searchsorted(timestamps, times), 0, len(timestamps) - 1)]
    difference = np.where(np.abs(times - nearest) < np.abs(times - following), times - nearest, times - following)
    offset = float(np.median(difference))
    if abs(_period(times) - period) > 0.2 * period:
        LOGGER.warning("%s: camera %r runs at %.1f Hz, the reference camera %r at %.1f Hz: only its image nearest to each frame is used",
                       where, name, 1.0 / _period(times), reference, 1.0 / period)
    candidates = [offset] + ([offset - period] if offset > 0.4 * period else []) + ([offset + period] if offset < -0.4 * period else [])
    return max(candidates, key=lambda candidate: (int(np.count_nonzero(_assign(times, timestamps, candidate, period) >= 0)), candidate >= 0))


def group_frames(stamps: dict[str, np.ndarray], where: str = "log") -> FrameGrouping:
    """Group the sorted, strictly increasing capture times of each camera into frames (module
    docstring). ``stamps``: camera name -> (N_c,) seconds, in rig order (ties of the reference
    choice go to the first camera)."""
    names = list(stamps)
    empty = [name for name in names if len(stamps[name]) == 0]
    if empty:
        raise DatasetError(f"{where}: no images from camera(s) {empty}")
    # the reference: among the cameras at the slowest rate (a faster camera would leave the others
    # without an image in every other frame), the one with the most images
    periods = {name: _period(stamps[name]) for name in names}
    slowest = [name for name in names if periods[name] >= 0.8 * max(periods.values())]
    reference = max(slowest, key=lambda name: (len(stamps[name]), -names.index(name)))
    period = periods[reference]
    timestamps = _filled_reference(stamps[reference], period)
    offsets = {name: 0.0 if name == reference else _phase_offset(stamps[name], timestamps, period, name, reference, where) for name in names}
    # frames beyond the reference's span where other cameras at its rate have images (a reference
    # camera that starts late or stops early), at its period
    same_rate = [name for name in names if abs(periods[name] - period) <= 0.2 * period]
    first = min(stamps[name][0] - offsets[name] for name in same_rate)
    last = max(stamps[name][-1] - offsets[name] for name in same_rate)
    before, after = int(np.floor((timestamps[0] - first) / period + 0.5)), int(np.floor((last - timestamps[-1]) / period + 0.5))
    timestamps = np.concatenate([timestamps[0] - period * np.arange(before, 0, -1), timestamps, timestamps[-1] + period * np.arange(1, after + 1)])
    indices = {}
    for name in names:
        times = stamps[name]
        index = _assign(times, timestamps, offsets[name], period)
        unused = len(times) - int(np.count_nonzero(index >= 0))
        if unused:
            LOGGER.info("%s: camera %r: %d of its %d images fall in no frame (extra images or far from the frame times)", where, name, unused, len(times))
        indices[name] = index
    return FrameGrouping(timestamps, indices, offsets, reference)


def _log_coverage(grouping: FrameGrouping, where: str) -> None:
    """One warning per camera that starts late, stops early or has dropped images."""
    for name, index in grouping.indices.items():
        present = np.flatnonzero(index >= 0)
        if len(present) == len(index):
            continue
        first, last = int(present[0]), int(present[-1])
        inner = int(np.count_nonzero(index[first:last + 1] < 0))
        parts = []
        if first > 0:
            parts.append(f"starts late (no image in frames 0-{first - 1})")
        if last < len(index) - 1:
            parts.append(f"stops early (no image after frame {last})")
        if inner:
            parts.append(f"{inner} dropped image(s)")
        LOGGER.warning("%s: camera %r %s: those frames run without it (its tracker re-initialises)", where, name, ", ".join(parts))


_MAX_TRANSPORT_DELAY_S = 1.0  # capture to log time: a header stamp of 0 with a log time later than this is unset


def capture_times(headers: np.ndarray, logtimes: np.ndarray, name: str, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A camera's capture times (s) from its images' header stamps ``headers`` (s) and log times
    (ns): ``(times, logtimes, headers)`` of the images kept. A camera whose driver leaves most
    stamps unset (0) gets the log's receive times instead (which carry the transport delay), with a
    warning; a few unset stamps among set ones drop those images (logged). A stamp of 0 is unset
    only where the log time is more than ``_MAX_TRANSPORT_DELAY_S`` later (a recording whose clock
    starts at 0, as one written from a simulated dataset, has a capture at 0)."""
    unset = (headers <= 0.0) & (logtimes * 1e-9 > headers + _MAX_TRANSPORT_DELAY_S)
    if np.count_nonzero(unset) * 2 > len(headers):
        LOGGER.warning("%s: camera %r: %d of %d images have no header stamp (0): the log's receive times are taken as capture times "
                       "(they include the transport delay)", where, name, int(np.count_nonzero(unset)), len(headers))
        return logtimes * 1e-9, logtimes, headers
    if np.any(unset):
        LOGGER.warning("%s: camera %r: %d image(s) without a header stamp (0) dropped", where, name, int(np.count_nonzero(unset)))
    return headers[~unset], logtimes[~unset], headers[~unset]


def _sorted_unique(times: np.ndarray, logtimes: np.ndarray, headers: np.ndarray, name: str, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Capture times sorted (messages out of order in the log), duplicates dropped, each logged
    once; the log times and header stamps of the images kept alongside."""
    order = np.argsort(times, kind="stable")
    if np.any(np.diff(order) < 0):
        LOGGER.warning("%s: camera %r: %d image(s) out of order in the log: sorted by capture time", where, name, int(np.count_nonzero(np.diff(times) < 0)))
    times, logtimes, headers = times[order], logtimes[order], headers[order]
    keep = np.concatenate([[True], np.diff(times) > 0])
    if not np.all(keep):
        LOGGER.warning("%s: camera %r: %d image(s) with a repeated capture time dropped", where, name, int(np.count_nonzero(~keep)))
    return times[keep], logtimes[keep], headers[keep]


# ---------------------------------------------------------------------- images
def decode_image_message(message: object, msgtype: str, where: str) -> np.ndarray:
    """The grey ``uint8`` image of a deserialised ``sensor_msgs/Image`` or ``CompressedImage``;
    :class:`DatasetError` for an unsupported encoding or undecodable data (16-bit: top byte)."""
    import cv2

    data = np.frombuffer(message.data, dtype=np.uint8) if not isinstance(message.data, np.ndarray) else message.data.view(np.uint8)
    if msgtype == COMPRESSED_IMAGE_TYPE:
        image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
        if image is None:
            raise DatasetError(f"{where}: compressed image ({message.format!r}) cannot be decoded")
        return image
    encoding = message.encoding
    if encoding not in _ENCODINGS:
        raise DatasetError(f"{where}: image encoding {encoding!r} not supported (supported: {', '.join(_ENCODINGS)})")
    dtype, channels, conversion = _ENCODINGS[encoding]
    itemsize = np.dtype(dtype).itemsize
    height, width, step = int(message.height), int(message.width), int(message.step)
    if step < width * channels * itemsize or data.size < step * height:
        raise DatasetError(f"{where}: image data of {data.size} bytes does not hold {width}x{height} {encoding} (step {step})")
    rows = data[:step * height].reshape(height, step)[:, :width * channels * itemsize]
    image = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(">" if message.is_bigendian else "<")).reshape(height, width, channels)
    if itemsize == 2:
        image = (image.astype(np.uint16) >> 8).astype(np.uint8)
    image = image[:, :, 0] if channels == 1 else image
    if conversion is not None:
        image = cv2.cvtColor(np.ascontiguousarray(image), getattr(cv2, conversion))
    return np.ascontiguousarray(image)


class Recording:
    """A log opened as a dataset (module docstring): ``rig``, ``timestamps`` (F,), ``camera_names``,
    ``camera_timestamps`` (camera -> (F,) capture times), ``load_image(frame, camera)``."""

    groundtruth = None
    measurements = None
    has_images = True

    def __init__(self, path: str | Path, rig: Rig, progress: bool | None = None) -> None:
        self.root = Path(path)
        self.rig = rig
        self.camera_names = tuple(rig.camera_names)
        missing = [camera.name for camera in rig.cameras if not camera.topic]
        if missing:
            raise DatasetError(f"{self.root}: rig cameras {missing} have no 'topic' in rig.yaml (the topic of their images in the log)")
        self._topics = {camera.name: camera.topic for camera in rig.cameras}
        reader = open_reader(self.root)
        try:
            connections = topic_connections(reader, list(dict.fromkeys(self._topics.values())), IMAGE_TYPES, self.root, "image")
            scanned = scan_stamps(reader, [c for conns in connections.values() for c in conns], self.root, progress)
        finally:
            reader.close()
        where = str(self.root)
        stamps, logtimes, headers = {}, {}, {}
        for name, topic in self._topics.items():
            stamps[name], logtimes[name], headers[name] = _sorted_unique(*capture_times(*scanned[topic], name, where), name, where)
        grouping = group_frames(stamps, where)
        _log_coverage(grouping, where)
        self.timestamps = grouping.timestamps
        self.reference_camera = grouping.reference
        self.camera_timestamps: dict[str, np.ndarray] = {}
        self._logtimes: dict[str, np.ndarray] = {}
        self._stamps: dict[str, np.ndarray] = {}
        for name in self.camera_names:
            index = grouping.indices[name]
            present = index >= 0
            self.camera_timestamps[name] = np.where(present, stamps[name][np.maximum(index, 0)], self.timestamps + grouping.offsets[name])
            self._logtimes[name] = np.where(present, logtimes[name][np.maximum(index, 0)], -1)
            self._stamps[name] = np.where(present, headers[name][np.maximum(index, 0)], np.nan)  # the header stamp: finds the message
        self.offsets = dict(grouping.offsets)
        LOGGER.info("%s: %d frames of cameras %s (reference %s; offsets %s ms)", where, len(self), list(self.camera_names), self.reference_camera,
                    ", ".join(f"{name} {1e3 * offset:+.1f}" for name, offset in self.offsets.items()))
        self._local = threading.local()
        self._lock = threading.Lock()
        self._cache: tuple[int, dict[str, object]] | None = None
        self._low_bit_depth_checked: set[str] = set()

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        for transient in ("_local", "_lock", "_cache"):
            state.pop(transient, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._local, self._lock, self._cache = threading.local(), threading.Lock(), None

    def camera_timestamp(self, frame: int, camera: str) -> float:
        return float(self.camera_timestamps[camera][frame])

    def _reader(self):
        reader = getattr(self._local, "reader", None)
        if reader is None:
            reader = self._local.reader = open_reader(self.root)
            self._local.connections = {c.topic: c for c in reader.connections if c.topic in self._topics.values()}
        return reader

    def close(self) -> None:
        reader = getattr(self._local, "reader", None)
        if reader is not None:
            reader.close()
            self._local.reader = None

    def _frame_messages(self, frame: int) -> dict[str, object]:
        """Deserialised image messages of one frame (camera -> message), fetched by log time."""
        wanted = {name: (self._topics[name], float(self._stamps[name][frame]), int(self._logtimes[name][frame]))
                  for name in self.camera_names if self._logtimes[name][frame] >= 0}
        if not wanted:
            return {}
        reader = self._reader()
        times = [logtime for _, _, logtime in wanted.values()]
        connections = [self._local.connections[topic] for topic in {topic for topic, _, _ in wanted.values()}]
        messages: dict[str, object] = {}
        try:
            for connection, logtime, rawdata in reader.messages(connections=connections, start=min(times), stop=max(times) + 1):
                for name, (topic, stamp, wanted_time) in wanted.items():
                    if name not in messages and connection.topic == topic and logtime == wanted_time and abs(header_stamp(rawdata, reader.is2) - stamp) < 1e-9:
                        messages[name] = reader.deserialize(rawdata, connection.msgtype), connection.msgtype
        except Exception as error:
            raise DatasetError(f"{self.root}: frame {frame}: cannot read its images ({type(error).__name__}: {error})") from None
        return messages

    def _cached_messages(self, frame: int) -> dict[str, object]:
        """The image messages of ``frame``, read once per frame (the last frame's are kept for the
        cameras that follow); :class:`DatasetError` for a frame out of range or a log that cannot be read."""
        if not 0 <= frame < len(self):
            raise DatasetError(f"{self.root}: frame {frame} out of range [0, {len(self)})")
        with self._lock:
            if self._cache is None or self._cache[0] != frame:
                self._cache = (frame, self._frame_messages(frame))
            return self._cache[1]

    def fetch_frame(self, frame: int) -> None:
        """Read the image messages of ``frame`` in the calling thread, so that the cameras'
        :meth:`load_image` calls that follow only decode them and can run in other threads without
        each opening the log (``ampc_vo.io.frame_images``); :class:`DatasetError` as :meth:`load_image`."""
        self._cached_messages(frame)

    def load_image(self, frame: int, camera: str) -> np.ndarray:
        """The grey ``uint8`` image of ``camera`` in ``frame``; :class:`DatasetError` when the frame
        has none from that camera or it cannot be decoded or has another size than the rig's."""
        if camera not in self.camera_names:
            raise DatasetError(f"{self.root}: no camera named {camera!r} (cameras: {list(self.camera_names)})")
        messages = self._cached_messages(frame)
        if camera not in messages:
            raise DatasetError(f"{self.root}: frame {frame}: no image from camera {camera!r} (topic {self._topics[camera]}) near {self.timestamps[frame]:.3f} s")
        message, msgtype = messages[camera]
        where = f"{self.root}: {self._topics[camera]} at {self.camera_timestamps[camera][frame]:.6f} s"
        from ampc_vo.io.folder import _check_size

        image = decode_image_message(message, msgtype, where)
        _check_size(where, image, self.rig.camera(camera))
        if camera not in self._low_bit_depth_checked and msgtype == IMAGE_TYPE and message.encoding in _SIXTEEN_BIT:
            self._low_bit_depth_checked.add(camera)
            raw = np.frombuffer(message.data, dtype=">u2" if message.is_bigendian else "<u2")
            if 0 < int(raw.max()) < 4096:
                LOGGER.warning("%s: 16-bit images whose values stay below 4096 (12-bit data?): read as 8 bit they keep at most 16 grey levels", where)
        return image


def read_recording(path: str | Path, rig: Rig, progress: bool | None = None) -> Recording:
    """Open a log as a :class:`Recording` of the rig's cameras (module docstring)."""
    return Recording(path, rig, progress)


def topic_messages(path: str | Path, topic: str, types: tuple[str, ...], what: str) -> Iterator[tuple[float, object]]:
    """``(header stamp s, message)`` of every message of ``topic`` (one of ``types``), in log order."""
    path = Path(path)
    reader = open_reader(path)
    try:
        connections = topic_connections(reader, [topic], types, path, what)[topic]
        for connection, _, rawdata in reader.messages(connections=connections):
            message = reader.deserialize(rawdata, connection.msgtype)
            stamp = message.header.stamp
            yield stamp.sec + 1e-9 * stamp.nanosec, message
    except DatasetError:
        raise
    except Exception as error:
        raise DatasetError(f"{path}: {topic}: cannot read its messages ({type(error).__name__}: {error})") from None
    finally:
        reader.close()
