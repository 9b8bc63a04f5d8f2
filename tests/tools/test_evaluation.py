"""Tests of ampc_vo.tools.evaluation against hand-constructed trajectories with known errors."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from ampc_vo.errors import AmpcError
from ampc_vo.io.groundtruth import GroundTruth
from ampc_vo.tools.evaluation import evaluate, evaluate_output, plot_evaluation, write_metrics
from ampc_vo.io.datasets import load_groundtruth
from ampc_vo.geometry import make_pose, planar_pose, rot_y, rot_z
from ampc_vo.io.outputs import HitchSeries, OutputWriter, Trajectory


def _route(count: int = 400, step: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Timestamps, tractor poses along an S-curve (~step m per frame), trailer poses (hitch 0.1 rad)."""
    times = np.arange(count) * 0.1
    yaw = 0.4 * np.sin(np.arange(count) / 60.0)
    xy = np.cumsum(step * np.stack([np.cos(yaw), np.sin(yaw)], axis=1), axis=0)
    tractor = np.array([planar_pose(x, y, a) for (x, y), a in zip(xy, yaw)])
    trailer = np.array([pose @ make_pose(rot_z(0.1), np.zeros(3)) for pose in tractor])
    return times, tractor, trailer


def _truth() -> GroundTruth:
    times, tractor, trailer = _route()
    return GroundTruth(times, tractor, trailer, 0.1 + 0.2 * np.sin(times))


def test_perfect_estimate_in_another_frame():
    """An exact estimate expressed in a different world frame: all errors vanish after alignment."""
    truth = _truth()
    offset = make_pose(rot_z(1.0), np.array([5.0, -3.0, 0.0]))
    estimate = Trajectory(truth.timestamps, np.array([offset @ p for p in truth.T_world_tractor]))
    trailer = Trajectory(truth.timestamps, np.array([offset @ p for p in truth.T_world_trailer]))
    result = evaluate(truth, estimate, trailer, HitchSeries(truth.timestamps, truth.hitch_angles, np.full(400, 0.01))).metrics
    assert result.frames == 400
    assert result.distance_m == pytest.approx(199.5, rel=1e-3)
    assert result.tractor_ate_m < 1e-6 and result.tractor_ate_sim3_m < 1e-6 and result.trailer_ate_m < 1e-6
    assert result.tractor_rpe_percent < 1e-6 and result.tractor_rotation_drift_deg_per_100m < 1e-6
    assert result.hitch_rmse_deg < 1e-9 and result.hitch_max_deg < 1e-9


def test_a_pitch_drift_that_the_ate_does_not_see():
    """Orientations pitched by 0.5 deg per 100 m of path with exact positions: the ATE is zero,
    the rotation drift over 100 m segments reads 0.5 deg per 100 m."""
    truth = _truth()
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(truth.T_world_tractor[:, :3, 3], axis=0), axis=1))])
    pitched = np.array([pose @ make_pose(rot_y(np.radians(0.5) * s / 100.0), np.zeros(3)) for pose, s in zip(truth.T_world_tractor, travelled)])
    result = evaluate(truth, Trajectory(truth.timestamps, pitched)).metrics
    assert result.tractor_ate_m < 1e-6
    assert result.tractor_rotation_drift_deg_per_100m == pytest.approx(0.5, rel=0.1)  # evo: pairs 100-110 m apart


def test_known_lateral_offset_of_half_the_points():
    """Points alternately shifted by +-d along z (which no rigid alignment removes): ATE = d."""
    truth = _truth()
    poses = truth.T_world_tractor.copy()
    poses[:, 2, 3] += np.where(np.arange(400) % 2 == 0, 0.3, -0.3)
    result = evaluate(truth, Trajectory(truth.timestamps, poses)).metrics
    assert result.tractor_ate_m == pytest.approx(0.3, rel=1e-3)
    assert result.trailer_ate_m is None and result.hitch_rmse_deg is None


