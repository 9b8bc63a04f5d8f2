"""Recordings end to end (issue 15): a rendered route with unsynchronised cameras written as ROS 2
MCAP (compressed images) and ROS 1 bags, calibrated through a Kalibr camchain, runs as accurately as
the same sequence from our dataset folder; the batch runs a fleet of logs locally and on Ray."""
from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ampc_vo.config import VoConfig
from ampc_vo.io.bag_writer import RecordingContent, write_recording
from ampc_vo.io.folder import read_dataset
from ampc_vo.io.wheel_speed import read_wheel_speed_csv
from ampc_vo.tools.recordings import compare_log_with_folder, render_unsynchronised

ROOT = Path(__file__).resolve().parents[2]
CI_ROUTE = ROOT / "configs" / "sim" / "ci_short.yaml"
OFFSETS = {"front": 0.0, "left": 0.017, "rear": 0.033, "right": 0.05}  # up to 50 ms (half a frame at 10 Hz)


@pytest.fixture(scope="module")
def unsynchronised(tmp_path_factory) -> Path:
    """The CI route (~6 s) rendered with every camera at its own capture time."""
    return render_unsynchronised(CI_ROUTE, tmp_path_factory.mktemp("unsynchronised") / "folder", OFFSETS)


def test_the_folder_keeps_each_cameras_capture_time(unsynchronised):
    dataset = read_dataset(unsynchronised)
    for camera, offset in OFFSETS.items():
        captured = dataset.camera_timestamps.get(camera, dataset.timestamps)  # no column: the frame time
        np.testing.assert_allclose(captured - dataset.timestamps, offset, atol=1e-9)
    assert (unsynchronised / "wheel_speed.csv").is_file()


@pytest.mark.slow
def test_mcap_and_ros1_logs_through_kalibr_are_as_accurate_as_the_folder(unsynchronised, tmp_path):
    """Issue 15: a log through a Kalibr camchain is as accurate as the dataset folder. With raw
    images (ROS 1) the log carries the same pixels, so it must match the folder's figures within
    10 %: capture times, frame grouping and the Kalibr round trip lose nothing. With JPEG (q95)
    images (ROS 2 MCAP) the tracks differ: on this 6 s route the hitch RMSE moved by up to 0.031
    deg (0.084 deg from the PNG folder, 0.115 deg from the JPEG log), so the bound is 10 % or
    0.05 deg and 2 cm of ATE, whichever is larger; a wrong time offset or extrinsic costs degrees."""
    raw = compare_log_with_folder(unsynchronised, tmp_path / "raw", formats=("ros1",), compressed=False)
    folder = raw.folder
    assert folder.tractor_ate_m < 0.5 and folder.hitch_rmse_deg < 1.0  # the folder run itself works
    metrics = raw.logs["ros1"]
    assert metrics.tractor_ate_m <= 1.1 * folder.tractor_ate_m and metrics.hitch_rmse_deg <= 1.1 * folder.hitch_rmse_deg
    assert metrics.frames >= folder.frames - 1
    compressed = compare_log_with_folder(unsynchronised, tmp_path / "jpeg", formats=("ros2-mcap",), compressed=True)
    metrics = compressed.logs["ros2-mcap"]
    assert metrics.tractor_ate_m <= max(1.1 * folder.tractor_ate_m, folder.tractor_ate_m + 0.02)
    assert metrics.hitch_rmse_deg <= max(1.1 * folder.hitch_rmse_deg, folder.hitch_rmse_deg + 0.05)
    assert metrics.frames >= folder.frames - 1


@pytest.fixture(scope="module")
def fleet(unsynchronised, tmp_path_factory) -> list[Path]:
    """Four logs: three formats of the first 25 frames with a pose topic, and a corrupt one."""
    import shutil

    from ampc_vo.io.folder import FRAMES_FILE, GROUNDTRUTH_FILE

    root = tmp_path_factory.mktemp("fleet")
    short = root / "short"
    shutil.copytree(unsynchronised, short)
    (short / "measurements.npz").unlink(missing_ok=True)  # the images only: the logs carry no bearings
    for name in (FRAMES_FILE, GROUNDTRUTH_FILE):  # keep the header and 25 frames
        lines = (short / name).read_text().splitlines()
        (short / name).write_text("\n".join(lines[:26]) + "\n")
    dataset = read_dataset(short)
    wheel = read_wheel_speed_csv(short / "wheel_speed.csv")
    content = RecordingContent(compressed=("left", "rear"), pose_topic="/truth/odometry", wheel_speed=(wheel.timestamps, wheel.speed))
    logs = [write_recording(dataset, root / "drive_a.mcap", "mcap", content),
            write_recording(dataset, root / "drive_b.bag", "ros1", content),
            write_recording(dataset, root / "drive_c", "ros2-sqlite3", content)]
    corrupt = root / "drive_d.bag"
    corrupt.write_bytes(logs[1].read_bytes()[:5000])
    truth = dataset.groundtruth  # drive_b's hitch-angle ground truth beside it
    (root / "drive_b.hitch.csv").write_text("timestamp,hitch_angle\n" + "".join(f"{float(t)!r},{float(a)!r}\n" for t, a in zip(truth.timestamps, truth.hitch_angle)))
    return logs + [corrupt]


