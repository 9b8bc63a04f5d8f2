"""Dataset folder (DESIGN 5): write/read round trip and one clear DatasetError per bad input."""
from __future__ import annotations

import csv
import shutil

import cv2
import numpy as np
import pytest

from ampc_vo.io.folder import GROUNDTRUTH_COLUMNS, read_dataset, write_dataset
from ampc_vo.errors import DatasetError


def _rewrite_csv(path, transform):
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    rows = transform(rows)
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows(rows)


def test_round_trip_identical_poses_and_rig(tiny_dataset, default_rig, short_trajectory):
    dataset = read_dataset(tiny_dataset, check_images=True)
    assert dataset.has_images and len(dataset) == 5
    assert dataset.camera_names == tuple(default_rig.camera_names)
    assert dataset.rig.bodies == default_rig.bodies
    for camera in default_rig.cameras:
        assert np.max(np.abs(dataset.rig.camera(camera.name).T_body_camera - camera.T_body_camera)) < 1e-15
    truth = dataset.groundtruth
    assert np.array_equal(truth.timestamps, short_trajectory.timestamps[:5])
    assert np.array_equal(truth.hitch_angle, short_trajectory.hitch_angle[:5])
    assert np.max(np.abs(truth.T_world_tractor - short_trajectory.T_world_tractor[:5])) < 1e-15
    assert np.max(np.abs(truth.T_world_trailer - short_trajectory.T_world_trailer[:5])) < 1e-15
    image = dataset.load_image(3, "rear")
    assert image.dtype == np.uint8 and image.shape == (480, 640)
    assert dataset.image_path(3, "rear") == tiny_dataset / "images" / "rear" / "000003.png"


def test_groundtruth_header_is_exactly_the_documented_one(tiny_dataset):
    header = (tiny_dataset / "groundtruth.csv").read_text().splitlines()[0]
    assert header == "timestamp,tractor_x,tractor_y,tractor_z,tractor_qx,tractor_qy,tractor_qz,tractor_qw," \
                     "trailer_x,trailer_y,trailer_z,trailer_qx,trailer_qy,trailer_qz,trailer_qw,hitch_angle"
    assert tuple(header.split(",")) == GROUNDTRUTH_COLUMNS
    assert (tiny_dataset / "frames.csv").read_text().splitlines()[0] == "frame,timestamp,front,left,rear,right"


def test_dataset_without_images_is_valid(tmp_path, default_rig, short_trajectory):
    root = write_dataset(tmp_path / "bearings_only", default_rig, short_trajectory.timestamps, groundtruth=short_trajectory)
    dataset = read_dataset(root)
    assert not dataset.has_images and dataset.measurements is None
    with pytest.raises(DatasetError, match="no image"):
        dataset.load_image(0, "front")


def test_images_folder_absent_reads_as_no_images(tiny_dataset):
    shutil.rmtree(tiny_dataset / "images")
    assert not read_dataset(tiny_dataset).has_images


def test_missing_rig(tiny_dataset):
    (tiny_dataset / "rig.yaml").unlink()
    with pytest.raises(DatasetError, match=r"rig\.yaml: file missing"):
        read_dataset(tiny_dataset)


def test_missing_frames_file(tiny_dataset):
    (tiny_dataset / "frames.csv").unlink()
    with pytest.raises(DatasetError, match=r"frames\.csv: file missing"):
        read_dataset(tiny_dataset)


def test_missing_image(tiny_dataset):
    (tiny_dataset / "images" / "left" / "000002.png").unlink()
    with pytest.raises(DatasetError, match=r"images/left/000002\.png: image file missing"):
        read_dataset(tiny_dataset)


