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
    cameras: CameraSettingsTable = field(default_factory=CameraSettingsTable)  # per-camera timing and effects
    traffic: tuple[VehicleSpec, ...] = ()            # moving vehicles (``sim.traffic``)
    trailer_body: TrailerBodySpec | None = None      # the trailer's box, seen by the tractor's cameras

    def load_rig(self) -> Rig:
        return load_rig(self.rig_path)


_TOP_LEVEL = {
    "rig", "rate_hz", "speed", "duration", "initial_hitch_angle_deg", "tyre_slip_deg_per_mps2", "seed", "pixel_noise_px", "outlier_fraction",
    "max_range_m", "min_range_m", "max_tracks_per_camera", "segments", "scene", "render", "cameras", "traffic", "trailer_body", "speed_ramp_m", "description", "name",
}


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
    route = route_from_list(raw["segments"], speed, source, speed_ramp_m=_float(raw, "speed_ramp_m", source, 10.0, minimum=0.0))
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
