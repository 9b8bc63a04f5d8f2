"""CI runs a short realistic route end to end (issue 13): configs/sim/realistic_ci_short.yaml on the
semitrailer rig (standing start on a 5 % grade, crown, suspension, vibration, tridem, tyre slip),
written as a dataset folder, read back, run through today's estimator in bearing mode and evaluated."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ampc_vo.backend.pipeline import run_on_frames
from ampc_vo.config import config_from_dict
from ampc_vo.io.datasets import load_groundtruth
from ampc_vo.io.folder import write_dataset
from ampc_vo.sim.simulation import simulate
from ampc_vo.tools.evaluation import evaluate_output

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def route():
    """The CI route simulated once for the module (the simulation is deterministic: its seed)."""
    return simulate(ROOT / "configs" / "sim" / "realistic_ci_short.yaml")


def test_realistic_ci_route_end_to_end(tmp_path, route):
    result = route
    assert result.rig.hitch_height == 1.2 and result.rig.axle_x("tractor") < 0.0
    data = tmp_path / "data"
    write_dataset(data, result.rig, result.trajectory.timestamps, groundtruth=result.trajectory, measurements=result.measurements)
    truth = load_groundtruth(data)
    # the 6-DoF truth survives groundtruth.csv: heights on the grade, pitch and roll
    assert np.allclose(truth.T_world_tractor, result.trajectory.T_world_tractor, atol=1e-6)
    assert np.ptp(truth.T_world_tractor[:, 2, 3]) > 1.0 and np.abs(truth.T_world_tractor[:, 2, 0]).max() > 0.04
    config = config_from_dict({"output": {"progress": False}})
    summary, estimates = run_on_frames(result.rig, config, result.measurements.frames(result.rig), tmp_path / "run", total=len(result.trajectory))
    assert summary.frames == len(result.trajectory) and len(estimates) >= 10
    metrics = evaluate_output(tmp_path / "run", truth).metrics
    assert np.isfinite(metrics.tractor_ate_m) and np.isfinite(metrics.hitch_rmse_deg)
    # measured (2026-12-05): ATE 0.059 m of 37 m (0.16 %), hitch RMSE 0.18 deg / max 0.24 deg, all
    # within 2 sigma; issue 16's limits: ATE 1 %, hitch RMSE 0.3 deg, max 1.5 deg, 95 % within 2 sigma
    assert metrics.tractor_ate_m < 0.01 * metrics.distance_m
    assert metrics.hitch_rmse_deg < 0.3 and metrics.hitch_max_deg < 1.5 and metrics.hitch_within_2sigma >= 0.95


def test_the_trailers_cameras_measure_its_crab(tmp_path, route):
    """The CI route's trailer drifts down the crown's cross-slope (its axle group's slip angle has a
    steady part): with the crab angle a variable of the trailer's non-holonomic factor
    (``smoother.trailer_crab_sigma_deg``, opt-in) the trailer cameras measure it; without it (the
    default) every keyframe pair's arc asserts zero alike and the hitch carries the drift (measured
    2026-12-05: hitch RMSE 0.056 deg against 0.175 deg, mean error -0.17 deg without; 2026-12-07,
    cross-camera pairs between consecutive keyframes only: 0.059 deg against 0.098 deg)."""
    result = route
    data = tmp_path / "data"
    write_dataset(data, result.rig, result.trajectory.timestamps, groundtruth=result.trajectory, measurements=result.measurements)
    truth = load_groundtruth(data)
    metrics = {}
    for name, crab in (("crab", 0.5), ("arc", None)):
        config = config_from_dict({"output": {"progress": False}, "smoother": {"trailer_crab_sigma_deg": crab}})
        run_on_frames(result.rig, config, result.measurements.frames(result.rig), tmp_path / name, total=len(result.trajectory))
        metrics[name] = evaluate_output(tmp_path / name, truth).metrics
    assert metrics["crab"].hitch_rmse_deg < 0.1 and metrics["arc"].hitch_rmse_deg > 1.4 * metrics["crab"].hitch_rmse_deg
    assert metrics["crab"].hitch_within_2sigma >= 0.95 and metrics["crab"].hitch_sigma_median_deg < 0.3


def test_capture_time_extrinsics_are_rebuilt_from_the_optimised_twist(tmp_path, monkeypatch):
    """The CI route with its cameras firing up to 38 ms after the frame time, as on the realistic
    routes (DESIGN 11): a keyframe's epipolar factor is built with each camera moved along its body's
    twist from the first guess; where the optimised twist moves a camera by more than a few
    millimetres, the factor is rebuilt with it and replaces the first in the smoother (the old one is
    gone from its graph, the new one is there), a rebuild that finds no pair keeps the first, and the
    run keeps issue 16's limits."""
    import yaml

    from ampc_vo.backend.smoother import ArticulatedSmoother
    from ampc_vo.sim.config import sim_config_from_dict

    path = ROOT / "configs" / "sim" / "realistic_ci_short.yaml"
    raw = yaml.safe_load(path.read_text())
    raw["cameras"] = {"cab_front": {"offset_ms": 0}, "mirror_left": {"offset_ms": 12}, "mirror_right": {"offset_ms": 27},
                      "trailer_left": {"offset_ms": 19}, "trailer_rear": {"offset_ms": 38}}
    result = simulate(sim_config_from_dict(raw, path))
    assert result.measurements.camera_timestamps is not None
    refreshed, starved = [], []
    original = ArticulatedSmoother._refresh_capture_twists

    def spy(self, keyframe):
        before = keyframe.epipolar_factor
        if not starved:
            # once: a rebuild that finds no moving pair (a stopping truck whose optimised chord fell
            # below the standstill distance) keeps the factor as built instead of dropping it
            calls = []
            with monkeypatch.context() as patch:
                patch.setattr(self, "_add_epipolar_factors", lambda *args: calls.append(args) and False)
                done = original(self, keyframe)
            if calls:
                graph = self._smoother.getFactors()
                starved.append((done, keyframe.epipolar_factor is before, any(graph.at(i) is before for i in range(graph.size()) if graph.exists(i))))
                return done
        done = original(self, keyframe)
        if done:
            graph = self._smoother.getFactors()
            present = [graph.at(i) for i in range(graph.size()) if graph.exists(i)]
            refreshed.append((any(factor is before for factor in present), any(factor is keyframe.epipolar_factor for factor in present)))
        return done

    monkeypatch.setattr(ArticulatedSmoother, "_refresh_capture_twists", spy)
    config = config_from_dict({"output": {"progress": False}})
    run_on_frames(result.rig, config, result.measurements.frames(result.rig), tmp_path / "run", total=len(result.trajectory))
    assert len(refreshed) >= 3  # the standing start: the first guesses' twists are far off
    assert all(not old and new for old, new in refreshed)
    assert starved == [(False, True, True)]
    data = tmp_path / "data"
    write_dataset(data, result.rig, result.trajectory.timestamps, groundtruth=result.trajectory, measurements=result.measurements)
    metrics = evaluate_output(tmp_path / "run", load_groundtruth(data)).metrics
    assert metrics.tractor_ate_m < 0.01 * metrics.distance_m
    assert metrics.hitch_rmse_deg < 0.3 and metrics.hitch_within_2sigma >= 0.95


