"""Per-camera simulation settings: the sim config's ``cameras:`` section (issue 13).

Timing (when each image is captured) and image formation (exposure, noise, vignetting) of each
camera. The rig says *how* a camera reads out (``readout_time`` in rig.yaml, a property of the
sensor the estimator must know); this section says what the simulated cameras do that the rig file
does not state: they are not synchronised, their trigger jitters, they expose and amplify::

    cameras:
      all:                     # defaults for every camera (optional)
        jitter_ms: 1.0         # standard deviation of the trigger jitter
        exposure_ms: 8.0       # nominal (and, with auto exposure, the longest) exposure time
        auto_exposure: true
        full_well_e: 6000      # electrons at white (shot noise: Poisson in electrons)
        read_noise_e: 8        # electrons RMS (Gaussian)
        vignetting: 0.5        # 0: none, 1: the full cos^4 fall-off
      front: {offset_ms: 0}
      left: {offset_ms: 23}    # per-camera overrides: this camera fires 23 ms after the frame time

Every field is optional; the defaults are an ideal synchronised global-shutter camera without noise
(what the simulator did before). Unknown keys and out-of-range values raise :class:`ConfigError`
naming the file and the field; camera names are checked against the rig by :func:`settings_for`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from ampc_vo.errors import ConfigError

__all__ = ["CameraSettings", "CameraSettingsTable", "camera_settings_from_dict", "settings_for"]

DEFAULTS_KEY = "all"


@dataclass(frozen=True)
class CameraSettings:
    """Timing and image formation of one simulated camera (module docstring; seconds inside)."""

    offset_s: float = 0.0             # capture time - frame time (YAML offset_ms)
    jitter_s: float = 0.0             # standard deviation of a Gaussian trigger jitter (YAML jitter_ms)
    exposure_s: float = 0.0           # nominal exposure (YAML exposure_ms); 0: instantaneous, no motion blur
    auto_exposure: bool = False       # exposure and gain follow the scene brightness (camera_effects)
    target_grey: float = 110.0        # auto exposure aims the mean grey level here
    exposure_time_constant_s: float = 0.4  # first-order lag of the auto-exposure loop
    max_gain: float = 8.0             # analogue gain once the exposure reaches exposure_s
    full_well_e: float = 0.0          # electrons at grey 255 and unit gain; 0: no shot noise
    read_noise_e: float = 0.0         # electrons RMS of read noise
    vignetting: float = 0.0           # fraction of the cos^4 law applied (0..1)
    motion_blur_samples: int = 4      # most sub-exposures averaged for motion blur (fewer when the motion is small)


_MILLISECONDS = {"offset_ms": "offset_s", "jitter_ms": "jitter_s", "exposure_ms": "exposure_s"}
_PLAIN = ("auto_exposure", "target_grey", "exposure_time_constant_s", "max_gain", "full_well_e", "read_noise_e", "vignetting",
          "motion_blur_samples")
_LIMITS = {  # field: (minimum, maximum)
    "offset_s": (-0.5, 0.5), "jitter_s": (0.0, 0.05), "exposure_s": (0.0, 0.1), "target_grey": (10.0, 245.0),
    "exposure_time_constant_s": (0.0, 10.0), "max_gain": (1.0, 64.0), "full_well_e": (0.0, 1e6), "read_noise_e": (0.0, 1e3),
    "vignetting": (0.0, 1.0), "motion_blur_samples": (1, 32),
}


@dataclass(frozen=True)
class CameraSettingsTable:
    """The parsed ``cameras:`` section: defaults and per-camera overrides."""

    defaults: CameraSettings = field(default_factory=CameraSettings)
    overrides: dict[str, CameraSettings] = field(default_factory=dict)
    source: str = "cameras"

    def get(self, camera: str) -> CameraSettings:
        return self.overrides.get(camera, self.defaults)


def _parse_one(raw: Any, base: CameraSettings, where: str) -> CameraSettings:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping of camera settings, got {raw!r}")
    values: dict[str, Any] = {}
    for key, value in raw.items():
        name = _MILLISECONDS.get(key, key if key in _PLAIN else None)
        if name is None:
            raise ConfigError(f"{where}.{key}: unknown camera setting (known: {', '.join(sorted([*_MILLISECONDS, *_PLAIN]))})")
        if name == "auto_exposure":
            if not isinstance(value, bool):
                raise ConfigError(f"{where}.{key}: expected true or false, got {value!r}")
            values[name] = value
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
            raise ConfigError(f"{where}.{key}: expected a number, got {value!r}")
        if name == "motion_blur_samples" and not isinstance(value, int):
            raise ConfigError(f"{where}.{key}: expected an integer, got {value!r}")
        number = value / 1000.0 if key in _MILLISECONDS else value
        low, high = _LIMITS[name]
        if not low <= number <= high:
            scale = 1000.0 if key in _MILLISECONDS else 1.0
            raise ConfigError(f"{where}.{key}: must be in [{low * scale:g}, {high * scale:g}], got {value!r}")
        values[name] = number
    return dataclasses.replace(base, **values)


def camera_settings_from_dict(raw: Any, source: str) -> CameraSettingsTable:
    """Parse the ``cameras:`` section (module docstring); ``source`` names the file in errors."""
    if raw is None:
        return CameraSettingsTable(source=source)
    where = f"{source}: cameras"
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping of camera names to settings")
    defaults = _parse_one(raw.get(DEFAULTS_KEY, {}), CameraSettings(), f"{where}.{DEFAULTS_KEY}")
    overrides = {str(name): _parse_one(value, defaults, f"{where}.{name}") for name, value in raw.items() if name != DEFAULTS_KEY}
    return CameraSettingsTable(defaults, overrides, source)


def settings_for(table: CameraSettingsTable, camera_names: tuple[str, ...] | list[str], rig_source: str = "the rig") -> list[CameraSettings]:
    """Settings of each rig camera, in rig order; a name in the section that the rig lacks is a ConfigError."""
    unknown = sorted(set(table.overrides) - set(camera_names))
    if unknown:
        raise ConfigError(f"{table.source}: cameras: {unknown} not in {rig_source} (cameras: {list(camera_names)})")
    return [table.get(name) for name in camera_names]
