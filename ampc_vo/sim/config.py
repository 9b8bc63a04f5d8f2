"""Simulation configs (``configs/sim/*.yaml``): route, rig, camera rate, noise and scene parameters.

Example::

    rig: ../rigs/default.yaml          # relative to this file, or to the repository root
    rate_hz: 10
    speed: 8.0                         # m/s, default speed of every segment
    duration: null                     # seconds; null = drive the route to its end
    initial_hitch_angle_deg: 0
    tyre_slip_deg_per_mps2: 0          # slip angle of each axle per lateral acceleration (0: ideal rolling)
    seed: 1
    pixel_noise_px: 0.5
    outlier_fraction: 0.1
    max_range_m: 60
    max_tracks_per_camera: 200
    segments:
      - {type: straight, length: 40}
      - {type: turn, angle_deg: 90, radius: 20, transition: 8}
    scene: {road_width: 7.0, facade_distance: [6, 25]}
    render: {sensor_noise_sigma: 1.0}  # optional, options of ampc_vo.sim.render.RenderOptions
    label: realistic                   # or ideal (flat road, rigid bodies, kinematics obeyed exactly)
    driving: {acceleration: 0.8, deceleration: 2.5, direction_change_pause_s: 1.5}   # routes.Route
    road: {start_grade_percent: 0, grades: [[200, 6], [500, -8]], vertical_curve_m: 120, crown_percent: 2.5,
           max_superelevation_percent: 6, design_speed: 20, lane_offset_m: 1.75,
           plane_slope_percent: [0, 0], bumps: [{station: 80, lateral: -1.75, length: 0.8, width: 0.6, height: -0.05}]}
    vehicle: {trailer_axles: 3, load: loaded, suspension: true, engine_deg: 0.01, road_deg_per_mps: 0.004, mount_deg_per_mps: 0.003}
    dense_rate_hz: 200                 # SimulationResult.dense_trajectory
    cameras: {left: {offset_ms: 23}}   # optional, per-camera timing and image formation (sim.camera_settings)
    traffic: [{kind: oncoming}]        # optional, moving vehicles (sim.traffic)
    trailer_body: true                 # optional, the trailer's box in the tractor cameras (sim.traffic)

Every problem raises :class:`ConfigError` naming the file and the field.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ampc_vo.errors import ConfigError
from ampc_vo.rig import Rig, load_rig
from ampc_vo.sim.attitude import SUSPENSION, VehicleConfig
from ampc_vo.sim.road import RoadConfig
from ampc_vo.sim.camera_settings import CameraSettingsTable, camera_settings_from_dict
from ampc_vo.sim.traffic_config import TrailerBodySpec, VehicleSpec, trailer_body_from_dict, traffic_from_list
from ampc_vo.sim.routes import Route, route_from_list

REPOSITORY_ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class SceneConfig:
    """Parameters of the procedural world built around the route (``scene.build_scene``)."""

    road_width: float = 7.0                          # m, asphalt strip centred on the tractor path
    shoulder_width: float = 3.0                      # m, gravel strip on each side of the road
    clearance: float = 4.0                           # m, nothing closer to the swept path
    facade_distance: tuple[float, float] = (5.0, 25.0)  # m, lateral distance of facades from the path
    facade_height: tuple[float, float] = (4.0, 14.0)
    facade_length: tuple[float, float] = (8.0, 24.0)
    facade_gap: tuple[float, float] = (0.0, 6.0)     # m between consecutive facades on one side
    object_spacing: float = 15.0                     # m between free-standing boxes/poles (per side)
    extension_m: float = 60.0                        # m of straight road added before start / after end
    ground_margin_m: float = 80.0                    # m of ground beyond the route's bounding box
    landmark_density_facade: float = 1.2             # landmarks per m^2 on facades/boxes/poles
    landmark_density_ground: float = 0.3             # landmarks per m^2 on road and ground near the route
    ground_landmark_band_m: float = 25.0             # m: ground landmarks within this distance of the path


@dataclass(frozen=True)
class SimulationConfig:
    """A parsed ``configs/sim/*.yaml``."""

    source: str
    rig_path: Path
    route: Route
    rate_hz: float = 10.0
    speed: float = 8.0
    duration: float | None = None
    initial_hitch_angle: float = 0.0                 # radians (YAML: initial_hitch_angle_deg)
    tyre_slip: float = 0.0                           # rad per m/s^2 of lateral acceleration (YAML: tyre_slip_deg_per_mps2)
    seed: int = 0
    pixel_noise_px: float = 0.5
    outlier_fraction: float = 0.1
    max_range_m: float = 60.0
    min_range_m: float = 0.5
    max_tracks_per_camera: int = 200
    scene: SceneConfig = field(default_factory=SceneConfig)
    render: dict | None = None                       # renderer options (``render.render_options_from_dict``)
    road: RoadConfig = field(default_factory=RoadConfig)        # 3D road (``road:``; default flat)
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)  # wheels, load, body motion (``vehicle:``)
    dense_rate_hz: float = 200.0                     # rate of SimulationResult.dense_trajectory (>= 200 Hz)
    label: str = ""                                  # "ideal" or "realistic" (YAML label)
    cameras: CameraSettingsTable = field(default_factory=CameraSettingsTable)  # per-camera timing and effects
    traffic: tuple[VehicleSpec, ...] = ()            # moving vehicles (``sim.traffic``)
    trailer_body: TrailerBodySpec | None = None      # the trailer's box, seen by the tractor's cameras

    def load_rig(self) -> Rig:
        return load_rig(self.rig_path)


_TOP_LEVEL = {
    "rig", "rate_hz", "speed", "duration", "initial_hitch_angle_deg", "tyre_slip_deg_per_mps2", "seed", "pixel_noise_px", "outlier_fraction",
    "max_range_m", "min_range_m", "max_tracks_per_camera", "segments", "scene", "render", "speed_ramp_m", "description", "name",
    "road", "driving", "vehicle", "dense_rate_hz", "label", "cameras", "traffic", "trailer_body",
}
_DRIVING_KEYS = {"acceleration", "deceleration", "direction_change_pause_s"}
_ROAD_KEYS = {"start_grade_percent", "grades", "vertical_curve_m", "crown_percent", "max_superelevation_percent", "design_speed",
              "lane_offset_m", "plane_slope_percent", "bumps"}
_BUMP_KEYS = ("station", "lateral", "length", "width", "height")


def _section(raw: Any, name: str, allowed: set[str] | tuple[str, ...], source: str) -> dict:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: {name}: expected a mapping")
    unknown = set(raw) - set(allowed)
    if unknown:
        raise ConfigError(f"{source}: {name}: unknown field(s) {sorted(unknown)} (allowed: {sorted(allowed)})")
    return raw


def _road_from_dict(raw: Any, source: str) -> RoadConfig:
    """The ``road:`` section (``road.RoadConfig``); grades within +-15 %."""
    raw = _section(raw, "road", _ROAD_KEYS, source)
    percent = lambda key, default=0.0, low=-15.0, high=15.0: _float(raw, key, source, default, minimum=low, maximum=high, where="road.") / 100.0  # noqa: E731
    grades = raw.get("grades", [])
    if not isinstance(grades, list):
        raise ConfigError(f"{source}: road.grades: expected a list of [station_m, grade_percent]")
    changes = []
    for index, item in enumerate(grades):
        if not isinstance(item, (list, tuple)) or len(item) != 2:
            raise ConfigError(f"{source}: road.grades[{index}]: expected [station_m, grade_percent], got {item!r}")
        station = _float({"v": item[0]}, "v", source, 0.0, where=f"road.grades[{index}][0]/")
        grade = _float({"v": item[1]}, "v", source, 0.0, minimum=-15.0, maximum=15.0, where=f"road.grades[{index}][1]/")
        if changes and station <= changes[-1][0]:
            raise ConfigError(f"{source}: road.grades[{index}]: stations must increase")
        changes.append((station, grade / 100.0))
    plane = raw.get("plane_slope_percent", [0.0, 0.0])
    if not isinstance(plane, (list, tuple)) or len(plane) != 2:
        raise ConfigError(f"{source}: road.plane_slope_percent: expected [x_percent, y_percent]")
    plane_slope = tuple(_float({"v": value}, "v", source, 0.0, minimum=-15.0, maximum=15.0, where=f"road.plane_slope_percent[{index}]/") / 100.0
                        for index, value in enumerate(plane))
    bumps_raw = raw.get("bumps", [])
    if not isinstance(bumps_raw, list):
        raise ConfigError(f"{source}: road.bumps: expected a list of {{{', '.join(_BUMP_KEYS)}}}")
    bumps = []
    for index, bump in enumerate(bumps_raw):
        bump = _section(bump, f"road.bumps[{index}]", _BUMP_KEYS, source)
        missing = [key for key in _BUMP_KEYS if key not in bump]
        if missing:
            raise ConfigError(f"{source}: road.bumps[{index}]: missing {missing}")
        values = tuple(_float(bump, key, source, 0.0, where=f"road.bumps[{index}].") for key in _BUMP_KEYS)
        if values[2] <= 0.0 or values[3] <= 0.0 or abs(values[4]) > 0.3:
            raise ConfigError(f"{source}: road.bumps[{index}]: length and width must be > 0 and |height| <= 0.3 m")
        bumps.append(values)
    return RoadConfig(
        start_grade=percent("start_grade_percent"), grade_changes=tuple(changes),
        vertical_curve_m=_float(raw, "vertical_curve_m", source, 80.0, minimum=1.0, where="road."),
        crown=percent("crown_percent", 0.0, 0.0, 10.0), max_superelevation=percent("max_superelevation_percent", 0.0, 0.0, 12.0),
        design_speed=_float(raw, "design_speed", source, 15.0, minimum=0.0, where="road."),
        lane_offset_m=_float(raw, "lane_offset_m", source, 0.0, where="road."), plane_slope=plane_slope, bumps=tuple(bumps),
    )


def _vehicle_from_dict(raw: Any, source: str) -> VehicleConfig:
    """The ``vehicle:`` section (``attitude.VehicleConfig``)."""
    names = {item.name for item in dataclasses.fields(VehicleConfig)}
    raw = _section(raw, "vehicle", names, source)
    defaults = VehicleConfig()
    values: dict[str, Any] = {}
    for name in raw:
        default = getattr(defaults, name)
        if name == "load":
            if raw[name] not in SUSPENSION:
                raise ConfigError(f"{source}: vehicle.load: expected one of {sorted(SUSPENSION)}, got {raw[name]!r}")
            values[name] = raw[name]
        elif name == "suspension":
            if not isinstance(raw[name], bool):
                raise ConfigError(f"{source}: vehicle.suspension: expected true or false")
            values[name] = raw[name]
        elif name == "trailer_axles":
            if not isinstance(raw[name], int) or isinstance(raw[name], bool) or not 1 <= raw[name] <= 3:
                raise ConfigError(f"{source}: vehicle.trailer_axles: expected 1, 2 or 3, got {raw[name]!r}")
            values[name] = raw[name]
        else:
            values[name] = _float(raw, name, source, default, minimum=0.0, where="vehicle.")
    vehicle = VehicleConfig(**values)
    if vehicle.tractor_wheelbase_m <= 0.0 or vehicle.half_track_m <= 0.0:
        raise ConfigError(f"{source}: vehicle: tractor_wheelbase_m and half_track_m must be > 0")
    return vehicle


def _float(raw: dict, key: str, source: str, default: float, minimum: float | None = None, maximum: float | None = None, where: str = "") -> float:
    value = raw.get(key, default)
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: {where}{key}: expected a number, got {value!r}") from None
    if number != number or number in (float("inf"), float("-inf")):
        raise ConfigError(f"{source}: {where}{key}: must be finite, got {value!r}")
    if minimum is not None and number < minimum:
        raise ConfigError(f"{source}: {where}{key}: must be >= {minimum}, got {value!r}")
    if maximum is not None and number > maximum:
        raise ConfigError(f"{source}: {where}{key}: must be <= {maximum}, got {value!r}")
    return number


def _resolve_rig(value: Any, config_path: Path, source: str) -> Path:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{source}: rig: expected a path to a rig.yaml, got {value!r}")
    candidate = Path(value)
    options = [candidate] if candidate.is_absolute() else [config_path.parent / candidate, REPOSITORY_ROOT / candidate, Path.cwd() / candidate]
    for option in options:
        if option.is_file():
            return option.resolve()
    raise ConfigError(f"{source}: rig: file {value!r} not found (looked in {[str(option) for option in options]})")


def _scene_from_dict(raw: Any, source: str) -> SceneConfig:
    if raw is None:
        return SceneConfig()
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: scene: expected a mapping")
    defaults = SceneConfig()
    values: dict[str, Any] = {}
    for item in dataclasses.fields(SceneConfig):
        if item.name not in raw:
            continue
        default = getattr(defaults, item.name)
        if isinstance(default, tuple):
            pair = raw[item.name]
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                raise ConfigError(f"{source}: scene.{item.name}: expected [min, max], got {pair!r}")
            low = _float({"v": pair[0]}, "v", source, 0.0, minimum=0.0, where=f"scene.{item.name}[0]/")
            high = _float({"v": pair[1]}, "v", source, 0.0, minimum=low, where=f"scene.{item.name}[1]/")
            values[item.name] = (low, high)
        else:
            values[item.name] = _float(raw, item.name, source, default, minimum=0.0, where="scene.")
    unknown = set(raw) - {item.name for item in dataclasses.fields(SceneConfig)}
    if unknown:
        raise ConfigError(f"{source}: scene: unknown field(s) {sorted(unknown)}")
    return SceneConfig(**values)


def sim_config_from_dict(raw: Any, config_path: Path) -> SimulationConfig:
    """Validate a parsed YAML mapping; ``config_path`` names the file in errors and anchors ``rig``."""
    source = str(config_path)
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: expected a mapping of simulation settings")
    unknown = set(raw) - _TOP_LEVEL
    if unknown:
        raise ConfigError(f"{source}: unknown field(s) {sorted(unknown)} (allowed: {sorted(_TOP_LEVEL)})")
    if "rig" not in raw:
        raise ConfigError(f"{source}: rig: missing")
    rig_path = _resolve_rig(raw["rig"], config_path, source)
    speed = _float(raw, "speed", source, 8.0, minimum=0.1)
    if "segments" not in raw:
        raise ConfigError(f"{source}: segments: missing")
    driving = _section(raw.get("driving"), "driving", _DRIVING_KEYS, source)
    route = route_from_list(
        raw["segments"], speed, source, speed_ramp_m=_float(raw, "speed_ramp_m", source, 10.0, minimum=0.0),
        acceleration=_float(driving, "acceleration", source, 1.0, minimum=0.05, maximum=5.0, where="driving.") if "acceleration" in driving else None,
        deceleration=_float(driving, "deceleration", source, 2.5, minimum=0.05, maximum=8.0, where="driving."),
        direction_change_pause_s=_float(driving, "direction_change_pause_s", source, 1.0, minimum=0.0, where="driving."))
    road = _road_from_dict(raw.get("road"), source)
    if road.has_profile and any(segment.reverse for segment in route.segments):
        raise ConfigError(f"{source}: road: a grade/crown/superelevation profile needs a route without reverse segments "
                          "(its centre line must not fold back); use plane_slope_percent and bumps")
    label = raw.get("label", "")
    if label not in ("", "ideal", "realistic"):
        raise ConfigError(f"{source}: label: expected 'ideal' or 'realistic', got {label!r}")
    duration = raw.get("duration")
    duration = None if duration is None else _float(raw, "duration", source, 0.0, minimum=1e-3)
    max_tracks = raw.get("max_tracks_per_camera", 200)
    if not isinstance(max_tracks, int) or isinstance(max_tracks, bool) or max_tracks < 1:
        raise ConfigError(f"{source}: max_tracks_per_camera: expected a positive integer, got {max_tracks!r}")
    seed = raw.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise ConfigError(f"{source}: seed: expected an integer, got {seed!r}")
    min_range = _float(raw, "min_range_m", source, 0.5, minimum=0.0)
    return SimulationConfig(
        source=source,
        rig_path=rig_path,
        route=route,
        rate_hz=_float(raw, "rate_hz", source, 10.0, minimum=0.1, maximum=1000.0),
        speed=speed,
        duration=duration,
        initial_hitch_angle=_float(raw, "initial_hitch_angle_deg", source, 0.0, minimum=-80.0, maximum=80.0) * 3.141592653589793 / 180.0,
        tyre_slip=math.radians(_float(raw, "tyre_slip_deg_per_mps2", source, 0.0, minimum=0.0, maximum=2.0)),
        seed=seed,
        pixel_noise_px=_float(raw, "pixel_noise_px", source, 0.5, minimum=0.0),
        outlier_fraction=_float(raw, "outlier_fraction", source, 0.1, minimum=0.0, maximum=1.0),
        max_range_m=_float(raw, "max_range_m", source, 60.0, minimum=min_range + 1e-6),
        min_range_m=min_range,
        max_tracks_per_camera=max_tracks,
        scene=_scene_from_dict(raw.get("scene"), source),
        render=_render_section(raw.get("render"), source),
        road=road,
        vehicle=_vehicle_from_dict(raw.get("vehicle"), source),
        dense_rate_hz=_float(raw, "dense_rate_hz", source, 200.0, minimum=200.0, maximum=2000.0),
        label=label,
        cameras=camera_settings_from_dict(raw.get("cameras"), source),
        traffic=traffic_from_list(raw.get("traffic"), source),
        trailer_body=trailer_body_from_dict(raw.get("trailer_body"), source),
    )


def _render_section(raw: Any, source: str) -> dict | None:
    """The ``render`` mapping, passed to the renderer (which validates its keys)."""
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: render: expected a mapping of renderer options")
    return dict(raw)


def load_sim_config(path: str | Path) -> SimulationConfig:
    """Read and validate a simulation YAML file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: simulation config not found")
    try:
        raw = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as error:  # a binary or non-UTF-8 file too
        raise ConfigError(f"{path}: not valid YAML: {error}") from None
    return sim_config_from_dict(raw, path)
