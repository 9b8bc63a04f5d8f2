"""End to end on rendered images (issue 7): frontend + backend on a short rendered route, the Rerun
recording, and bad input (missing, corrupt, black images, a short camera folder, a sudden jump)."""
from __future__ import annotations

import itertools
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from ampc_vo.config import VoConfig
from ampc_vo.errors import DatasetError
from ampc_vo.tools.evaluation import evaluate_output
from ampc_vo.tools.runner import run_sequence
from ampc_vo.sim.simulation import simulate_dataset
from ampc_vo.frontend.sources import FrameStep, Sequence, open_sequence

ROOT = Path(__file__).resolve().parents[2]
CI_ROUTE = ROOT / "configs" / "sim" / "ci_short.yaml"


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    """The CI route (straight + 40 degree turn, ~5 s) rendered with images, once per module."""
    folder = tmp_path_factory.mktemp("rendered") / "ci_short"
    result = simulate_dataset(CI_ROUTE, folder, with_images=True)
    assert result.images_written
    return folder


@pytest.fixture(scope="module")
def image_run(rendered, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    sequence = open_sequence(rendered, VoConfig())
    summary, estimates = run_sequence(sequence, VoConfig(), out, rerun_path=out / "run.rrd", progress=False)
    return sequence, summary, estimates, out


def test_images_are_the_source_when_the_folder_has_them(rendered):
    assert open_sequence(rendered, VoConfig()).kind == "images"
    forced = open_sequence(rendered, VoConfig(source="bearings"))
    assert forced.kind == "bearings"
    assert len(forced) == len(open_sequence(rendered, VoConfig()))


def test_image_pipeline_meets_the_accuracy_of_issue_7(image_run):
    """Tractor ATE <= 2 % of the distance, hitch RMSE <= 0.5 deg, max <= 1.5 deg (issue 7)."""
    sequence, summary, estimates, out = image_run
    metrics = evaluate_output(out, sequence.truth).metrics
    assert summary.frames == len(sequence)
    assert summary.keyframes >= 10
    assert metrics.tractor_ate_m <= 0.02 * metrics.distance_m, metrics
    assert metrics.hitch_rmse_deg <= 0.5, metrics
    assert metrics.hitch_max_deg <= 1.5, metrics
    assert "frontend" in summary.backend_ms_breakdown
    # the backend thread's CPU time: positive, and no more than its wall time (one thread)
    assert 0.0 < summary.backend_cpu_ms_median <= 1.05 * summary.backend_ms_median + 1.0, summary


def test_rerun_recording_verifies_and_has_the_entities(image_run):
    from ampc_vo.tools.viz import recording_contents, verify_recording

    _, _, _, out = image_run
    verify_recording(out / "run.rrd")
    entities = recording_contents(out / "run.rrd")
    for entity in ("/world/tractor", "/world/trailer", "/world/tractor/front", "/world/tractor/front/features",
                   "/world/trailer/rear/features", "/world/trajectory/tractor_estimate", "/world/trajectory/tractor_truth",
                   "/plots/hitch_deg/estimate", "/plots/hitch_deg/truth", "/plots/hitch_deg/upper"):
        assert entity in entities, sorted(entities)


def _damaged_copy(rendered: Path, target: Path) -> Path:
    """The rendered dataset with one missing image, one corrupt file, an all-black frame, a camera
    whose folder ends early and a sudden jump (two frames of one camera swapped with far-away ones)."""
    shutil.copytree(rendered, target)
    images = target / "images"
    (images / "front" / "000010.png").unlink()
    (images / "left" / "000012.png").write_bytes(b"not a png at all")
    black = np.zeros((480, 640), np.uint8)
    for camera in ("front", "left", "rear", "right"):
        cv2.imwrite(str(images / camera / "000015.png"), black)
    frames = sorted((images / "rear").glob("*.png"))
    for path in frames[-8:]:
        path.unlink()
    jump_a, jump_b = images / "right" / "000020.png", images / "right" / "000040.png"
    saved = jump_a.read_bytes()
    jump_a.write_bytes(jump_b.read_bytes())
    jump_b.write_bytes(saved)
    return target


def test_bad_images_are_logged_and_the_run_recovers(rendered, tmp_path):
    damaged = _damaged_copy(rendered, tmp_path / "damaged")
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "run_odometry.py"), str(damaged), "--out", str(out), "--no-progress"],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    assert "000010.png" in run.stderr and "000012.png" in run.stderr  # each bad file is named
    assert "blank" in run.stderr
    rows = [line for line in (out / "tractor.tum").read_text().splitlines() if not line.startswith("#")]
    assert len(rows) >= 10
    metrics = evaluate_output(out, open_sequence(damaged, VoConfig()).truth).metrics
    assert metrics.tractor_ate_m <= 0.05 * metrics.distance_m, metrics  # degraded, not lost


