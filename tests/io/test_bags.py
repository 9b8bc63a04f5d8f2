"""Recordings read without ROS (issue 15): ROS 1 bags, ROS 2 bags (sqlite3, MCAP) and bare MCAP
files written with the rosbags writers from a small dataset folder, read back as a dataset."""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from ampc_vo.errors import DatasetError
from ampc_vo.io.bag_writer import RecordingContent, recording_time_origin, write_recording
from ampc_vo.io.bags import decode_image_message, group_frames, header_stamp, is_log, read_recording
from ampc_vo.io.folder import image_relative_path, read_dataset, write_dataset
from ampc_vo.rig import replace_camera

FRAMES = 6
T0 = 1_700_000_000.0  # a realistic epoch: stamps keep nanoseconds
OFFSETS = {"front": 0.0, "left": 0.017, "rear": 0.033, "right": 0.05}
SUFFIX = {"ros1": ".bag", "mcap": ".mcap", "ros2-mcap": "", "ros2-sqlite3": ""}


@pytest.fixture(scope="module")
def folder(tmp_path_factory, default_rig):
    """6 frames of 4 unsynchronised cameras (offsets up to 50 ms) with random 640x480 images."""
    rig = dataclasses.replace(default_rig, cameras=tuple(replace_camera(c, topic=f"/cam/{c.name}/image") for c in default_rig.cameras))
    root = tmp_path_factory.mktemp("bags") / "folder"
    timestamps = T0 + 0.1 * np.arange(FRAMES)
    write_dataset(root, rig, timestamps, with_images=True, camera_timestamps={name: timestamps + offset for name, offset in OFFSETS.items()})
    rng = np.random.default_rng(1)
    for frame in range(FRAMES):
        for camera in rig.camera_names:
            path = root / image_relative_path(camera, frame)
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), rng.integers(0, 256, (48, 64), dtype=np.uint8).repeat(10, 0).repeat(10, 1))
    return read_dataset(root)


def _log(folder, tmp_path: Path, format: str, **content) -> Path:
    return write_recording(folder, tmp_path / f"log{SUFFIX[format]}", format, RecordingContent(**content))


@pytest.mark.parametrize("format", ["ros1", "ros2-sqlite3", "ros2-mcap", "mcap"])
def test_every_log_format_reads_back_the_frames_stamps_and_images(folder, tmp_path, format):
    log = _log(folder, tmp_path, format, compressed=("left",), image_format="png")
    assert is_log(log)
    recording = read_recording(log, folder.rig)
    assert len(recording) == FRAMES
    np.testing.assert_allclose(recording.timestamps, folder.timestamps, atol=1e-9)
    for camera in folder.camera_names:
        np.testing.assert_allclose(recording.camera_timestamps[camera], folder.camera_timestamps[camera], atol=1e-9)
        for frame in (0, FRAMES - 1):  # raw and PNG-compressed images decode to the stored pixels
            np.testing.assert_array_equal(recording.load_image(frame, camera), folder.load_image(frame, camera))


def test_jpeg_images_decode_close_to_the_originals(folder, tmp_path):
    recording = read_recording(_log(folder, tmp_path, "ros2-mcap", compressed=tuple(folder.camera_names), jpeg_quality=95), folder.rig)
    difference = np.abs(recording.load_image(2, "rear").astype(float) - folder.load_image(2, "rear"))
    assert 0 < difference.mean() < 3.0


def test_messages_out_of_order_dropped_images_and_a_late_camera_are_recovered(folder, tmp_path, caplog):
    # the rear topic arrives 0.25 s late (out of stamp order against the others), right loses frame 3,
    # left starts at frame 2: frames keep the reference camera's times, missing images are errors the
    # frontend recovers from, and each problem is logged once
    log = _log(folder, tmp_path, "ros1", delays={"/cam/rear/image": 0.25}, drop={"right": (3,), "left": (0, 1)})
    with caplog.at_level(logging.WARNING):
        recording = read_recording(log, folder.rig)
    assert len(recording) == FRAMES
    np.testing.assert_allclose(recording.timestamps, folder.timestamps, atol=1e-9)
    np.testing.assert_array_equal(recording.load_image(4, "rear"), folder.load_image(4, "rear"))
    with pytest.raises(DatasetError, match="frame 3: no image from camera 'right'"):
        recording.load_image(3, "right")
    with pytest.raises(DatasetError, match="no image from camera 'left'"):
        recording.load_image(0, "left")
    # a missing image's capture time is predicted from the camera's offset
    assert recording.camera_timestamps["right"][3] == pytest.approx(folder.camera_timestamps["right"][3], abs=1e-6)
    text = caplog.text
    assert "'right' 1 dropped image(s)" in text and "'left' starts late (no image in frames 0-1)" in text


