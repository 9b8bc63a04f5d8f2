"""Write a dataset folder as a recording (issue 15): a ROS 1 ``.bag``, a ROS 2 bag folder (sqlite3 or
MCAP storage) or a bare ``.mcap`` file, with the ``rosbags`` writers.

What the recording holds: every camera's images on its rig ``topic`` (``sensor_msgs/Image`` mono8, or
``sensor_msgs/CompressedImage`` JPEG/PNG), stamped with that camera's capture time
(``Dataset.camera_timestamps``); optionally the tractor's rear-axle speed
(``geometry_msgs/TwistStamped`` ``twist.linear.x``, or ``nav_msgs/Odometry``) and the ground-truth
tractor pose (``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped``). A message's log time is its
stamp plus an optional per-topic transport delay (delays that differ between topics put the
messages out of stamp order in the log, as real recorders do). A log's time cannot be negative, but
a dataset's capture times can (a camera that fires before the first frame time, as the realistic
routes' unsynchronised cameras do): every stamp is written plus ``time_origin`` seconds, by default
the whole seconds that make the earliest stamp non-negative (:func:`recording_time_origin`; 0 for
most datasets). Used by the tests to build logs from rendered sequences and by users to export a
dataset folder.
"""
from __future__ import annotations

import logging
import math
import shutil
import tempfile
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np

from ampc_vo.errors import DatasetError
from ampc_vo.geometry import pose_to_xyz_quat

FORMATS = ("ros1", "ros2-sqlite3", "ros2-mcap", "mcap")
SPEED_TYPES = {"twist": "geometry_msgs/msg/TwistStamped", "odometry": "nav_msgs/msg/Odometry"}
POSE_TYPES = {"odometry": "nav_msgs/msg/Odometry", "pose": "geometry_msgs/msg/PoseStamped"}

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordingContent:
    """What goes into the recording besides the images (module docstring). ``compressed``: the
    cameras written as ``CompressedImage`` (``image_format`` ``jpeg`` or ``png``); ``delays``:
    topic -> transport delay (s) added to the log time; ``drop``: camera -> frames left out;
    ``time_origin``: seconds added to every stamp (``None``: :func:`recording_time_origin`);
    ``unstamped``: cameras whose images carry a header stamp of 0 (a driver that does not stamp:
    only the log time tells when they came)."""

    compressed: tuple[str, ...] = ()
    image_format: str = "jpeg"
    jpeg_quality: int = 95
    wheel_speed: tuple[np.ndarray, np.ndarray] | None = None  # (timestamps, speed m/s)
    wheel_speed_topic: str = "/vehicle/wheel_speed"
    wheel_speed_type: str = "twist"
    pose_topic: str | None = None  # the ground-truth tractor pose (dataset groundtruth.csv)
    pose_type: str = "odometry"
    delays: dict[str, float] = field(default_factory=dict)
    drop: dict[str, tuple[int, ...]] = field(default_factory=dict)
    time_origin: float | None = None
    unstamped: tuple[str, ...] = ()


def recording_time_origin(dataset: object, content: RecordingContent = RecordingContent()) -> float:
    """Seconds added to every stamp of ``dataset``'s recording (module docstring): ``content.time_origin``
    when given, else the whole seconds that lift the earliest capture, wheel-speed or ground-truth
    time to zero or above (0 when none is negative). Outputs of the recording are on this clock:
    subtract it to compare them with the dataset's own times."""
    if content.time_origin is not None:
        return float(content.time_origin)
    earliest = _earliest_time(dataset, content)
    return float(math.ceil(-earliest)) if earliest < 0.0 else 0.0


def _earliest_time(dataset: object, content: RecordingContent) -> float:
    """The earliest capture, wheel-speed or ground-truth time (s) the recording would hold, before its origin."""
    earliest = min([float(np.min(dataset.timestamps))] + [float(np.min(times)) for times in dataset.camera_timestamps.values()])
    if content.wheel_speed is not None and len(content.wheel_speed[0]):
        earliest = min(earliest, float(np.min(content.wheel_speed[0])))
    if content.pose_topic is not None and dataset.groundtruth is not None:
        earliest = min(earliest, float(np.min(dataset.groundtruth.timestamps)))
    return earliest