def test_without_the_trailer_cameras_the_hitch_sigma_says_so(tmp_path, route):
    """``run_odometry.py --without-cameras`` (the ablation of the README): the same folder run without
    the trailer cameras publishes the hitch of the joint loop and the trailer's model alone, with
    a sigma that says so (measured on realistic_ci_short: median 0.14 deg with the cameras, 3.0 deg
    without), and an unknown or the last tractor camera is refused with the names the rig has."""
    from ampc_vo.errors import DatasetError
    from ampc_vo.frontend.sources import open_sequence
    from ampc_vo.tools.runner import run_sequence

    result = route
    data = tmp_path / "data"
    write_dataset(data, result.rig, result.trajectory.timestamps, groundtruth=result.trajectory, measurements=result.measurements)
    config = config_from_dict({"output": {"progress": False}})
    truth = load_groundtruth(data)
    metrics = {}
    for name, dropped in (("with", ()), ("without", ("trailer_left", "trailer_rear"))):
        sequence = open_sequence(data, config, dropped_cameras=dropped)
        assert [camera.body for camera in sequence.rig.cameras].count("trailer") == (0 if dropped else 2)
        run_sequence(sequence, config, tmp_path / name, progress=False)
        metrics[name] = evaluate_output(tmp_path / name, truth).metrics
    assert metrics["with"].hitch_sigma_median_deg < 0.3
    assert metrics["without"].hitch_sigma_median_deg > 3.0 * metrics["with"].hitch_sigma_median_deg
    assert metrics["without"].hitch_within_3sigma >= 0.99
    with pytest.raises(DatasetError, match="no camera trailer_back in the rig; its cameras are cab_front"):
        open_sequence(data, config, dropped_cameras=("trailer_back",))
    with pytest.raises(DatasetError, match="no tractor camera is left"):
        open_sequence(data, config, dropped_cameras=("cab_front", "mirror_left", "mirror_right"))