def test_a_failing_source_keeps_the_estimates_written_so_far(rendered, tmp_path):
    """An error in the middle of the stream: the error reaches the caller, and every keyframe
    estimated until then (including those still in the smoother window) is in the output files."""
    sequence = open_sequence(rendered, VoConfig(source="bearings"))

    def failing_steps(images=True):
        for index, step in enumerate(sequence.steps(images=images)):
            if index == 35:
                raise DatasetError("camera unplugged")
            yield step

    broken = Sequence(sequence.path, sequence.kind, sequence.rig, sequence.timestamps, sequence.truth, failing_steps)
    with pytest.raises(DatasetError, match="unplugged"):
        run_sequence(broken, VoConfig(), tmp_path, progress=False)
    rows = [line for line in (tmp_path / "tractor.tum").read_text().splitlines() if not line.startswith("#")]
    assert len(rows) >= 8
    last_time = float(rows[-1].split()[0])
    assert last_time >= sequence.timestamps[30]


def test_missing_dataset_and_bearings_only_folder_give_clear_errors(tmp_path):
    with pytest.raises(DatasetError, match="no such dataset folder"):
        open_sequence(tmp_path / "nope", VoConfig())
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(DatasetError, match="not a folder"):
        open_sequence(tmp_path / "file.txt", VoConfig())


def test_frame_step_carries_images_and_frontend_details(rendered):
    steps = open_sequence(rendered, VoConfig()).steps()
    first: FrameStep = next(steps)
    second: FrameStep = next(steps)
    steps.close()
    assert first.images is not None and set(first.images) == {"front", "left", "rear", "right"}
    assert second.frontend is not None
    tracked = sum(len(observations) for observations in second.observations.cameras.values())
    assert tracked >= 400
    # without images (no recording to show them): the frontend process sends the same observations only
    bare = open_sequence(rendered, VoConfig(frontend_worker="process")).steps(images=False)
    bare_first, bare_second = next(bare), next(bare)
    bare.close()
    assert bare_first.images is None and bare_second.images is None and bare_second.frontend is not None
    for name, camera in second.observations.cameras.items():
        np.testing.assert_array_equal(bare_second.observations.cameras[name].track_ids, camera.track_ids)
        np.testing.assert_array_equal(bare_second.observations.cameras[name].bearings, camera.bearings)


def test_frontend_in_its_own_process_gives_the_inline_observations(rendered):
    """frontend_worker process (the default) and none track the same features to the same bearings."""
    frames = 6
    inline = list(itertools.islice(open_sequence(rendered, VoConfig(frontend_worker="none")).steps(), frames))
    stream = open_sequence(rendered, VoConfig(frontend_worker="process")).steps()
    in_process = list(itertools.islice(stream, frames))
    stream.close()
    assert len(inline) == len(in_process) == frames
    for ours, theirs in zip(inline, in_process):
        assert ours.observations.frame == theirs.observations.frame
        assert set(theirs.observations.cameras) == {"front", "left", "rear", "right"}
        for name, camera in ours.observations.cameras.items():
            other = theirs.observations.cameras[name]
            assert len(camera) > 50
            np.testing.assert_array_equal(camera.track_ids, other.track_ids)
            np.testing.assert_array_equal(camera.bearings, other.bearings)
        assert theirs.images is not None and theirs.frontend is not None and theirs.seconds > 0