def _stamp(typestore, seconds: float, ros1: bool):
    Time = typestore.types["builtin_interfaces/msg/Time"]
    nanoseconds = int(round(seconds * 1e9))
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def _header(typestore, seconds: float, frame_id: str, ros1: bool):
    Header = typestore.types["std_msgs/msg/Header"]
    stamp = _stamp(typestore, seconds, ros1)
    return Header(seq=0, stamp=stamp, frame_id=frame_id) if ros1 else Header(stamp=stamp, frame_id=frame_id)


def _image_message(typestore, image: Callable[[], np.ndarray], seconds: float, frame_id: str, ros1: bool, compressed: bool, content: RecordingContent):
    import cv2

    header = _header(typestore, seconds, frame_id, ros1)
    image = image()
    if compressed:
        extension = ".jpg" if content.image_format == "jpeg" else ".png"
        params = [cv2.IMWRITE_JPEG_QUALITY, content.jpeg_quality] if extension == ".jpg" else []
        ok, encoded = cv2.imencode(extension, image, params)
        if not ok:
            raise DatasetError(f"cannot encode an image as {content.image_format}")
        return typestore.types["sensor_msgs/msg/CompressedImage"](header=header, format=content.image_format, data=encoded.reshape(-1))
    height, width = image.shape[:2]
    return typestore.types["sensor_msgs/msg/Image"](header=header, height=height, width=width, encoding="mono8", is_bigendian=0, step=width,
                                                   data=np.ascontiguousarray(image, dtype=np.uint8).reshape(-1))