def test_scale_error_counts_in_se3_not_in_sim3():
    truth = _truth()
    poses = truth.T_world_tractor.copy()
    poses[:, :3, 3] *= 1.03
    result = evaluate(truth, Trajectory(truth.timestamps, poses)).metrics
    assert result.tractor_ate_m > 0.5  # 3% of a ~200 m route
    assert result.tractor_ate_sim3_m < 1e-6
    assert result.sim3_scale == pytest.approx(1.0 / 1.03, rel=1e-6)
    # translation error over 10 m segments is 3% of the segment
    assert result.tractor_rpe_percent == pytest.approx(3.0, rel=0.02)


def test_trailer_uses_tractor_alignment():
    """A trailer estimate that is off by a rigid transform (tractor exact) is not aligned away."""
    truth = _truth()
    shifted = np.array([make_pose(np.eye(3), np.array([0.0, 0.0, 0.5])) @ p for p in truth.T_world_trailer])
    result = evaluate(truth, Trajectory(truth.timestamps, truth.T_world_tractor), Trajectory(truth.timestamps, shifted)).metrics
    assert result.tractor_ate_m < 1e-6
    assert result.trailer_ate_m == pytest.approx(0.5, rel=1e-6)


def test_hitch_offset_and_sparse_keyframes():
    """Estimates at every 5th frame with a constant 0.4 deg offset and one 2 deg spike."""
    truth = _truth()
    keep = np.arange(0, 400, 5)
    angles = truth.hitch_angles[keep] + np.radians(0.4)
    angles[10] += np.radians(1.6)
    result = evaluate(
        truth, Trajectory(truth.timestamps[keep], truth.T_world_tractor[keep]), None,
        HitchSeries(truth.timestamps[keep], angles, np.full(keep.size, 0.01)),
    ).metrics
    assert result.frames == keep.size
    expected = np.sqrt(((keep.size - 1) * 0.4**2 + 2.0**2) / keep.size)
    assert result.hitch_rmse_deg == pytest.approx(expected, rel=1e-6)
    assert result.hitch_max_deg == pytest.approx(2.0, rel=1e-6)


def test_hitch_wraps_angles():
    truth = GroundTruth(np.arange(3.0), np.array([planar_pose(k, 0, 0) for k in range(3)]), None, np.full(3, np.pi - 0.01))
    result = evaluate(truth, Trajectory(truth.timestamps, truth.T_world_tractor), None, HitchSeries(truth.timestamps, np.full(3, -np.pi + 0.01), np.zeros(3))).metrics
    assert result.hitch_max_deg == pytest.approx(np.degrees(0.02), rel=1e-6)


def test_short_run_has_no_rpe_and_unmatched_times_fail():
    truth = _truth()
    result = evaluate(truth, Trajectory(truth.timestamps[:10], truth.T_world_tractor[:10])).metrics
    assert result.tractor_rpe_percent is None and result.tractor_rotation_drift_deg_per_100m is None
    with pytest.raises(AmpcError):
        evaluate(truth, Trajectory(truth.timestamps[:10] + 0.05, truth.T_world_tractor[:10]))


def test_output_folder_files_and_plot(tmp_path):
    from ampc_vo.io.folder import write_dataset
    from ampc_vo.io.groundtruth import Trajectory as TruthTrajectory
    from ampc_vo.rig import load_rig

    truth = _truth()
    rig = load_rig(Path(__file__).resolve().parents[2] / "configs" / "rigs" / "default.yaml")
    write_dataset(tmp_path / "dataset", rig, truth.timestamps, groundtruth=TruthTrajectory(truth.timestamps, truth.T_world_tractor, truth.T_world_trailer, truth.hitch_angles))
    loaded = load_groundtruth(tmp_path / "dataset")
    np.testing.assert_allclose(loaded.T_world_trailer, truth.T_world_trailer, atol=1e-9)
    out = tmp_path / "out"
    with OutputWriter(out) as writer:
        for t, a, b, h in zip(truth.timestamps, truth.T_world_tractor, truth.T_world_trailer, truth.hitch_angles):
            writer.write(t, a, b, h + 0.01, 0.02)
    (out / "timing.json").write_text(json.dumps({"seconds_per_frame": 0.05}))
    evaluation = evaluate_output(out, loaded)
    assert evaluation.metrics.seconds_per_frame == pytest.approx(0.05)
    assert evaluation.metrics.hitch_rmse_deg == pytest.approx(np.degrees(0.01), rel=1e-4)
    write_metrics(evaluation.metrics, out / "metrics.json")
    data = json.loads((out / "metrics.json").read_text())
    assert set(data) >= {"frames", "distance_m", "tractor_ate_m", "tractor_ate_sim3_m", "trailer_ate_m", "tractor_rpe_percent", "hitch_rmse_deg", "hitch_max_deg", "seconds_per_frame"}
    plot_evaluation(evaluation, out / "evaluation.png")
    assert (out / "evaluation.png").stat().st_size > 10_000