def test_a_reference_gap_is_filled_and_images_are_sorted_by_stamp():
    period = 0.1
    reference = np.delete(np.arange(10) * period, [4, 5])  # two frames dropped by the camera with most images
    other = np.arange(8) * period + 0.03
    grouping = group_frames({"a": reference, "b": other[[0, 1, 2, 3, 4, 5, 6, 7]]})
    np.testing.assert_allclose(grouping.timestamps, np.arange(10) * period, atol=1e-12)
    np.testing.assert_array_equal(grouping.indices["a"], [0, 1, 2, 3, -1, -1, 4, 5, 6, 7])
    np.testing.assert_array_equal(grouping.indices["b"], [0, 1, 2, 3, 4, 5, 6, 7, -1, -1])
    assert grouping.offsets["b"] == pytest.approx(0.03)


def test_a_camera_half_a_period_late_joins_the_frames_it_belongs_to():
    # exactly half a period: the phase is ambiguous; the one that puts every image into a frame wins
    frames = np.arange(20) * 0.1
    grouping = group_frames({"a": frames, "b": frames + 0.05})
    assert np.all(grouping.indices["b"] == np.arange(20))
    assert grouping.offsets["b"] == pytest.approx(0.05)


def test_another_clock_is_an_error():
    with pytest.raises(DatasetError, match="do not overlap"):
        group_frames({"a": np.arange(10) * 0.1, "b": 100.0 + np.arange(10) * 0.1})


def test_missing_topic_no_topic_and_not_a_log_are_clear_errors(folder, tmp_path):
    log = _log(folder, tmp_path, "mcap")
    renamed = dataclasses.replace(folder.rig, cameras=(replace_camera(folder.rig.cameras[0], topic="/nothing"),) + folder.rig.cameras[1:])
    with pytest.raises(DatasetError, match=r"image topic '/nothing' is not in the log .*'/cam/front/image'"):
        read_recording(log, renamed)
    untopiced = dataclasses.replace(folder.rig, cameras=(replace_camera(folder.rig.cameras[0], topic=None),) + folder.rig.cameras[1:])
    with pytest.raises(DatasetError, match=r"\['front'\] have no 'topic'"):
        read_recording(log, untopiced)
    corrupt = tmp_path / "corrupt.bag"
    corrupt.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 64)
    with pytest.raises(DatasetError, match="corrupt.bag: cannot read the log"):
        read_recording(corrupt, folder.rig)
    with pytest.raises(DatasetError, match="not a recording"):
        read_recording(tmp_path, folder.rig)


def test_header_stamp_is_read_without_deserialising(folder, tmp_path):
    from rosbags.highlevel import AnyReader

    for format in ("ros1", "ros2-mcap"):
        log = _log(folder, tmp_path / format, format)
        with AnyReader([log]) as reader:
            for connection, _, rawdata in reader.messages():
                stamp = reader.deserialize(rawdata, connection.msgtype).header.stamp
                assert header_stamp(rawdata, reader.is2) == pytest.approx(stamp.sec + 1e-9 * stamp.nanosec, abs=1e-9)


class _Image:
    def __init__(self, array: np.ndarray, encoding: str, bigendian: bool = False, padding: int = 0):
        self.height, self.width = array.shape[:2]
        channels = 1 if array.ndim == 2 else array.shape[2]
        dtype = array.dtype.newbyteorder(">" if bigendian else "<")
        rows = array.astype(dtype).reshape(self.height, -1).view(np.uint8)
        rows = np.concatenate([rows, np.zeros((self.height, padding), np.uint8)], axis=1)
        self.step, self.data, self.encoding, self.is_bigendian = rows.shape[1], rows.reshape(-1), encoding, int(bigendian)
        assert self.step == self.width * channels * array.dtype.itemsize + padding


