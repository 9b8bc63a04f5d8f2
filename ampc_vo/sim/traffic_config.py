"""The sim config's ``traffic:`` and ``trailer_body:`` sections (issue 13): what moves in the world
(the motion itself: ``sim.traffic``, whose docstring describes the keys)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ampc_vo.errors import ConfigError

__all__ = ["VehicleSpec", "TrailerBodySpec", "traffic_from_list", "trailer_body_from_dict", "KINDS", "SIZES"]

KINDS = ("leading", "oncoming", "overtaking", "crossing")
SIZES = {"car": (4.5, 1.8, 1.5), "van": (5.5, 2.0, 2.4), "truck": (12.0, 2.5, 3.6)}
_TEXTURES = ("metal", "paint", "metal", "wood")


@dataclass(frozen=True)
class VehicleSpec:
    """One traffic vehicle (module docstring)."""

    kind: str
    size: tuple[float, float, float] = SIZES["car"]
    speed_mps: float = 10.0
    start_m: float = 60.0
    lateral_m: float = 0.0
    gap_m: float = 20.0
    gap_variation_m: float = 0.0
    relative_speed_mps: float = 3.0
    at_m: float = 50.0
    time_s: float = 5.0
    texture: str = "metal"


@dataclass(frozen=True)
class TrailerBodySpec:
    """The trailer's box in the trailer frame (module docstring)."""

    length_m: float = 13.6
    width_m: float = 2.55
    height_m: float = 2.7
    front_x_m: float = 1.5
    floor_height_m: float = 1.25
    texture: str = "metal"


_VEHICLE_DEFAULT_LATERAL = {"leading": 0.0, "oncoming": 3.5, "overtaking": 3.5, "crossing": 0.0}


def _number(raw: dict, key: str, where: str, default: float, minimum: float | None = None) -> float:
    value = raw.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}.{key}: expected a finite number, got {value!r}")
    if minimum is not None and value < minimum:
        raise ConfigError(f"{where}.{key}: must be >= {minimum}, got {value!r}")
    return float(value)


def traffic_from_list(raw: Any, source: str) -> tuple[VehicleSpec, ...]:
    """Parse the ``traffic:`` list (module docstring); errors name the file and the entry."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ConfigError(f"{source}: traffic: expected a list of vehicles")
    known = {"kind", "size", "speed_mps", "start_m", "lateral_m", "gap_m", "gap_variation_m", "relative_speed_mps", "at_m", "time_s", "texture"}
    vehicles = []
    for index, item in enumerate(raw):
        where = f"{source}: traffic[{index}]"
        if not isinstance(item, dict):
            raise ConfigError(f"{where}: expected a mapping, got {item!r}")
        unknown = set(item) - known
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)} (known: {sorted(known)})")
        kind = item.get("kind")
        if kind not in KINDS:
            raise ConfigError(f"{where}.kind: expected one of {KINDS}, got {kind!r}")
        size = item.get("size", "car")
        if isinstance(size, str):
            if size not in SIZES:
                raise ConfigError(f"{where}.size: expected one of {sorted(SIZES)} or [length, width, height], got {size!r}")
            size = SIZES[size]
        elif not (isinstance(size, list) and len(size) == 3 and all(isinstance(v, (int, float)) and v > 0 for v in size)):
            raise ConfigError(f"{where}.size: expected one of {sorted(SIZES)} or [length, width, height] > 0, got {size!r}")
        texture = item.get("texture", _TEXTURES[index % len(_TEXTURES)])
        if not isinstance(texture, str):
            raise ConfigError(f"{where}.texture: expected a texture name, got {texture!r}")
        vehicles.append(VehicleSpec(
            kind=kind, size=tuple(float(v) for v in size), speed_mps=_number(item, "speed_mps", where, 10.0, 0.0),
            start_m=_number(item, "start_m", where, 60.0 if kind == "oncoming" else -25.0),
            lateral_m=_number(item, "lateral_m", where, _VEHICLE_DEFAULT_LATERAL[kind]),
            gap_m=_number(item, "gap_m", where, 20.0, 0.0), gap_variation_m=_number(item, "gap_variation_m", where, 0.0, 0.0),
            relative_speed_mps=_number(item, "relative_speed_mps", where, 3.0), at_m=_number(item, "at_m", where, 50.0),
            time_s=_number(item, "time_s", where, 5.0), texture=texture))
    return tuple(vehicles)


def trailer_body_from_dict(raw: Any, source: str) -> TrailerBodySpec | None:
    """Parse the ``trailer_body:`` mapping (``None``: no box); ``true`` takes the defaults."""
    if raw is None or raw is False:
        return None
    if raw is True:
        return TrailerBodySpec()
    where = f"{source}: trailer_body"
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping or true")
    known = {"length_m", "width_m", "height_m", "front_x_m", "floor_height_m", "texture"}
    unknown = set(raw) - known
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)} (known: {sorted(known)})")
    default = TrailerBodySpec()
    return TrailerBodySpec(
        length_m=_number(raw, "length_m", where, default.length_m, 0.5), width_m=_number(raw, "width_m", where, default.width_m, 0.5),
        height_m=_number(raw, "height_m", where, default.height_m, 0.2), front_x_m=_number(raw, "front_x_m", where, default.front_x_m),
        floor_height_m=_number(raw, "floor_height_m", where, default.floor_height_m, 0.0), texture=str(raw.get("texture", default.texture)))