def _summary(path: Path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.slow
def test_a_batch_locally_and_on_ray_gives_the_same_summary_and_reports_the_corrupt_log(fleet, unsynchronised, tmp_path):
    pytest.importorskip("ray")
    rig = unsynchronised / "rig.yaml"
    command = [sys.executable, str(ROOT / "scripts" / "batch_odometry.py"), *map(str, fleet), "--rig", str(rig),
               "--groundtruth-topic", "/truth/odometry", "--workers", "2", "--no-progress"]
    local = subprocess.run(command + ["--out", str(tmp_path / "local")], capture_output=True, text=True, timeout=600)
    on_ray = subprocess.run(command + ["--out", str(tmp_path / "ray"), "--ray"], capture_output=True, text=True, timeout=600)
    for result in (local, on_ray):
        assert result.returncode == 1, result.stderr  # one log failed
        assert "drive_d: failed: " in result.stderr and "3 of 4 logs done" in result.stdout
    rows = {run: _summary(tmp_path / run / "summary.csv") for run in ("local", "ray")}
    assert [row["log"] for row in rows["local"]] == ["drive_a", "drive_b", "drive_c", "drive_d"]
    for row_local, row_ray in zip(rows["local"], rows["ray"]):
        for column in row_local:
            if column != "frames_per_second":  # wall time
                assert row_local[column] == row_ray[column], (row_local["log"], column)
    for row in rows["local"][:3]:
        assert row["status"] == "ok" and int(row["frames"]) == 25 and float(row["tractor_ate_m"]) < 0.5
    assert [row["hitch_rmse_deg"] != "" for row in rows["local"]] == [False, True, False, False]  # drive_b.hitch.csv
    assert float(rows["local"][1]["hitch_rmse_deg"]) < 1.0 and float(rows["local"][1]["trailer_ate_m"]) < 0.5
    # the same images in three formats, two cameras JPEG-compressed in each: the same estimate
    assert rows["local"][0]["tractor_ate_m"] == rows["local"][1]["tractor_ate_m"] == rows["local"][2]["tractor_ate_m"]
    # a rerun skips the logs already done and retries the failed one
    again = subprocess.run(command + ["--out", str(tmp_path / "local")], capture_output=True, text=True, timeout=600)
    assert again.returncode == 1 and _summary(tmp_path / "local" / "summary.csv") == rows["local"]


@pytest.mark.slow
def test_run_odometry_and_evaluate_take_a_log_with_wheel_speed_and_a_pose_topic(fleet, unsynchronised, tmp_path):
    log, rig = fleet[0], unsynchronised / "rig.yaml"
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "run_odometry.py"), str(log), "--rig", str(rig), "--out", str(tmp_path / "run"),
                          "--wheel-speed", "/vehicle/wheel_speed", "--no-progress"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert "frames 25" in run.stdout and "wheel speed, 55 samples" in run.stderr  # the folder's whole wheel_speed.csv
    evaluation = subprocess.run([sys.executable, str(ROOT / "scripts" / "evaluate.py"), str(tmp_path / "run"), str(log), "--groundtruth-topic",
                                 "/truth/odometry", "--rig", str(rig), "--no-plot"], capture_output=True, text=True, timeout=300)
    assert evaluation.returncode == 0, evaluation.stderr
    ate = float(next(line.split()[1] for line in evaluation.stdout.splitlines() if line.startswith("tractor_ate_m")))
    assert 0.0 < ate < 0.5
    missing = subprocess.run([sys.executable, str(ROOT / "scripts" / "run_odometry.py"), str(log), "--out", str(tmp_path / "x")],
                             capture_output=True, text=True, timeout=300)
    assert missing.returncode == 2 and "needs a rig (--rig RIG.yaml)" in missing.stderr