def test_fisheye_image_pipeline_meets_the_accuracy_of_issue_7(tmp_path):
    """The CI route seen by the equidistant fisheye rig (configs/rigs/fisheye.yaml): rendered fisheye
    images through the frontend's fisheye bearings to the same limits as the pinhole rig
    (measured: ATE 0.06 m over 42 m, hitch RMSE 0.19 deg, max 0.25 deg)."""
    import dataclasses

    from ampc_vo.sim.config import load_sim_config

    config = dataclasses.replace(load_sim_config(CI_ROUTE), rig_path=ROOT / "configs" / "rigs" / "fisheye.yaml")
    folder = tmp_path / "ci_short_fisheye"
    simulate_dataset(config, folder, with_images=True)
    sequence = open_sequence(folder, VoConfig())
    assert {camera.model for camera in sequence.rig.cameras} == {"fisheye"}
    summary, _ = run_sequence(sequence, VoConfig(), tmp_path / "out", progress=False)
    metrics = evaluate_output(tmp_path / "out", sequence.truth).metrics
    assert summary.keyframes >= 10
    assert metrics.tractor_ate_m <= 0.02 * metrics.distance_m, metrics
    assert metrics.hitch_rmse_deg <= 0.5, metrics
    assert metrics.hitch_max_deg <= 1.5, metrics


def test_the_run_summary_records_its_dataset(image_run):
    import json

    sequence, summary, _, out = image_run
    assert summary.dataset == str(Path(sequence.path).resolve())
    assert json.loads((out / "timing.json").read_text())["dataset"] == summary.dataset


def test_hitch_sigma_covers_the_error_without_being_vacuous(image_run):
    """The published 1-sigma of the hitch angle (gtsam.Marginals) against the true error on the CI
    route: at least 90 % of the errors within 2 sigma, and sigma small enough to mean something
    (measured: 1 sigma 0.15 deg median, errors within 1 sigma 90-100 % on five routes: conservative)."""
    from ampc_vo.geometry import wrap_angle
    from ampc_vo.io.outputs import read_hitch

    sequence, _, _, out = image_run
    hitch = read_hitch(out / "hitch.csv")
    truth = sequence.truth
    index = np.array([int(np.argmin(np.abs(truth.timestamps - t))) for t in hitch.timestamps])
    error = np.abs(wrap_angle(hitch.angles - truth.hitch_angles[index]))
    known = np.isfinite(hitch.sigmas)
    assert known.sum() >= 0.8 * len(hitch.sigmas)
    assert np.mean(error[known] <= 2.0 * hitch.sigmas[known]) >= 0.9
    assert np.degrees(np.median(hitch.sigmas[known])) < 0.5


def test_without_worker_processes_the_frontend_runs_in_a_thread(rendered, monkeypatch, caplog):
    """Where no process can be started (a container without /dev/shm: semaphores fail), the image
    source says so and tracks in a thread: the same observations as inline."""
    import ampc_vo.frontend.worker

    class NoSemaphores:
        def Queue(self, *args, **kwargs):
            raise OSError(38, "Function not implemented")

    monkeypatch.setattr(ampc_vo.frontend.worker.multiprocessing, "get_context", lambda method: NoSemaphores())
    with caplog.at_level("WARNING"):
        fallback = list(itertools.islice(open_sequence(rendered, VoConfig(frontend_worker="process")).steps(), 3))
    assert "could not be started" in caplog.text and "runs in a thread" in caplog.text
    inline = list(itertools.islice(open_sequence(rendered, VoConfig(frontend_worker="none")).steps(), 3))
    for ours, theirs in zip(inline, fallback):
        for name, camera in ours.observations.cameras.items():
            np.testing.assert_array_equal(camera.bearings, theirs.observations.cameras[name].bearings)
