"""Simulation config files: every shipped config loads; bad fields give errors naming file and field."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from ampc_vo.errors import ConfigError
from ampc_vo.sim.config import load_sim_config

SIM_DIR = Path(__file__).resolve().parents[2] / "configs" / "sim"
REQUIRED_ROUTES = ("city_block", "roundabout", "gentle_curve", "highway_lane_changes", "yard", "demo")
REALISTIC_ROUTES = ("realistic_city_start", "realistic_yard_reverse", "realistic_hilly_rural", "realistic_motorway",
                    "realistic_stop_and_go", "realistic_ci_short")


def test_realistic_suite_is_labelled_on_the_semitrailer_rig_and_starts_and_ends_at_rest():
    for name in REALISTIC_ROUTES:
        config = load_sim_config(SIM_DIR / f"{name}.yaml")
        assert config.label == "realistic" and config.rig_path.name == "semitrailer.yaml", name
        assert config.route.segments[0].kind == "stop" and config.route.acceleration is not None, name
        assert config.vehicle.suspension and config.vehicle.trailer_axles > 1, name
        if name != "realistic_ci_short":
            assert config.route.segments[-1].kind == "stop", name
    for path in SIM_DIR.glob("*.yaml"):
        label = load_sim_config(path).label
        assert label == ("realistic" if path.stem.startswith("realistic_") else "ideal"), path.name
    motorway = load_sim_config(SIM_DIR / "realistic_motorway.yaml")
    assert max(segment.speed for segment in motorway.route.segments) >= 25.0
    assert any(segment.kind == "lane_change" for segment in motorway.route.segments)
    hilly = load_sim_config(SIM_DIR / "realistic_hilly_rural.yaml")
    assert max(abs(grade) for _, grade in hilly.road.grade_changes) == 0.08 and hilly.road.crown > 0 and hilly.road.max_superelevation > 0
    yard = load_sim_config(SIM_DIR / "realistic_yard_reverse.yaml")
    directions = [segment.reverse for segment in yard.route.segments if segment.kind != "stop"]
    assert sum(a != b for a, b in zip(directions, directions[1:])) == 2


def test_required_route_configs_exist_and_load():
    for name in REQUIRED_ROUTES:
        config = load_sim_config(SIM_DIR / f"{name}.yaml")
        assert config.rig_path.is_file() and config.route.length > 0
    assert load_sim_config(SIM_DIR / "city_block.yaml").route.length >= 400.0
    demo = load_sim_config(SIM_DIR / "demo.yaml")
    assert 18.0 <= demo.route.length / demo.speed <= 22.0 and demo.rate_hz == 10


def _write(tmp_path: Path, changes: dict, drop: tuple = ()) -> Path:
    raw = yaml.safe_load((SIM_DIR / "demo.yaml").read_text())
    raw["rig"] = str(SIM_DIR.parent / "rigs" / "default.yaml")
    raw.update(changes)
    for key in drop:
        raw.pop(key)
    path = tmp_path / "broken_sim.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize(
    "changes, drop, field",
    [
        ({"rig": "no/such/rig.yaml"}, (), "rig"),
        ({}, ("rig",), "rig: missing"),
        ({"rate_hz": -1}, (), "rate_hz"),
        ({"outlier_fraction": 1.5}, (), "outlier_fraction"),
        ({"max_tracks_per_camera": 0}, (), "max_tracks_per_camera"),
        ({"segments": []}, (), "segments"),
        ({"segments": [{"type": "turn", "angle_deg": 90, "radius": -3}]}, (), "segments[0].radius"),
        ({"segments": [{"type": "straight", "length": 10, "radius": 3}]}, (), "segments[0]: unknown field"),
        ({"scene": {"facade_distance": [5]}}, (), "scene.facade_distance"),
        ({"scene": {"tree_density": 1}}, (), "scene: unknown field"),
        ({"speeed": 3}, (), "unknown field(s) ['speeed']"),
        ({"tyre_slip_deg_per_mps2": -0.1}, (), "tyre_slip_deg_per_mps2"),
        ({"road": {"grade": 5}}, (), "road: unknown field(s) ['grade']"),
        ({"road": {"start_grade_percent": 40}}, (), "road.start_grade_percent"),
        ({"road": {"grades": [[100, 4], [50, 2]]}}, (), "road.grades[1]: stations must increase"),
        ({"road": {"grades": [[100]]}}, (), "road.grades[0]"),
        ({"road": {"bumps": [{"station": 3, "lateral": 0, "length": 1, "width": 1}]}}, (), "road.bumps[0]: missing ['height']"),
        ({"road": {"crown_percent": 2}, "segments": [{"type": "straight", "length": 10, "reverse": True}]}, (), "road: a grade/crown"),
        ({"vehicle": {"load": "heavy"}}, (), "vehicle.load"),
        ({"vehicle": {"trailer_axles": 4}}, (), "vehicle.trailer_axles"),
        ({"driving": {"acceleration": 0}}, (), "driving.acceleration"),
        ({"driving": {"jerk": 1}}, (), "driving: unknown field"),
        ({"segments": [{"type": "stop", "duration": 1, "reverse": True}]}, (), "segments[0].reverse"),
        ({"label": "fancy"}, (), "label"),
        ({"dense_rate_hz": 50}, (), "dense_rate_hz"),
    ],
)
def test_bad_configs_name_file_and_field(tmp_path, changes, drop, field):
    path = _write(tmp_path, changes, drop)
    with pytest.raises(ConfigError) as error:
        load_sim_config(path)
    assert str(path) in str(error.value) and field in str(error.value), str(error.value)


def test_rig_path_relative_to_the_repository(tmp_path):
    path = _write(tmp_path, {"rig": "configs/rigs/default.yaml"})
    assert load_sim_config(path).rig_path.name == "default.yaml"


def test_a_binary_file_is_a_config_error(tmp_path):
    path = tmp_path / "binary.yaml"
    path.write_bytes(b"\xff\xfe\x00garbage\x89")  # used to be a UnicodeDecodeError traceback
    with pytest.raises(ConfigError, match="binary.yaml: not valid YAML"):
        load_sim_config(path)


def test_tyre_slip_reaches_the_simulated_trajectory(tmp_path):
    """``tyre_slip_deg_per_mps2`` (degrees per m/s^2) is read in radians and drives the kinematics."""
    import math

    from ampc_vo.sim.simulation import simulate

    assert load_sim_config(SIM_DIR / "demo.yaml").tyre_slip == 0.0
    slipping = load_sim_config(_write(tmp_path, {"tyre_slip_deg_per_mps2": 0.5}))
    assert slipping.tyre_slip == pytest.approx(math.radians(0.5))
    ideal = simulate(SIM_DIR / "ci_short.yaml").trajectory
    import dataclasses

    slipped = simulate(dataclasses.replace(load_sim_config(SIM_DIR / "ci_short.yaml"), tyre_slip=math.radians(0.5))).trajectory
    from ampc_vo.geometry import yaw_of

    heading_change = max(abs(yaw_of(a) - yaw_of(b)) for a, b in zip(slipped.T_world_tractor, ideal.T_world_tractor))
    assert math.radians(0.5) < heading_change < math.radians(3.0)  # the same axle path, turned headings in the turn