def test_raw_encodings_decode_to_the_same_grey_image():
    rng = np.random.default_rng(2)
    bgr = rng.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    np.testing.assert_array_equal(decode_image_message(_Image(bgr, "bgr8", padding=3), "sensor_msgs/msg/Image", "t"), grey)
    np.testing.assert_array_equal(decode_image_message(_Image(bgr[:, :, ::-1], "rgb8"), "sensor_msgs/msg/Image", "t"), grey)
    np.testing.assert_array_equal(decode_image_message(_Image(grey, "mono8", padding=2), "sensor_msgs/msg/Image", "t"), grey)
    wide = grey.astype(np.uint16) * 256 + 77  # 16-bit: the top byte
    for bigendian in (False, True):
        np.testing.assert_array_equal(decode_image_message(_Image(wide, "mono16", bigendian), "sensor_msgs/msg/Image", "t"), grey)
    np.testing.assert_array_equal(decode_image_message(_Image(bgr, "8UC3"), "sensor_msgs/msg/Image", "t"), grey)
    np.testing.assert_array_equal(decode_image_message(_Image(bgr.astype(np.uint16) * 256 + 77, "bgr16", True), "sensor_msgs/msg/Image", "t"), grey)
    with pytest.raises(DatasetError, match="encoding 'nv21' not supported"):
        decode_image_message(_Image(grey, "nv21"), "sensor_msgs/msg/Image", "t")


def test_yuv422_gives_the_luma_bytes():
    rng = np.random.default_rng(3)
    luma, chroma = rng.integers(0, 256, (4, 6), dtype=np.uint8), rng.integers(0, 256, (4, 6), dtype=np.uint8)
    uyvy = np.stack([chroma, luma], axis=2)  # U Y V Y ...: chroma in the even bytes
    yuyv = np.stack([luma, chroma], axis=2)
    np.testing.assert_array_equal(decode_image_message(_Image(uyvy, "yuv422"), "sensor_msgs/msg/Image", "t"), luma)
    np.testing.assert_array_equal(decode_image_message(_Image(yuyv, "yuv422_yuy2"), "sensor_msgs/msg/Image", "t"), luma)


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_mosaics_demosaic_to_the_scene_grey(pattern):
    """A scene of smooth colour (red rising to the right, blue downwards) sampled through each ROS
    Bayer pattern (the letters: the colours of the top-left 2x2 block, row by row) decodes to the
    scene's grey; the wrong pattern (red and blue swapped: 0.299 and 0.114 of the grey) is far off."""
    rows, columns = np.mgrid[0:48, 0:64].astype(float)
    bgr = np.stack([40 + 3 * rows, np.full_like(rows, 120.0), 20 + 3 * columns], axis=2).round().astype(np.uint8)
    channel = {"b": 0, "g": 1, "r": 2}
    mosaic = np.empty(bgr.shape[:2], np.uint8)
    for index, colour in enumerate(pattern):
        row, column = divmod(index, 2)
        mosaic[row::2, column::2] = bgr[row::2, column::2, channel[colour]]
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(float)
    inside = (slice(2, -2), slice(2, -2))
    for encoding, image in ((f"bayer_{pattern}8", mosaic), (f"bayer_{pattern}16", mosaic.astype(np.uint16) * 256)):
        decoded = decode_image_message(_Image(image, encoding), "sensor_msgs/msg/Image", "t").astype(float)
        assert np.abs(decoded - expected)[inside].max() <= 2.0, encoding
    swapped = pattern.replace("r", "x").replace("b", "r").replace("x", "b")
    wrong = decode_image_message(_Image(mosaic, f"bayer_{swapped}8"), "sensor_msgs/msg/Image", "t").astype(float)
    assert np.abs(wrong - expected)[inside].mean() > 5.0


