"""Fault injection (issue 14): every listed fault class, through the command-line tools where a
user meets it, asserting the exit code (or the error) AND its message; one test per listed case.

The numbers in the headings are the issue's list. Signals (4) run the real script in a process
of its own on rendered images and check by PID that the frontend worker and multiprocessing's
resource tracker are gone afterwards.
"""
from __future__ import annotations

import errno
import importlib.util
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from ampc_vo.config import config_from_dict
from ampc_vo.errors import ConfigError, DatasetError
from ampc_vo.geometry import ROTATION_TOLERANCE, orthonormality_error
from ampc_vo.io.folder import FRAMES_FILE, RIG_FILE, image_relative_path, read_dataset, write_dataset
from ampc_vo.io.kitti import load_kitti
from ampc_vo.io.measurements import MEASUREMENTS_FILE, load_measurements
from ampc_vo.io.outputs import OutputWriter, read_tum
from ampc_vo.io.run_folder import LOCK_FILE, RunFolder, read_run
from ampc_vo.rig import load_rig
from ampc_vo.sim.simulation import simulate_dataset
from ampc_vo.tools.processes import run_helpers, wait_gone

ROOT = Path(__file__).resolve().parents[2]
CI_ROUTE = ROOT / "configs" / "sim" / "ci_short.yaml"
KITTI_CLIP = Path(__file__).resolve().parents[3] / "shared" / "data" / "kitti-clip"
needs_clip = pytest.mark.skipif(not KITTI_CLIP.is_dir(), reason=f"KITTI clip not found at {KITTI_CLIP}")