def _vector3(typestore, x: float, y: float = 0.0, z: float = 0.0):
    return typestore.types["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))


def _pose(typestore, T: np.ndarray):
    x, y, z, qx, qy, qz, qw = pose_to_xyz_quat(T)
    types = typestore.types
    return types["geometry_msgs/msg/Pose"](position=types["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                                           orientation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))


def _odometry(typestore, seconds: float, ros1: bool, T: np.ndarray | None = None, speed: float = 0.0):
    types = typestore.types
    zeros = np.zeros(36)
    pose = types["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(typestore, np.eye(4) if T is None else T), covariance=zeros)
    twist = types["geometry_msgs/msg/TwistWithCovariance"](twist=types["geometry_msgs/msg/Twist"](linear=_vector3(typestore, speed), angular=_vector3(typestore, 0.0)), covariance=zeros)
    return types["nav_msgs/msg/Odometry"](header=_header(typestore, seconds, "odom", ros1), child_frame_id="tractor", pose=pose, twist=twist)


class _Sink:
    """One rosbags writer behind ``connection(topic, msgtype)`` and ``write(topic, seconds, message)``."""

    def __init__(self, path: Path, format: str):
        from rosbags.typesys import Stores, get_typestore

        self.ros1 = format == "ros1"
        self.typestore = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if self.ros1:
            from rosbags.rosbag1 import Writer

            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.SQLITE3 if format == "ros2-sqlite3" else StoragePlugin.MCAP
            self.writer = Writer(path, version=9, storage_plugin=plugin)
        self.writer.open()
        self.connections: dict[str, object] = {}

    def write(self, topic: str, msgtype: str, seconds: float, message: object) -> None:
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.typestore)
        serialize = self.typestore.serialize_ros1 if self.ros1 else self.typestore.serialize_cdr
        self.writer.write(self.connections[topic], int(round(seconds * 1e9)), serialize(message, msgtype))

    def close(self) -> None:
        self.writer.close()


def write_recording(dataset: object, out: str | Path, format: str = "ros2-mcap", content: RecordingContent = RecordingContent()) -> Path:
    """Write ``dataset`` (``io.folder.Dataset`` with images; its rig cameras need a ``topic``) as a
    recording at ``out`` in ``format`` (one of :data:`FORMATS`); returns ``out``."""
    if format not in FORMATS:
        raise DatasetError(f"{out}: unknown recording format {format!r} (expected one of {FORMATS})")
    out = Path(out)
    if out.exists():
        raise DatasetError(f"{out}: exists already (a recording is never overwritten)")
    rig = dataset.rig
    missing = [camera.name for camera in rig.cameras if not camera.topic]
    if missing:
        raise DatasetError(f"{dataset.root}: rig cameras {missing} have no topic to write their images on")
    origin = recording_time_origin(dataset, content)
    earliest = _earliest_time(dataset, content)
    if earliest + origin < 0.0:
        raise DatasetError(f"{out}: time origin {origin} s leaves stamps before 0 s (earliest {earliest:.6f} s in "
                           f"{dataset.root}); a log's time cannot be negative")
    if origin:
        logger.info("%s: stamps written %+.0f s from the dataset's times (a log's time cannot be negative)", out, origin)
    target = out
    staging = None
    if format == "mcap":  # a bare .mcap file: the storage file of a ROS 2 MCAP bag
        staging = Path(tempfile.mkdtemp(prefix="ampc_vo_mcap_"))
        target = staging / "bag"
    out.parent.mkdir(parents=True, exist_ok=True)
    sink = _Sink(target, "ros2-mcap" if format == "mcap" else format)
    events: list[tuple[float, int, str, str, object]] = []  # (log time, order, topic, msgtype, message)
    try:
        for frame in range(len(dataset)):
            for camera in rig.cameras:
                if frame in content.drop.get(camera.name, ()):
                    continue
                stamp = dataset.camera_timestamp(frame, camera.name) + origin
                compressed = camera.name in content.compressed
                msgtype = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
                # images are loaded and encoded when written (one in memory at a time)
                header_stamp = 0.0 if camera.name in content.unstamped else stamp
                message = partial(_image_message, sink.typestore, partial(dataset.load_image, frame, camera.name), header_stamp, camera.name, sink.ros1,
                                  compressed, content)
                events.append((stamp + content.delays.get(camera.topic, 0.0), len(events), camera.topic, msgtype, message))
        if content.wheel_speed is not None:
            msgtype = SPEED_TYPES[content.wheel_speed_type]
            for stamp, speed in zip(content.wheel_speed[0] + origin, content.wheel_speed[1]):
                if content.wheel_speed_type == "twist":
                    twist = sink.typestore.types["geometry_msgs/msg/Twist"](linear=_vector3(sink.typestore, speed), angular=_vector3(sink.typestore, 0.0))
                    message = sink.typestore.types[msgtype](header=_header(sink.typestore, stamp, "tractor", sink.ros1), twist=twist)
                else:
                    message = _odometry(sink.typestore, stamp, sink.ros1, speed=speed)
                events.append((stamp + content.delays.get(content.wheel_speed_topic, 0.0), len(events), content.wheel_speed_topic, msgtype, message))
        if content.pose_topic is not None:
            truth = dataset.groundtruth
            if truth is None:
                raise DatasetError(f"{dataset.root}: no groundtruth.csv to write a pose topic from")
            msgtype = POSE_TYPES[content.pose_type]
            for stamp, T in zip(truth.timestamps + origin, truth.T_world_tractor):
                if content.pose_type == "odometry":
                    message = _odometry(sink.typestore, stamp, sink.ros1, T=T)
                else:
                    message = sink.typestore.types[msgtype](header=_header(sink.typestore, stamp, "world", sink.ros1), pose=_pose(sink.typestore, T))
                events.append((stamp + content.delays.get(content.pose_topic, 0.0), len(events), content.pose_topic, msgtype, message))
        for log_time, _, topic, msgtype, message in sorted(events, key=lambda event: (event[0], event[1])):
            sink.write(topic, msgtype, log_time, message() if callable(message) else message)
    finally:
        sink.close()
    if staging is not None:
        shutil.move(str(next(target.glob("*.mcap"))), out)
        shutil.rmtree(staging, ignore_errors=True)
    return out