def test_corrupt_image(tiny_dataset):
    (tiny_dataset / "images" / "right" / "000001.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    read_dataset(tiny_dataset)  # existence only by default: decoding is lazy
    with pytest.raises(DatasetError, match=r"images/right/000001\.png: image cannot be decoded"):
        read_dataset(tiny_dataset, check_images=True)
    with pytest.raises(DatasetError, match=r"000001\.png: image cannot be decoded"):
        read_dataset(tiny_dataset).load_image(1, "right")


def test_image_size_not_matching_the_rig(tiny_dataset):
    cv2.imwrite(str(tiny_dataset / "images" / "front" / "000004.png"), np.zeros((240, 320), np.uint8))
    with pytest.raises(DatasetError, match=r"000004\.png: image is 320x240 but rig.yaml says camera 'front' is 640x480"):
        read_dataset(tiny_dataset, check_images=True)
    with pytest.raises(DatasetError, match="320x240"):
        read_dataset(tiny_dataset).load_image(4, "front")


def test_a_whole_camera_of_another_size_is_an_error_up_front(tiny_dataset):
    """Checked on its first readable image (it used to be a warning at every frame and a run
    without that camera); a corrupt first image is left to the run, which skips it."""
    (tiny_dataset / "images" / "left" / "000000.png").write_bytes(b"not a png")
    for frame in range(1, 5):
        cv2.imwrite(str(tiny_dataset / "images" / "left" / f"{frame:06d}.png"), np.zeros((240, 320), np.uint8))
    with pytest.raises(DatasetError, match=r"left/000001\.png: image is 320x240 but rig.yaml says camera 'left' is 640x480"):
        read_dataset(tiny_dataset, allow_missing_images=True)


def test_twelve_bit_data_in_sixteen_bit_images_is_flagged(tiny_dataset, caplog):
    """12-bit data in 16-bit PNGs reads as 8 bit with 16 grey levels: a warning names the file;
    full-range 16-bit images (and 8-bit ones) pass silently."""
    rng = np.random.default_rng(0)
    path = tiny_dataset / "images" / "rear" / "000000.png"
    cv2.imwrite(str(path), rng.integers(0, 4096, (480, 640)).astype(np.uint16))
    with caplog.at_level("WARNING"):
        read_dataset(tiny_dataset)
    assert "rear/000000.png: 16-bit image whose values stay below 4096" in caplog.text
    caplog.clear()
    cv2.imwrite(str(path), rng.integers(0, 65536, (480, 640)).astype(np.uint16))
    with caplog.at_level("WARNING"):
        read_dataset(tiny_dataset)
    assert "16-bit" not in caplog.text


def test_non_increasing_timestamps(tiny_dataset):
    def swap(rows):
        rows[3][1], rows[4][1] = rows[4][1], rows[3][1]
        return rows

    _rewrite_csv(tiny_dataset / "frames.csv", swap)
    with pytest.raises(DatasetError, match=r"frames\.csv: timestamps not strictly increasing at line 5"):
        read_dataset(tiny_dataset)


def test_camera_name_mismatch(tiny_dataset):
    def rename(rows):
        rows[0][2] = "windscreen"
        return rows

    _rewrite_csv(tiny_dataset / "frames.csv", rename)
    with pytest.raises(DatasetError, match=r"frames\.csv: camera columns .*windscreen.* do not match the rig's cameras"):
        read_dataset(tiny_dataset)


def test_groundtruth_length_mismatch(tiny_dataset):
    _rewrite_csv(tiny_dataset / "groundtruth.csv", lambda rows: rows[:-1])
    with pytest.raises(DatasetError, match=r"groundtruth\.csv: 4 rows but frames\.csv has 5 frames"):
        read_dataset(tiny_dataset)


def test_groundtruth_timestamp_mismatch(tiny_dataset):
    def shift(rows):
        rows[2][0] = "12.5"
        return rows

    _rewrite_csv(tiny_dataset / "groundtruth.csv", shift)
    with pytest.raises(DatasetError, match=r"groundtruth\.csv: line 3: timestamp 12\.5 does not match"):
        read_dataset(tiny_dataset)


def test_groundtruth_bad_header_and_numbers(tiny_dataset):
    def rename(rows):
        rows[0][1] = "x"
        return rows

    _rewrite_csv(tiny_dataset / "groundtruth.csv", rename)
    with pytest.raises(DatasetError, match=r"groundtruth\.csv: header must be timestamp,tractor_x"):
        read_dataset(tiny_dataset)


def test_frames_with_a_non_number(tiny_dataset):
    def corrupt(rows):
        rows[2][1] = "soon"
        return rows

    _rewrite_csv(tiny_dataset / "frames.csv", corrupt)
    with pytest.raises(DatasetError, match=r"frames\.csv: line 3: not a number"):
        read_dataset(tiny_dataset)


def test_missing_folder(tmp_path):
    with pytest.raises(DatasetError, match="dataset folder not found"):
        read_dataset(tmp_path / "nothing")


def _measurements(timestamps, camera_names):
    from ampc_vo.io.measurements import Measurements

    empty = np.zeros(0, np.int64)
    return Measurements(frame=empty, camera_index=empty, track_id=empty, landmark_id=empty, pixel=np.zeros((0, 2)), pixel_clean=np.zeros((0, 2)),
                        is_outlier=np.zeros(0, bool), camera_names=tuple(camera_names), landmarks=np.zeros((0, 3)), timestamps=np.asarray(timestamps, float))


def test_measurement_timestamps_must_match_the_frames(tmp_path, default_rig, short_trajectory):
    """The bearing source runs on the measurements' timestamps: ones that disagree with frames.csv
    gave estimates at other times than the ground truth (a wrong ATE, no error)."""
    from ampc_vo.io.measurements import MEASUREMENTS_FILE, save_measurements

    times = short_trajectory.timestamps
    root = write_dataset(tmp_path / "bearings", default_rig, times, groundtruth=short_trajectory,
                         measurements=_measurements(times * 2.0, default_rig.camera_names))
    with pytest.raises(DatasetError, match=r"measurements\.npz: frame 1: timestamp .* does not match frames\.csv timestamp"):
        read_dataset(root)
    save_measurements(_measurements(np.arange(len(times), dtype=float), default_rig.camera_names), root / MEASUREMENTS_FILE)  # none in the file
    np.testing.assert_array_equal(read_dataset(root).measurements.timestamps, times)


def test_per_camera_capture_times_round_trip(tmp_path, default_rig, short_trajectory):
    """frames.csv ``<camera>_timestamp`` columns (DESIGN section 5): written for some cameras, read
    back exactly; cameras without a column use the frame's timestamp."""
    timestamps = short_trajectory.timestamps
    offsets = {"front": 0.012, "rear": -0.031}
    camera_timestamps = {name: timestamps + offset for name, offset in offsets.items()}
    root = write_dataset(tmp_path / "dataset", default_rig, timestamps, camera_timestamps=camera_timestamps)
    header = (root / "frames.csv").read_text().splitlines()[0].split(",")
    assert header[-2:] == ["front_timestamp", "rear_timestamp"]
    dataset = read_dataset(root)
    assert set(dataset.camera_timestamps) == {"front", "rear"}
    np.testing.assert_array_equal(dataset.camera_timestamps["rear"], timestamps - 0.031)
    assert dataset.camera_timestamp(3, "front") == timestamps[3] + 0.012
    assert dataset.camera_timestamp(3, "left") == timestamps[3]


@pytest.mark.parametrize("offset, problem", [(0.8, "s from the frame's timestamp"), (float("nan"), "capture times must be finite")])
def test_implausible_capture_times_are_refused(tmp_path, default_rig, short_trajectory, offset, problem):
    timestamps = short_trajectory.timestamps
    times = timestamps.copy()
    times[4] += offset
    root = write_dataset(tmp_path / "dataset", default_rig, timestamps, camera_timestamps={"left": times})
    with pytest.raises(DatasetError, match=problem):
        read_dataset(root)