def test_trailer_ate_at_the_axle_sees_hitch_errors():
    """A hitch-angle error moves the trailer axle (8 m behind the hitch) but not the hitch itself."""
    truth = _truth()
    truth = GroundTruth(truth.timestamps, truth.T_world_tractor, truth.T_world_trailer, truth.hitch_angles, trailer_axle_x=-8.0)
    rotated = np.array([pose @ make_pose(rot_z(np.radians(1.0)), np.zeros(3)) for pose in truth.T_world_trailer])
    result = evaluate(truth, Trajectory(truth.timestamps, truth.T_world_tractor), Trajectory(truth.timestamps, rotated)).metrics
    assert result.trailer_ate_m == pytest.approx(2 * 8.0 * np.sin(np.radians(0.5)), rel=1e-6)


def test_ground_truth_of_a_dataset_with_missing_images(tmp_path):
    """The evaluation needs no images: a run that skipped a missing image can still be evaluated
    (load_groundtruth used to refuse the dataset the run had accepted)."""
    from ampc_vo.io.folder import write_dataset
    from ampc_vo.io.groundtruth import Trajectory as TruthTrajectory
    from ampc_vo.rig import load_rig

    truth = _truth()
    rig = load_rig(Path(__file__).resolve().parents[2] / "configs" / "rigs" / "default.yaml")
    root = write_dataset(tmp_path / "dataset", rig, truth.timestamps, with_images=True,
                         groundtruth=TruthTrajectory(truth.timestamps, truth.T_world_tractor, truth.T_world_trailer, truth.hitch_angles))
    (root / "images" / "front").mkdir(parents=True)  # images/ exists, but every listed image is missing
    loaded = load_groundtruth(root)
    np.testing.assert_allclose(loaded.T_world_tractor, truth.T_world_tractor, atol=1e-9)


def test_a_timing_file_with_a_non_number_is_logged_and_ignored(tmp_path, caplog):
    from ampc_vo.tools.evaluation import read_seconds_per_frame

    (tmp_path / "timing.json").write_text('{"seconds_per_frame": "fast"}')
    with caplog.at_level("WARNING"):
        assert read_seconds_per_frame(tmp_path) is None
    assert "unreadable timing file" in caplog.text


def test_a_run_evaluated_against_another_dataset_is_refused(tmp_path):
    """run.json (or, for older runs, timing.json) records the dataset folder of the run; evaluating
    it against another one is an error (issue 14: it used to be a warning, and metrics.json was
    overwritten)."""
    import json

    from ampc_vo.errors import OutputError
    from ampc_vo.tools.evaluation import require_run_dataset

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    out = tmp_path / "out"
    out.mkdir()
    require_run_dataset(out, tmp_path / "a")  # no run.json, no timing.json: nothing to check
    (out / "timing.json").write_text(json.dumps({"dataset": str((tmp_path / "a").resolve())}))
    require_run_dataset(out, tmp_path / "b" / ".." / "a")
    with pytest.raises(OutputError, match=f"the run read {re.escape(str((tmp_path / 'a').resolve()))}, not {re.escape(str((tmp_path / 'b').resolve()))}"):
        require_run_dataset(out, tmp_path / "b")


def test_evaluate_script_rejects_nonsense_options(tmp_path):
    import subprocess
    import sys

    script = Path(__file__).resolve().parents[2] / "scripts" / "evaluate.py"
    for option, value in (("--max-time-diff", "-1"), ("--seconds-per-frame", "0")):
        run = subprocess.run([sys.executable, str(script), str(tmp_path), str(tmp_path), option, value], capture_output=True, text=True, timeout=120)
        assert run.returncode == 2 and f"{option} must be > 0" in run.stderr