def test_a_recording_pickles_without_its_reader_and_reads_on(folder, tmp_path):
    import pickle

    recording = read_recording(_log(folder, tmp_path, "ros2-sqlite3"), folder.rig)
    recording.load_image(0, "front")
    copy = pickle.loads(pickle.dumps(recording))
    np.testing.assert_array_equal(copy.load_image(1, "rear"), folder.load_image(1, "rear"))


def test_a_faster_camera_does_not_become_the_reference():
    # one camera at 20 Hz, two at 10 Hz: frames at 10 Hz, the fast camera's image nearest each frame
    slow = np.arange(10) * 0.1
    grouping = group_frames({"fast": np.arange(20) * 0.05 + 0.01, "a": slow, "b": slow + 0.02})
    assert grouping.reference == "a"
    np.testing.assert_array_equal(grouping.indices["fast"], np.arange(0, 20, 2))
    np.testing.assert_array_equal(grouping.indices["b"], np.arange(10))


def test_images_out_of_stamp_order_are_sorted_and_repeats_dropped(caplog):
    from ampc_vo.io.bags import _sorted_unique

    stamps = np.array([0.0, 0.2, 0.1, 0.3, 0.3, 0.4])
    logtimes = np.arange(6) * 10
    with caplog.at_level(logging.WARNING):
        sorted_stamps, sorted_logtimes, sorted_headers = _sorted_unique(stamps, logtimes, stamps + 5.0, "front", "log")
    np.testing.assert_array_equal(sorted_stamps, [0.0, 0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(sorted_logtimes, [0, 20, 10, 30, 50])  # each image keeps its own log time
    np.testing.assert_array_equal(sorted_headers, sorted_stamps + 5.0)  # ... and its own header stamp
    assert "1 image(s) out of order in the log" in caplog.text and "1 image(s) with a repeated capture time dropped" in caplog.text


def test_the_export_script_writes_a_log_and_its_rig(tiny_dataset, tmp_path):
    import importlib.util

    from ampc_vo.rig import load_rig

    spec = importlib.util.spec_from_file_location("dataset_to_log", Path(__file__).resolve().parents[2] / "scripts" / "dataset_to_log.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main([str(tiny_dataset), "--out", str(tmp_path / "drive.mcap"), "--format", "mcap", "--compressed", "--pose-topic", "/truth"]) == 0
    rig = load_rig(tmp_path / "drive.mcap.rig.yaml")
    assert [camera.topic for camera in rig.cameras] == [f"/camera/{name}/image" for name in rig.camera_names]
    recording = read_recording(tmp_path / "drive.mcap", rig)
    assert len(recording) == 5 and recording.load_image(4, "rear").shape == (480, 640)
    assert script.main([str(tiny_dataset), "--out", str(tmp_path / "drive.mcap")]) == 2  # never overwritten


def test_frames_extend_where_the_reference_camera_has_not_started_or_has_stopped():
    # a and b have 10 images each (a is the reference): a covers frames 0-9, b frames 3-12 (30 ms
    # later in each): frames 10-12 exist for b, and the reference is missing there
    period = 0.1
    a = np.arange(10) * period
    b = (np.arange(10) + 3) * period + 0.03
    grouping = group_frames({"a": a, "b": b})
    assert grouping.reference == "a"
    np.testing.assert_allclose(grouping.timestamps, np.arange(13) * period, atol=1e-9)
    np.testing.assert_array_equal(grouping.indices["a"], list(range(10)) + [-1, -1, -1])
    np.testing.assert_array_equal(grouping.indices["b"], [-1, -1, -1] + list(range(10)))


def test_a_recordings_frames_are_read_in_one_thread_and_decoded_in_parallel(folder, tmp_path, monkeypatch):
    import threading

    from ampc_vo.io import bags
    from ampc_vo.io.frame_images import FrameImageReader

    recording = read_recording(_log(folder, tmp_path, "mcap", compressed=("left", "rear"), image_format="png", drop={"right": (3,)}), folder.rig)
    opened, open_reader = [], bags.open_reader
    monkeypatch.setattr(bags, "open_reader", lambda path: opened.append(threading.current_thread().name) or open_reader(path))
    with FrameImageReader(recording, range(FRAMES), threads=3) as reader:
        for frame in range(FRAMES):
            images = reader.take(frame).images
            for camera in folder.camera_names:
                if (camera, frame) == ("right", 3):
                    assert images[camera] is None
                else:
                    np.testing.assert_array_equal(images[camera], folder.load_image(frame, camera))
    assert len(opened) == 1 and opened[0].startswith("frame-reader")  # the log is opened and read by the reading thread only


def test_a_camera_firing_before_time_zero_is_written_on_a_shifted_clock(tmp_path, default_rig):
    # a realistic route's camera captures 1 ms before the first frame time: a log's time cannot be
    # negative, so every stamp moves by a whole second and reads back with the same spacing
    rig = dataclasses.replace(default_rig, cameras=tuple(replace_camera(c, topic=f"/cam/{c.name}/image") for c in default_rig.cameras))
    timestamps = 0.1 * np.arange(3)
    offsets = {"front": -0.001, "left": 0.02}
    write_dataset(tmp_path / "folder", rig, timestamps, with_images=True, camera_timestamps={name: timestamps + offset for name, offset in offsets.items()})
    for frame in range(3):
        for camera in rig.camera_names:
            path = tmp_path / "folder" / image_relative_path(camera, frame)
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), np.full((480, 640), 10 * frame, np.uint8))
    folder = read_dataset(tmp_path / "folder")
    assert recording_time_origin(folder) == 1.0 and recording_time_origin(folder, RecordingContent(time_origin=T0)) == T0
    recording = read_recording(_log(folder, tmp_path, "mcap"), folder.rig)
    np.testing.assert_allclose(recording.camera_timestamps["front"], 1.0 + timestamps - 0.001, atol=1e-9)
    np.testing.assert_allclose(recording.camera_timestamps["left"], 1.0 + timestamps + 0.02, atol=1e-9)
    with pytest.raises(DatasetError, match="time origin 0.0 s leaves stamps before 0 s"):
        write_recording(folder, tmp_path / "zero.mcap", "mcap", RecordingContent(time_origin=0.0))
    assert not (tmp_path / "zero.mcap").exists()


def test_a_camera_without_header_stamps_takes_the_log_times(folder, tmp_path, caplog):
    """A driver that leaves the header stamp at 0: the camera's capture times are the log's receive
    times (here the capture time plus a 20 ms transport delay), with a warning, and its images are
    found and decoded; without the fallback every image but one was a repeated stamp."""
    topic = folder.rig.camera("left").topic or "/left/image_raw"
    log = _log(folder, tmp_path, "ros2-mcap", unstamped=("left",), delays={topic: 0.02})
    with caplog.at_level("WARNING"):
        recording = read_recording(log, folder.rig)
    assert any("have no header stamp" in record.message and "'left'" in record.message for record in caplog.records)
    assert len(recording) == FRAMES
    np.testing.assert_allclose(recording.camera_timestamps["left"], folder.camera_timestamps["left"] + 0.02, atol=1e-6)
    for camera in folder.camera_names:
        if camera != "left":
            np.testing.assert_allclose(recording.camera_timestamps[camera], folder.camera_timestamps[camera], atol=1e-9)
    np.testing.assert_array_equal(recording.load_image(FRAMES - 1, "left"), folder.load_image(FRAMES - 1, "left"))


def test_a_few_unset_stamps_are_dropped_and_most_unset_take_the_log_times(caplog):
    from ampc_vo.io.bags import capture_times

    headers = np.array([1.0, 0.0, 1.1, 1.2])
    logtimes = np.array([1_005_000_000, 1_055_000_000, 1_105_000_000, 1_205_000_000])
    with caplog.at_level("WARNING"):
        times, kept_logtimes, kept_headers = capture_times(headers, logtimes, "left", "t")
    np.testing.assert_array_equal(times, [1.0, 1.1, 1.2])
    np.testing.assert_array_equal(kept_logtimes, logtimes[[0, 2, 3]])
    assert "1 image(s) without a header stamp (0) dropped" in caplog.text
    times, _, kept_headers = capture_times(np.zeros(4), logtimes, "left", "t")
    np.testing.assert_allclose(times, logtimes * 1e-9)
    np.testing.assert_array_equal(kept_headers, np.zeros(4))