def _script(name: str):
    spec = importlib.util.spec_from_file_location(f"script_{name}", ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


run_odometry = _script("run_odometry").main
evaluate_cli = _script("evaluate").main


def _last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if lines else ""


def _pose_rows(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line and not line.startswith("#"))


@pytest.fixture(scope="module")
def bearings(tmp_path_factory) -> Path:
    """The CI route as a dataset folder with simulated bearings only (no images)."""
    folder = tmp_path_factory.mktemp("bearings") / "ci_short"
    simulate_dataset(CI_ROUTE, folder, with_images=False)
    return folder


@pytest.fixture(scope="module")
def bearing_run(bearings, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bearing_run")
    assert run_odometry([str(bearings), "--out", str(out), "--no-progress"]) == 0
    return out


def _copy_dataset(source: Path, target: Path) -> Path:
    shutil.copytree(source, target)
    return target


def _frames_csv(folder: Path) -> list[list[str]]:
    return [line.split(",") for line in (folder / FRAMES_FILE).read_text().splitlines()]


def _write_frames_csv(folder: Path, rows: list[list[str]], prefix: str = "") -> None:
    (folder / FRAMES_FILE).write_text(prefix + "\n".join(",".join(row) for row in rows) + "\n", encoding="utf-8")


# ---------------------------------------------------------------------- 1. rounded quaternions
def test_1_a_rig_with_quaternions_rounded_to_6_decimals_runs_to_the_end(bearings, tmp_path, capsys):
    """The rig's quaternions as people type them (6 decimals): normalised on load, so the factor
    constructors' rigid-transform check (the same ROTATION_TOLERANCE) passes at every frame."""
    folder = _copy_dataset(bearings, tmp_path / "rounded")
    raw = yaml.safe_load((folder / RIG_FILE).read_text())
    for camera in raw["cameras"]:
        camera["T_body_camera"]["quaternion"] = [round(value, 6) for value in camera["T_body_camera"]["quaternion"]]
    (folder / RIG_FILE).write_text(yaml.safe_dump(raw))
    rig = load_rig(folder / RIG_FILE)
    assert max(orthonormality_error(camera.R_body_camera) for camera in rig.cameras) < 1e-12
    out = tmp_path / "out"
    assert run_odometry([str(folder), "--out", str(out), "--no-progress"]) == 0, capsys.readouterr().err
    assert _pose_rows(out / "tractor.tum") >= 10
    # beyond the tolerance it is a typo, with the field named
    raw["cameras"][0]["T_body_camera"]["quaternion"][0] += 10 * ROTATION_TOLERANCE
    (folder / RIG_FILE).write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError, match=r"cameras\[0\]\.T_body_camera\.quaternion: not a unit quaternion"):
        load_rig(folder / RIG_FILE)


def test_1_the_factor_check_uses_the_same_rotation_tolerance():
    from factors._checks import check_rigid_transform

    rotation = cv2.Rodrigues(np.array([0.3, -0.2, 0.1]))[0]
    rounded = np.eye(4)
    rounded[:3, :3] = np.round(rotation, 4)  # orthonormal to about 1e-4: accepted and projected
    assert orthonormality_error(check_rigid_transform(rounded, "T")[:3, :3]) < 1e-12
    broken = np.eye(4)
    broken[:3, :3] = rotation * (1.0 + 5 * ROTATION_TOLERANCE)
    with pytest.raises(ValueError, match="not a rigid transform"):
        check_rigid_transform(broken, "T")


# ---------------------------------------------------------------------- 2. reused --out folder
def test_2_a_tractor_only_run_into_a_used_folder_leaves_no_trailer_files_of_the_earlier_run(bearings, bearing_run, tmp_path, capsys):
    out = tmp_path / "reused"
    shutil.copytree(bearing_run, out)
    earlier = read_run(out).run_id
    assert (out / "trailer.tum").is_file() and (out / "hitch.csv").is_file()
    assert run_odometry([str(bearings), "--out", str(out), "--mode", "tractor_only", "--no-progress"]) == 0, capsys.readouterr().err
    assert not (out / "trailer.tum").exists() and not (out / "hitch.csv").exists()
    record = read_run(out)
    assert record.run_id != earlier and record.state == "done" and "trailer.tum" not in record.files
    assert evaluate_cli([str(out), str(bearings), "--no-plot"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["hitch_rmse_deg"] is None and metrics["trailer_ate_m"] is None and metrics["run_id"] == record.run_id


def test_2_a_stale_file_copied_in_from_another_run_is_refused(bearings, bearing_run, tmp_path, capsys):
    out = tmp_path / "tractor_only"
    assert run_odometry([str(bearings), "--out", str(out), "--mode", "tractor_only", "--no-progress"]) == 0
    shutil.copy(bearing_run / "hitch.csv", out / "hitch.csv")
    capsys.readouterr()
    assert evaluate_cli([str(out), str(bearings), "--no-plot"]) == 2
    assert "hitch.csv: not written by the run recorded in" in _last_line(capsys.readouterr().err)
    assert not (out / "metrics.json").exists()


def test_2_after_a_killed_run_the_old_timing_json_is_gone(bearings, bearing_run, tmp_path, caplog):
    """A run killed (SIGKILL) leaves run.json 'running' and a lock of a dead PID; the earlier
    run's timing.json was removed when it started, so evaluation cannot read its numbers."""
    from ampc_vo.tools.evaluation import evaluate_output
    from ampc_vo.io.datasets import load_groundtruth

    out = tmp_path / "killed"
    shutil.copytree(bearing_run, out)
    assert (out / "timing.json").is_file()
    run = RunFolder(out).__enter__()  # a run that starts ...
    with OutputWriter(out, run=run) as writer:
        for k, estimate in enumerate(read_tum(bearing_run / "tractor.tum").poses[:5]):
            writer.write(0.1 * k, estimate)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock = json.loads((out / LOCK_FILE).read_text())
    (out / LOCK_FILE).write_text(json.dumps(lock | {"pid": dead.pid}))  # ... and is killed
    assert not (out / "timing.json").exists()
    evaluation = evaluate_output(out, load_groundtruth(bearings))
    assert evaluation.metrics.seconds_per_frame is None and evaluation.metrics.frames == 5
    assert "did not end (killed?)" in caplog.text


def test_2_a_second_run_into_a_folder_in_use_is_refused(bearings, tmp_path, capsys):
    out = tmp_path / "busy"
    with RunFolder(out):  # this (live) process holds the folder
        assert run_odometry([str(bearings), "--out", str(out), "--no-progress"]) == 2
        assert f"in use by another run (PID {os.getpid()}" in _last_line(capsys.readouterr().err)
        assert evaluate_cli([str(out), str(bearings)]) == 2
        assert "a run is still writing there" in _last_line(capsys.readouterr().err)
    assert not (out / LOCK_FILE).exists()


def test_2_two_runs_started_at_once_into_one_folder_one_is_refused(bearings, tmp_path):
    out = tmp_path / "race"
    command = [sys.executable, str(ROOT / "scripts" / "run_odometry.py"), str(bearings), "--out", str(out), "--no-progress"]
    runs = [subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT) for _ in range(2)]
    results = sorted((run.wait(timeout=300), run.communicate()[1]) for run in runs)
    assert [code for code, _ in results] == [0, 2], results
    assert "in use by another run (PID " in _last_line(results[1][1])
    record = read_run(out)
    assert record.state == "done" and record.pid in [run.pid for run in runs]
    assert all(read_run(out).run_id in (out / name).read_text() for name in ("tractor.tum", "trailer.tum", "hitch.csv", "timing.json"))


def test_2_a_lock_left_by_a_killed_run_is_taken_over(bearings, tmp_path, capsys, caplog):
    out = tmp_path / "stale_lock"
    out.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (out / LOCK_FILE).write_text(json.dumps({"pid": dead.pid, "host": os.uname().nodename, "start_ticks": None, "run_id": "x"}))
    assert run_odometry([str(bearings), "--out", str(out), "--no-progress", "--stop", "30"]) == 0, capsys.readouterr().err
    assert "taking over the lock of a run that no longer exists" in caplog.text
    assert read_run(out).state == "done" and not (out / LOCK_FILE).exists()


# ---------------------------------------------------------------------- 3. timestamp units
@pytest.mark.parametrize("unit, factor, hint", [("milliseconds", 1e3, "in milliseconds? then it is 0.1 s"),
                                                ("nanoseconds", 1e9, "in nanoseconds? then it is 0.1 s")])
def test_3_timestamps_in_milliseconds_or_nanoseconds_are_refused(bearings, tmp_path, capsys, unit, factor, hint):
    folder = _copy_dataset(bearings, tmp_path / unit)
    rows = _frames_csv(folder)
    for row in rows[1:]:
        row[1] = repr(float(row[1]) * factor)
    _write_frames_csv(folder, rows)
    (folder / "groundtruth.csv").unlink()
    (folder / MEASUREMENTS_FILE).unlink()
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    message = _last_line(capsys.readouterr().err)
    assert "frames.csv: timestamp: median frame interval" in message and hint in message
    assert not (tmp_path / "out").exists()


@needs_clip
def test_3_kitti_times_and_measurement_timestamps_in_milliseconds_are_refused(bearings, tmp_path):
    from tests.io.test_kitti import link_clip

    folder = link_clip(tmp_path / "kitti")
    np.savetxt(folder / "times.txt", np.arange(51) * 100.0)
    with pytest.raises(DatasetError, match=r"times.txt: median frame interval 100 s.*in milliseconds\? then it is 0.1 s"):
        load_kitti(folder)
    with np.load(bearings / MEASUREMENTS_FILE) as archive:
        data = dict(archive)
    np.savez(tmp_path / MEASUREMENTS_FILE, **(data | {"timestamps": data["timestamps"] * 1e3}))
    with pytest.raises(DatasetError, match=r"measurements.npz: timestamps: median frame interval.*in milliseconds\?"):
        load_measurements(tmp_path / MEASUREMENTS_FILE)


def test_3_a_gap_in_the_frame_times_is_a_warning(bearings, tmp_path, caplog):
    folder = _copy_dataset(bearings, tmp_path / "gap")
    rows = _frames_csv(folder)
    for row in rows[21:]:
        row[1] = repr(float(row[1]) + 30.0)
    _write_frames_csv(folder, rows)
    (folder / "groundtruth.csv").unlink()
    (folder / MEASUREMENTS_FILE).unlink()
    read_dataset(folder)
    assert "line 22 comes 30.1 s after the previous frame" in caplog.text and "the tracks are lost there" in caplog.text


# ---------------------------------------------------------------------- 4. signals
@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("rendered") / "ci_short"
    assert simulate_dataset(CI_ROUTE, folder, with_images=True).images_written
    return folder


def _start_run(dataset: Path, out: Path) -> tuple[subprocess.Popen, int, int]:
    """The script on ``dataset`` in a process of its own; returns it with the PIDs of its frontend
    worker and its resource tracker, once poses are being written (a 1 s smoother lag: the first
    poses come about 2 s into the 5.5 s sequence, leaving the rest to signal it)."""
    config = out.parent / "short_lag.yaml"
    config.write_text("smoother: {lag_s: 1.0}\n")
    process = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "run_odometry.py"), str(dataset), "--out", str(out), "--no-progress", "--config", str(config)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    deadline = time.monotonic() + 120
    worker = tracker = None
    while time.monotonic() < deadline and process.poll() is None:
        found = run_helpers(process.pid)
        worker, tracker = found[0] or worker, found[1] or tracker
        if worker and tracker and (out / "tractor.tum").is_file() and _pose_rows(out / "tractor.tum") >= 2:
            return process, worker, tracker
        time.sleep(0.05)
    process.kill()
    raise AssertionError(f"the run did not get going: {process.communicate()}")


@pytest.mark.slow
@pytest.mark.parametrize("signal_number, exit_code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_4_sigterm_like_sigint_keeps_the_estimates_and_leaves_no_process(rendered, tmp_path, signal_number, exit_code):
    out = tmp_path / "out"
    process, worker, tracker = _start_run(rendered, out)
    rows_before = _pose_rows(out / "tractor.tum")
    process.send_signal(signal_number)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == exit_code, stderr
    rows_after = _pose_rows(out / "tractor.tum")
    assert _last_line(stderr) == f"interrupted ({signal.Signals(signal_number).name}): the {rows_after} poses written so far are in {out}"
    assert wait_gone([worker, tracker], 10.0) == [], (worker, tracker)
    record = read_run(out)
    assert record.state == "interrupted" and not (out / LOCK_FILE).exists()
    # the window was written at the interrupt, as after Ctrl-C: more poses than when it came
    assert rows_after > rows_before
    assert "run stopped at frame" in stderr and "writing the keyframes still in the window" in stderr


@pytest.mark.slow
def test_4_sigkill_of_the_run_leaves_no_worker_or_resource_tracker(rendered, tmp_path):
    out = tmp_path / "out"
    process, worker, tracker = _start_run(rendered, out)
    process.kill()
    process.wait(timeout=30)  # not communicate(): an orphan would hold its pipes open
    left = wait_gone([worker, tracker], 10.0)
    for pid in left:  # do not leave them to the next test
        os.kill(pid, signal.SIGKILL)
    process.stdout.close()
    process.stderr.close()
    assert left == [], (worker, tracker)
    assert read_run(out).state == "running"  # it never ended: evaluation says so (test_2_after_a_killed_run...)


# ---------------------------------------------------------------------- 5. nonsense calibration
def _rig_with(folder: Path, **changes) -> Path:
    raw = yaml.safe_load((folder / RIG_FILE).read_text())
    raw["cameras"][0].update(changes)
    (folder / RIG_FILE).write_text(yaml.safe_dump(raw))
    return folder


def test_5_distortion_k1_minus_5_on_undistorted_images_is_refused(bearings, tmp_path, capsys):
    folder = _rig_with(_copy_dataset(bearings, tmp_path / "k1"), distortion=[-5.0, 0.0, 0.0, 0.0])
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    message = _last_line(capsys.readouterr().err)
    assert "rig.yaml: cameras[0] (front): distortion [-5.0, 0.0, 0.0, 0.0] maps the image outside itself" in message
    assert "rays reach at most 55 px from the principal point, the image corners are 400 px away" in message


def test_5_a_focal_length_of_1e_minus_9_is_refused(bearings, tmp_path, capsys):
    folder = _rig_with(_copy_dataset(bearings, tmp_path / "fx"), fx=1e-9)
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert "cameras[0] (front): fx = 1e-09, fy = 320 px give a field of view of 180.0 degrees" in _last_line(capsys.readouterr().err)


def test_5_a_principal_point_far_from_the_centre_is_a_warning_that_says_what_it_does(bearings, tmp_path, caplog):
    folder = _rig_with(_copy_dataset(bearings, tmp_path / "cx"), cx=600.0)
    load_rig(folder / RIG_FILE)
    assert "cameras[0] (front): cx = 600 is 280 px from the image centre (640 px): cx and cy swapped" in caplog.text
    assert "every bearing of this camera is tilted by it" in caplog.text


@needs_clip
@pytest.mark.parametrize("factor, message", [(-1.0, "P1 puts the right camera 0.537 m to the left of the left camera (sign of P1[0, 3] flipped?"),
                                             (1000.0, "stereo baseline 537.2 m is outside [0.02, 5.0] m")])
def test_5_a_kitti_baseline_with_its_sign_flipped_or_in_millimetres_is_refused(tmp_path, capsys, factor, message):
    from tests.io.test_kitti import link_clip

    folder = link_clip(tmp_path / "kitti")
    rows = [line.split() for line in (folder / "calib.txt").read_text().splitlines() if line.strip()]
    rows[1][3] = repr(float(rows[1][3]) * factor)
    (folder / "calib.txt").write_text("\n".join(" ".join(row) for row in rows) + "\n")
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert message in _last_line(capsys.readouterr().err)


# ---------------------------------------------------------------------- 6. sparse trajectories
@pytest.mark.parametrize("every", [2, 4, 8])
def test_6_evaluate_on_a_sparse_trajectory_gives_metrics_not_a_crash(bearings, bearing_run, tmp_path, capsys, every):
    out = tmp_path / "sparse"
    shutil.copytree(bearing_run, out)
    for name in ("tractor.tum", "trailer.tum"):
        lines = (out / name).read_text().splitlines()
        header = [line for line in lines if line.startswith("#")]
        poses = [line for line in lines if not line.startswith("#")]
        (out / name).write_text("\n".join(header + poses[::every]) + "\n")
    assert evaluate_cli([str(out), str(bearings), "--no-plot"]) == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["tractor_ate_m"] < 0.05 * metrics["distance_m"]


# ---------------------------------------------------------------------- 7. measurements.npz content
def _measurements_with(bearings: Path, tmp_path: Path, **changes) -> Path:
    with np.load(bearings / MEASUREMENTS_FILE) as archive:
        data = dict(archive)
    path = tmp_path / MEASUREMENTS_FILE
    np.savez(path, **(data | changes))
    return path


def test_7_nan_timestamps_in_measurements_are_refused(bearings, tmp_path):
    with np.load(bearings / MEASUREMENTS_FILE) as archive:
        timestamps = archive["timestamps"].copy()
    timestamps[7] = np.nan
    with pytest.raises(DatasetError, match=r"measurements.npz: array 'timestamps' contains NaN or infinite values \(frame 7\)"):
        load_measurements(_measurements_with(bearings, tmp_path, timestamps=timestamps))


def test_7_a_duplicate_track_id_in_a_frame_is_refused_by_the_run(bearings, tmp_path, capsys):
    folder = _copy_dataset(bearings, tmp_path / "dup")
    with np.load(folder / MEASUREMENTS_FILE) as archive:
        data = dict(archive)
    rows = np.flatnonzero((data["frame"] == 3) & (data["camera_index"] == 0))
    data["track_id"][rows[1]] = data["track_id"][rows[0]]
    np.savez(folder / MEASUREMENTS_FILE, **data)
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert f"track_id {data['track_id'][rows[0]]} appears more than once in frame 3, camera 'front'" in _last_line(capsys.readouterr().err)


def test_7_a_2d_frame_array_and_a_0d_camera_names_are_refused(bearings, tmp_path):
    with np.load(bearings / MEASUREMENTS_FILE) as archive:
        frame = archive["frame"]
    with pytest.raises(DatasetError, match=r"array 'frame' must be one-dimensional, got shape \(1, \d+\)"):
        load_measurements(_measurements_with(bearings, tmp_path, frame=frame[None, :]))
    with pytest.raises(DatasetError, match=r"array 'camera_names' must be one-dimensional, got shape \(\)"):
        load_measurements(_measurements_with(bearings, tmp_path, camera_names=np.array("front")))


def test_7_pixels_of_another_resolution_and_a_file_that_is_no_npz_are_refused(bearings, tmp_path, default_rig):
    with np.load(bearings / MEASUREMENTS_FILE) as archive:
        pixel = archive["pixel"]
    with pytest.raises(DatasetError, match=r"row \d+: pixel .* lies outside the 640x480 image of camera '\w+' \(\d+ rows outside; measurements of another rig\?\)"):
        load_measurements(_measurements_with(bearings, tmp_path, pixel=pixel * 2.0), default_rig)
    load_measurements(bearings / MEASUREMENTS_FILE, default_rig)  # the simulator's noisy border pixels are fine
    (tmp_path / "text.npz").write_text("hello")
    with pytest.raises(DatasetError, match=r"text.npz: not a readable .npz file \(not a zip archive of arrays\)"):
        load_measurements(tmp_path / "text.npz")


# ---------------------------------------------------------------------- 8. Ctrl-C in the demo's first render
def test_8_ctrl_c_during_the_demos_first_render(tmp_path, monkeypatch, capsys):
    import ampc_vo.sim.simulation

    def interrupted_render(config_path, folder, **kwargs):
        Path(folder).mkdir(parents=True)
        (Path(folder) / "half.png").write_bytes(b"")
        raise KeyboardInterrupt

    monkeypatch.setenv("AMPC_VO_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(ampc_vo.sim.simulation, "simulate_dataset", interrupted_render)
    assert run_odometry(["--no-progress"]) == 130
    assert _last_line(capsys.readouterr().err) == "interrupted (SIGINT): nothing was written"
    assert list((tmp_path / "cache").iterdir()) == []  # the half-rendered folder is gone


# ---------------------------------------------------------------------- 9. disk full, read-only leftovers
class _FillingDisk:
    """A file whose writes fail with ENOSPC once ``budget[0]`` writes (over all files) are used up."""

    def __init__(self, handle, budget: list[int]) -> None:
        self._handle, self._budget = handle, budget

    def write(self, text: str) -> int:
        self._budget[0] -= 1
        if self._budget[0] < 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self._handle.write(text)

    def __getattr__(self, name: str):
        return getattr(self._handle, name)


def test_9_disk_full_mid_run_keeps_what_was_written(bearings, tmp_path, monkeypatch, capsys):
    import builtins

    import ampc_vo.io.outputs as outputs

    budget = [30]  # 3 headers (with the provenance line), then 3 writes per estimate: 9 estimates
    monkeypatch.setattr(outputs, "open", lambda *args, **kwargs: _FillingDisk(builtins.open(*args, **kwargs), budget), raising=False)
    out = tmp_path / "out"
    assert run_odometry([str(bearings), "--out", str(out), "--no-progress"]) == 1
    message = _last_line(capsys.readouterr().err)
    assert message == f"error: {out / 'tractor.tum'}: cannot write (No space left on device); the estimates written before are kept", message
    assert _pose_rows(out / "tractor.tum") == 9
    record = read_run(out)
    assert record.state == "failed" and "No space left on device" in record.message


def test_9_a_read_only_timing_json_of_an_earlier_run_is_replaced(bearings, bearing_run, tmp_path, capsys):
    out = tmp_path / "readonly"
    shutil.copytree(bearing_run, out)
    (out / "timing.json").chmod(0o444)
    old = json.loads((out / "timing.json").read_text())["run_id"]
    assert run_odometry([str(bearings), "--out", str(out), "--no-progress", "--stop", "30"]) == 0, capsys.readouterr().err
    timing = json.loads((out / "timing.json").read_text())
    assert timing["run_id"] == read_run(out).run_id != old and timing["frames"] == 30


# ---------------------------------------------------------------------- 10. nothing to track
@pytest.mark.parametrize("value", [0, 255])
def test_10_all_black_or_all_white_images_exit_1_with_no_poses(tmp_path, capsys, default_rig, value):
    folder = tmp_path / f"blank{value}"
    write_dataset(folder, default_rig, np.arange(25) * 0.1, with_images=True)
    for camera in default_rig.cameras:
        for frame in range(25):
            path = folder / image_relative_path(camera.name, frame)
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), np.full((camera.height, camera.width), value, np.uint8))
    out = tmp_path / "out"
    assert run_odometry([str(folder), "--out", str(out), "--no-progress"]) == 1
    assert _last_line(capsys.readouterr().err).startswith("error: no motion measured in 25 frames (nothing to track")
    assert _pose_rows(out / "tractor.tum") == 0 and read_run(out).state == "failed"


@pytest.mark.slow
def test_10_black_frames_mid_run_are_reported_as_predicted_not_measured(rendered, tmp_path, capsys, caplog):
    folder = _copy_dataset(rendered, tmp_path / "black_middle")
    for image in (folder / "images").glob("*/*.png"):
        if 30 <= int(image.stem) < 45:
            cv2.imwrite(str(image), np.zeros((480, 640), np.uint8))
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 0, capsys.readouterr().err
    assert re.search(r"\d+ of \d+ keyframes had too few tracks: their motion is the constant-velocity prediction, not a measurement", caplog.text)


def test_10_an_empty_frames_csv_is_bad_input(bearings, tmp_path, capsys):
    folder = _copy_dataset(bearings, tmp_path / "empty")
    _write_frames_csv(folder, _frames_csv(folder)[:1])
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert _last_line(capsys.readouterr().err).endswith("frames.csv: no frames")


@pytest.mark.parametrize("frames", [1, 2, 3])
def test_10_one_to_three_frames_exit_1_with_a_message(bearings, tmp_path, capsys, frames):
    out = tmp_path / "out"
    assert run_odometry([str(bearings), "--out", str(out), "--no-progress", "--stop", str(frames)]) == 1
    message = _last_line(capsys.readouterr().err)
    expected = "error: 1 frame(s): motion needs at least 2; no poses written" if frames == 1 else f"error: no motion measured in {frames} frames"
    assert message.startswith(expected)
    assert _pose_rows(out / "tractor.tum") == 0


def test_10_a_straight_start_without_scale_publishes_no_made_up_speed(bearings, tmp_path):
    """Nothing measures metric scale (ground plane and stereo off, a straight start): no pose is
    written at an assumed 1 m/s; the poses start when a turn gives the scale."""
    from ampc_vo.frontend.sources import open_sequence
    from ampc_vo.tools.runner import run_sequence

    config = config_from_dict({"scale": {"ground_plane": False, "bootstrap_max_s": 1.0}})
    _, estimates = run_sequence(open_sequence(bearings, config), config, tmp_path / "out", progress=False)
    assert len(estimates) >= 5
    speeds = [np.linalg.norm(b.T_world_tractor[:2, 3] - a.T_world_tractor[:2, 3]) / (b.timestamp - a.timestamp) for a, b in zip(estimates, estimates[1:])]
    assert min(speeds) > 4.0 and np.median(speeds) == pytest.approx(8.0, rel=0.25)  # the route's 8 m/s, never 1 m/s


# ---------------------------------------------------------------------- 11. incomplete KITTI folders
@needs_clip
@pytest.mark.parametrize("drop, message", [("calib.txt", "looks like a KITTI odometry folder but has no calib.txt"),
                                           ("image_r", "looks like a KITTI odometry folder but has no image_r or image_1/")])
def test_11_a_kitti_folder_without_calib_or_right_images_says_so(tmp_path, capsys, drop, message):
    from tests.io.test_kitti import link_clip

    folder = link_clip(tmp_path / "kitti")
    target = folder / drop
    target.unlink() if target.is_symlink() or target.is_file() else shutil.rmtree(target)
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert message in _last_line(capsys.readouterr().err)
    assert evaluate_cli([str(tmp_path / "out"), str(folder)]) == 2
    assert message in _last_line(capsys.readouterr().err)


# ---------------------------------------------------------------------- 12. frames.csv, config, evaluation mix-ups
@pytest.mark.parametrize("image_path", ["../../etc/passwd", "/etc/passwd", "images/../../outside.png"])
def test_12_image_paths_that_leave_the_dataset_folder_are_refused(bearings, tmp_path, capsys, default_rig, image_path):
    folder = tmp_path / "escape"
    write_dataset(folder, default_rig, np.arange(5) * 0.1, with_images=True)
    rows = _frames_csv(folder)
    rows[3][2] = image_path
    _write_frames_csv(folder, rows)
    assert run_odometry([str(folder), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert f"frames.csv: line 4: image path '{image_path}' of camera 'front' leaves the dataset folder" in _last_line(capsys.readouterr().err)


def test_12_a_utf8_bom_in_frames_csv_is_read(bearings, tmp_path):
    folder = _copy_dataset(bearings, tmp_path / "bom")
    _write_frames_csv(folder, _frames_csv(folder), prefix="\ufeff")
    assert (folder / FRAMES_FILE).read_bytes().startswith(b"\xef\xbb\xbf")
    dataset = read_dataset(folder)
    assert len(dataset) == len(read_dataset(bearings)) and dataset.timestamps[1] == pytest.approx(0.1)


@pytest.mark.parametrize("frames, expected", [([0, 1, 1, 3], "line 4: frame 1, expected 2 (frames are numbered 0, 1, 2, ... in row order; a duplicate)"),
                                              ([0, 1, 5, 6], "line 4: frame 5, expected 2 (frames are numbered 0, 1, 2, ... in row order; a gap or reordering)")])
def test_12_the_frame_column_must_count_the_rows(bearings, tmp_path, frames, expected):
    folder = _copy_dataset(bearings, tmp_path / "frames")
    rows = _frames_csv(folder)[:5]
    for row, frame in zip(rows[1:], frames):
        row[0] = str(frame)
    _write_frames_csv(folder, rows)
    with pytest.raises(DatasetError, match=re.escape(expected)):
        read_dataset(folder, load_measurements_file=False)


def test_12_lag_s_inf_is_refused(tmp_path, capsys, bearings):
    config = tmp_path / "vo.yaml"
    config.write_text("smoother:\n  lag_s: .inf\n")
    assert run_odometry([str(bearings), "--out", str(tmp_path / "out"), "--config", str(config), "--no-progress"]) == 2
    assert _last_line(capsys.readouterr().err) == f"error: {config}: smoother.lag_s: must be a finite number, got inf"
    with pytest.raises(ConfigError, match="must be a finite number"):
        config_from_dict({"keyframes": {"max_interval_s": float("nan")}})


def test_12_evaluating_against_the_wrong_dataset_writes_nothing(bearings, bearing_run, tmp_path, capsys):
    out = tmp_path / "mixup"
    shutil.copytree(bearing_run, out)
    assert evaluate_cli([str(out), str(bearings), "--no-plot"]) == 0
    metrics_before = (out / "metrics.json").read_bytes()
    other = _copy_dataset(bearings, tmp_path / "other_sequence")
    capsys.readouterr()
    assert evaluate_cli([str(out), str(other), "--no-plot"]) == 2
    assert f"the run read {bearings.resolve()}, not {other.resolve()}" in _last_line(capsys.readouterr().err)
    assert (out / "metrics.json").read_bytes() == metrics_before


# ---------------------------------------------------------------------- exit codes
def test_every_exit_has_its_documented_code_and_one_line(capsys):
    from ampc_vo.errors import Interrupted, NothingMeasuredError, SourceError, WriteError
    from ampc_vo.tools.cli import run_cli

    def failing(error: BaseException):
        def main(context):
            raise error
        return main

    cases = [(DatasetError("d: bad\nsecond line"), 2, "error: d: bad second line"),
             (SourceError("worker died"), 1, "error: worker died"),
             (WriteError("x: cannot write"), 1, "error: x: cannot write"),
             (NothingMeasuredError("nothing"), 1, "error: nothing"),
             (OSError(errno.ENOSPC, "No space left on device", "/out/a"), 1, "failed: /out/a: disk full"),
             (RuntimeError("bug"), 1, "failed: RuntimeError: bug (the traceback is logged at DEBUG level)"),
             (KeyboardInterrupt(), 130, "interrupted (SIGINT): nothing was written"),
             (Interrupted(signal.SIGTERM, 143), 143, "interrupted (SIGTERM): nothing was written")]
    for error, code, message in cases:
        assert run_cli(failing(error)) == code
        err = capsys.readouterr().err
        assert err == message + "\n", (error, err)
    assert run_cli(lambda context: 0) == 0
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL or callable(signal.getsignal(signal.SIGTERM))