def _circle(speed: float, radius: float, count: int = 200) -> GroundTruth:
    """A drive at ``speed`` (m/s, 10 Hz) round a circle of ``radius`` (m; centre on the left when positive)."""
    times = np.arange(count) * 0.1
    heading = speed * times / radius
    xy = np.stack([radius * np.sin(heading), radius * (1.0 - np.cos(heading))], axis=1)
    tractor = np.array([planar_pose(x, y, a) for (x, y), a in zip(xy, heading)])
    return GroundTruth(times, tractor, None, np.zeros(count))


@pytest.mark.parametrize("speed, radius", [(25.0, 700.0), (8.0, -30.0)])
def test_lateral_acceleration_of_a_circle(speed, radius):
    from ampc_vo.tools.evaluation import lateral_accelerations

    truth = _circle(speed, radius)
    lateral, speed_read = lateral_accelerations(truth.timestamps, truth.T_world_tractor)
    np.testing.assert_allclose(lateral[1:-1], speed**2 / radius, rtol=1e-3)  # v^2 / R, left positive
    np.testing.assert_allclose(speed_read[1:-1], speed, rtol=1e-3)


def test_a_hitch_error_in_proportion_to_the_lateral_acceleration():
    """The S-curve route driven at 25 m/s (lateral acceleration up to 1.7 m/s^2) with a hitch that
    errs by 0.4 deg per m/s^2 of lateral acceleration, as one following an unmodelled tyre slip:
    the slope reads 0.4, and the cornering figures cover the keyframes beyond CORNERING_MPS2 only."""
    from ampc_vo.tools.evaluation import CORNERING_MPS2, lateral_accelerations

    times, tractor, trailer = _route(step=2.5)          # 25 m/s
    truth = GroundTruth(times, tractor, trailer, 0.1 + 0.2 * np.sin(times))
    lateral, _ = lateral_accelerations(times, tractor)
    assert np.abs(lateral).max() > 2 * CORNERING_MPS2 and np.mean(np.abs(lateral) >= CORNERING_MPS2) > 0.2
    error = np.radians(0.4) * lateral
    sigma = np.full(len(times), np.radians(0.1))
    result = evaluate(truth, Trajectory(times, tractor), None, HitchSeries(times, truth.hitch_angles + error, sigma)).metrics
    assert result.hitch_error_per_lateral_acceleration == pytest.approx(0.4, rel=1e-6)
    cornering = np.abs(lateral) >= CORNERING_MPS2
    assert result.hitch_cornering_rmse_deg == pytest.approx(np.degrees(np.sqrt(np.mean(error[cornering] ** 2))), rel=1e-6)
    assert result.hitch_cornering_within_2sigma == pytest.approx(np.mean(np.abs(error[cornering]) <= 2 * sigma[cornering]), abs=1e-12)
    assert result.hitch_cornering_within_2sigma < 0.5                          # errors of 0.2-0.5 deg at 0.1 deg sigma
    # an error that does not follow the lateral acceleration has no slope
    flat = evaluate(truth, Trajectory(times, tractor), None, HitchSeries(times, truth.hitch_angles + np.radians(0.3), sigma)).metrics
    assert abs(flat.hitch_error_per_lateral_acceleration) < 1e-9


def test_straight_driving_has_no_cornering_figures():
    times = np.arange(100) * 0.1
    tractor = np.array([planar_pose(25.0 * t, 0.0, 0.0) for t in times])
    truth = GroundTruth(times, tractor, None, np.zeros(100))
    result = evaluate(truth, Trajectory(times, tractor), None, HitchSeries(times, np.full(100, 0.01), np.full(100, 0.01))).metrics
    assert result.hitch_rmse_deg is not None
    assert result.hitch_cornering_rmse_deg is None and result.hitch_cornering_within_2sigma is None
    assert result.hitch_error_per_lateral_acceleration is None