def test_rolling_shutter_rows_in_the_epipolar_factors_run_end_to_end(tmp_path, monkeypatch, route):
    """``smoother.rolling_shutter_rows`` (off by default, DESIGN 11) on the CI route, whose cameras
    read out over 30 ms: the per-row factors are built and the run stays as accurate as without
    (measured: ATE 0.065 m of 37 m, hitch RMSE 0.17 deg, all within 3 sigma)."""
    result = route
    assert all(camera.readout_time > 0.0 for camera in result.rig.cameras)
    data = tmp_path / "data"
    write_dataset(data, result.rig, result.trajectory.timestamps, groundtruth=result.trajectory, measurements=result.measurements)
    from ampc_vo.backend import smoother

    calls = []
    per_row = smoother.body_correspondences_per_row
    monkeypatch.setattr(smoother, "body_correspondences_per_row", lambda *args: calls.append(args[1]) or per_row(*args))
    config = config_from_dict({"output": {"progress": False}, "smoother": {"rolling_shutter_rows": True}})
    run_on_frames(result.rig, config, result.measurements.frames(result.rig), tmp_path / "run", total=len(result.trajectory))
    metrics = evaluate_output(tmp_path / "run", load_groundtruth(data)).metrics
    assert len(calls) > 50 and max(float(np.ptp(centers, axis=0).max()) for centers in calls) > 0.05  # rows apart by centimetres
    assert metrics.tractor_ate_m < 0.005 * metrics.distance_m
    assert metrics.hitch_rmse_deg < 0.3 and metrics.hitch_within_3sigma >= 0.99


def test_the_realistic_ci_route_on_fisheye_images(tmp_path):
    """The CI route rendered through the semitrailer rig with equidistant fisheye lenses on every
    camera (configs/rigs/semitrailer_fisheye.yaml: ~150 deg, the mirror cameras see the trailer's
    side, rolling shutter, vignetting) and run on its images: issue 16's limits hold on fisheye
    cameras as on pinholes (measured 2026-12-07: ATE 0.048 m of 37 m, hitch RMSE 0.05 deg / max
    0.09 deg, all within 2 sigma, median sigma 0.15 deg)."""
    import dataclasses

    from ampc_vo.config import VoConfig
    from ampc_vo.frontend.sources import open_sequence
    from ampc_vo.sim.config import load_sim_config
    from ampc_vo.sim.simulation import simulate_dataset
    from ampc_vo.tools.runner import run_sequence

    config = dataclasses.replace(load_sim_config(ROOT / "configs" / "sim" / "realistic_ci_short.yaml"),
                                 rig_path=ROOT / "configs" / "rigs" / "semitrailer_fisheye.yaml")
    simulate_dataset(config, tmp_path / "data", with_images=True)
    sequence = open_sequence(tmp_path / "data", VoConfig())
    assert {camera.model for camera in sequence.rig.cameras} == {"fisheye"} and sequence.rig.hitch_height == 1.2
    summary, _ = run_sequence(sequence, VoConfig(), tmp_path / "out", progress=False)
    metrics = evaluate_output(tmp_path / "out", sequence.truth).metrics
    assert summary.keyframes >= 15
    assert metrics.tractor_ate_m < 0.01 * metrics.distance_m
    assert metrics.hitch_rmse_deg < 0.3 and metrics.hitch_max_deg < 1.5 and metrics.hitch_within_2sigma >= 0.95
    assert metrics.hitch_sigma_median_deg < 0.3
