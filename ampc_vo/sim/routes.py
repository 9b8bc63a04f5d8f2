"""Route descriptions for the simulator: speed and curvature as functions of arc length (DESIGN 6).

A route is a list of segments driven one after the other by the tractor's rear-axle midpoint.
Each segment has a length (metres), a curvature profile ``kappa(s)`` over its local arc length
``s`` in [0, length] (1/m, positive = left turn) and a target speed (m/s). Segment kinds:

* ``straight``: ``kappa = 0``;
* ``turn``: a constant-curvature arc of ``angle_deg`` (signed, positive = left) and ``radius``,
  with optional clothoid ``transition`` (m) at entry and exit (curvature ramps linearly); the arc
  is shortened so that the total heading change is exactly ``angle_deg``;
* ``clothoid``: curvature ramps linearly from ``kappa_start`` to ``kappa_end``;
* ``lane_change``: ``kappa(s) = (2 pi offset / L^2) sin(2 pi s / L)``, which moves the vehicle
  sideways by ~``offset`` metres (positive = left) with zero net heading change;
* ``s_curve``: ``kappa(s) = max_curvature sin(2 pi s / L)``, a left-then-right S;
* ``stop``: zero length; the vehicle brakes to a standstill at this point (constant deceleration
  ``stop_deceleration``, speed ``sqrt(2 a d)`` at distance ``d`` from the stop, never below
  ``CREEP_SPEED`` so the stop is reached), stands still for ``duration`` seconds, then accelerates
  the same way (the standstill itself is timed by ``kinematics.simulate_kinematics``).

Speed changes between segments ramp linearly over ``speed_ramp_m`` metres after the boundary.
With ``acceleration`` set (realistic driving, issue 13) the speed is instead limited by constant
acceleration and braking as trucks drive (a loaded truck accelerates at ~0.5-1 m/s^2 and brakes at
up to 3-4 m/s^2): ``v(s) = min_j env_j(s)`` over the segments ``j`` with ``env_j = v_j`` on the
segment, ``sqrt(v_j^2 + 2 b (start_j - s))`` before it and ``sqrt(v_j^2 + 2 a (s - end_j))``
after it (the closed form of the forward-backward pass of a velocity planner; stops are segments
of speed 0), tabulated as ``v^2`` every 2 cm (linear in ``s`` at constant acceleration).

Any segment may carry ``reverse: true``: it is driven backwards (negative axle speed). Its
curvature is then the curvature commanded for the **trailer** axle (``kinematics`` steers the
tractor with a stabilising controller so that the trailer follows it, as a driver reversing to a
dock does); a stop of ``direction_change_pause_s`` is inserted between segments of opposite
direction unless one is there.
Route segments are built from YAML (see ``sim_config``); errors name the file and the field.
"""
from __future__ import annotations

import bisect
import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ampc_vo.errors import ConfigError

SEGMENT_KINDS = ("straight", "turn", "clothoid", "lane_change", "s_curve", "stop")
CREEP_SPEED = 0.05  # m/s: lowest speed of the braking envelope, so that a stop is reached in finite time


@dataclass(frozen=True)
class Segment:
    """One piece of a route. ``kind`` selects the curvature profile (module docstring)."""

    kind: str
    length: float
    speed: float
    radius: float = 0.0
    angle: float = 0.0          # turn: signed heading change (radians)
    transition: float = 0.0     # turn: clothoid length at entry and exit (m)
    kappa_start: float = 0.0    # clothoid
    kappa_end: float = 0.0      # clothoid
    offset: float = 0.0         # lane_change: lateral offset (m)
    max_curvature: float = 0.0  # s_curve
    duration: float = 0.0       # stop: standstill time (s)
    reverse: bool = False       # driven backwards; the curvature is the trailer's (module docstring)

    def curvature(self, s: float) -> float:
        """Curvature (1/m) at local arc length ``s`` in [0, length]."""
        if self.kind in ("straight", "stop"):
            return 0.0
        if self.kind == "turn":
            kappa = math.copysign(1.0 / self.radius, self.angle)
            if self.transition > 0.0:
                if s < self.transition:
                    return kappa * s / self.transition
                if s > self.length - self.transition:
                    return kappa * max(self.length - s, 0.0) / self.transition
            return kappa
        if self.kind == "clothoid":
            fraction = min(max(s / self.length, 0.0), 1.0)
            return self.kappa_start + (self.kappa_end - self.kappa_start) * fraction
        if self.kind == "lane_change":
            return 2.0 * math.pi * self.offset / self.length**2 * math.sin(2.0 * math.pi * s / self.length)
        if self.kind == "s_curve":
            return self.max_curvature * math.sin(2.0 * math.pi * s / self.length)
        raise ValueError(f"unknown segment kind {self.kind!r}")


@dataclass(frozen=True)
class Route:
    """Segments driven in order; ``curvature(s)`` and ``speed(s)`` over the route's arc length.

    Beyond the end the route continues straight at the last speed (so a fixed duration longer
    than the route is still well defined).
    """

    segments: tuple[Segment, ...]
    speed_ramp_m: float = 10.0
    stop_deceleration: float = 1.0
    acceleration: float | None = None   # m/s^2: acceleration-limited profile (module docstring); None: legacy ramps
    deceleration: float = 2.5           # m/s^2: braking of the acceleration-limited profile

    def __post_init__(self) -> None:
        starts, total, stops = [], 0.0, []
        for segment in self.segments:
            starts.append(total)
            if segment.kind == "stop":
                stops.append((total, segment.duration))
            total += segment.length
        object.__setattr__(self, "_starts", starts)
        object.__setattr__(self, "_length", total)
        object.__setattr__(self, "_stops", tuple(stops))
        object.__setattr__(self, "_any_reverse", any(segment.reverse for segment in self.segments))
        object.__setattr__(self, "_table", self._speed_table() if self.acceleration is not None else None)

    _TABLE_STEP_M = 0.02

    def _speed_table(self) -> np.ndarray:
        """Squared acceleration-limited speed every 2 cm over the route (module docstring)."""
        s = np.arange(0.0, self.length + 2.0 * self._TABLE_STEP_M, self._TABLE_STEP_M)
        speed = np.full(s.shape, np.inf)
        acceleration, braking = float(self.acceleration), self.deceleration
        for start, segment in zip(self._starts, self.segments):  # type: ignore[attr-defined]
            end = start + segment.length
            target = 0.0 if segment.kind == "stop" else segment.speed
            envelope = np.where(s < start, np.sqrt(target**2 + 2.0 * braking * np.maximum(start - s, 0.0)),
                                np.where(s > end, np.sqrt(target**2 + 2.0 * acceleration * np.maximum(s - end, 0.0)), target))
            speed = np.minimum(speed, envelope)
        return np.maximum(speed, CREEP_SPEED) ** 2  # v^2: linear in s at constant acceleration, so interpolation is exact

    def is_reverse(self, s: float) -> bool:
        """True where the route is driven backwards (beyond the end: like the last segment)."""
        if not self._any_reverse:  # type: ignore[attr-defined]
            return False
        return self.segments[self._locate(min(s, self.length))].reverse

    @property
    def stops(self) -> tuple[tuple[float, float], ...]:
        """``(arc length, standstill duration)`` of every ``stop`` segment, in order."""
        return self._stops  # type: ignore[attr-defined]

    @property
    def length(self) -> float:
        return self._length  # type: ignore[attr-defined]

    def _locate(self, s: float) -> int:
        return max(bisect.bisect_right(self._starts, s) - 1, 0)  # type: ignore[attr-defined]

    def curvature(self, s: float) -> float:
        """Curvature (1/m) at route arc length ``s``; 0 beyond the end."""
        if s >= self.length or not self.segments:
            return 0.0
        index = self._locate(s)
        return self.segments[index].curvature(s - self._starts[index])  # type: ignore[attr-defined]

    def profile(self, s: float) -> tuple[float, float]:
        """``(speed(s), curvature(s))`` with one segment lookup (the integrator's hot path)."""
        index = self._locate(s)
        start = self._starts[index]  # type: ignore[attr-defined]
        segment = self.segments[index]
        curvature = segment.curvature(s - start) if s < self.length else 0.0
        if self._table is not None:  # type: ignore[attr-defined]
            return self._tabulated(s), curvature
        if not self._stops and (index == 0 or self.speed_ramp_m <= 0.0 or s - start >= min(self.speed_ramp_m, segment.length)):  # type: ignore[attr-defined]
            return segment.speed, curvature
        return self.speed(s), curvature

    def speed(self, s: float) -> float:
        """Speed (m/s) at arc length ``s``: each segment's speed, ramped linearly over
        ``speed_ramp_m`` after a boundary where it changes, and limited by the braking and
        acceleration envelope ``max(sqrt(2 a |s - s_stop|), CREEP_SPEED)`` around stops; with
        ``acceleration`` set, the acceleration-limited profile of the module docstring."""
        if self._table is not None:  # type: ignore[attr-defined]
            return self._tabulated(s)
        index = self._locate(min(s, self.length))
        target = self.segments[index].speed
        if index > 0 and self.speed_ramp_m > 0.0:
            previous = self.segments[index - 1].speed
            into = s - self._starts[index]  # type: ignore[attr-defined]
            ramp = min(self.speed_ramp_m, self.segments[index].length)
            if into < ramp:
                target = previous + (target - previous) * into / ramp
        for position, _ in self._stops:  # type: ignore[attr-defined]
            envelope = max(math.sqrt(2.0 * self.stop_deceleration * abs(s - position)), CREEP_SPEED)
            target = min(target, envelope)
        return target


    def design_curvature(self, s: float) -> float:
        """Curvature of the road's design line at arc length ``s``: the route's, with lane changes flat."""
        if not 0.0 <= s < self.length or self.segments[self._locate(s)].kind == "lane_change":
            return 0.0
        return self.curvature(s)

    def lane_change_offset(self, s: float) -> float:
        """Left offset (m) of the driven path from the design line at arc length ``s``: the lane
        changes so far, ``offset (u - sin(2 pi u) / (2 pi))`` at fraction ``u`` of each (the double
        integral of its curvature, small angles)."""
        total = 0.0
        for start, segment in zip(self._starts, self.segments):  # type: ignore[attr-defined]
            if segment.kind == "lane_change" and s > start:
                fraction = min((s - start) / segment.length, 1.0)
                total += segment.offset * (fraction - math.sin(2.0 * math.pi * fraction) / (2.0 * math.pi))
        return total

    def design_path(self, start_xy: tuple[float, float], extension_m: float, step_m: float = 0.25) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The road's design line: the rear-axle path of the route's curvature with every
        ``lane_change`` flattened to a straight (a lane change moves the vehicle, not the road),
        starting at ``start_xy`` heading +x and extended straight ``extension_m`` before and after.
        Returns points (N, 2), station (N,: route arc length, negative before the start) and
        curvature (N,). Heading and position are integrated with the trapezoidal rule."""
        station = np.arange(-extension_m, self.length + extension_m + 1e-9, step_m)
        curvature = np.array([self.design_curvature(s) for s in station])
        heading = np.concatenate([[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1]) * step_m)])
        heading -= np.interp(0.0, station, heading)
        direction = np.column_stack([np.cos(heading), np.sin(heading)])
        points = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (direction[1:] + direction[:-1]) * step_m, axis=0)])
        points += np.asarray(start_xy) - np.array([np.interp(0.0, station, points[:, axis]) for axis in range(2)])
        return points, station, curvature

    def _tabulated(self, s: float) -> float:
        table = self._table  # type: ignore[attr-defined]
        position = min(max(s, 0.0), self.length + self._TABLE_STEP_M) / self._TABLE_STEP_M
        index = min(int(position), len(table) - 2)
        fraction = position - index
        return math.sqrt(table[index] + (table[index + 1] - table[index]) * fraction)


# ---------------------------------------------------------------------- parsing
def _number(spec: dict, key: str, where: str, source: str, default: float | None = None, positive: bool = False) -> float:
    if key not in spec or spec[key] is None:
        if default is None:
            raise ConfigError(f"{source}: {where}.{key}: missing")
        return default
    try:
        value = float(spec[key])
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: {where}.{key}: expected a number, got {spec[key]!r}") from None
    if not math.isfinite(value) or (positive and value <= 0.0):
        raise ConfigError(f"{source}: {where}.{key}: must be a {'positive ' if positive else ''}finite number, got {spec[key]!r}")
    return value


_ALLOWED_KEYS = {
    "straight": {"length"},
    "turn": {"angle_deg", "radius", "transition"},
    "clothoid": {"length", "curvature_start", "curvature_end"},
    "lane_change": {"length", "offset"},
    "s_curve": {"length", "max_curvature"},
    "stop": {"duration"},
}


def segment_from_dict(spec: Any, default_speed: float, where: str, source: str) -> Segment:
    """Parse one YAML segment mapping, e.g. ``{type: turn, angle_deg: 90, radius: 20}``."""
    if not isinstance(spec, dict):
        raise ConfigError(f"{source}: {where}: expected a mapping with a 'type' field, got {spec!r}")
    kind = spec.get("type")
    if kind not in SEGMENT_KINDS:
        raise ConfigError(f"{source}: {where}.type: unknown segment type {kind!r} (expected one of {SEGMENT_KINDS})")
    unknown = set(spec) - _ALLOWED_KEYS[kind] - {"type", "speed", "reverse"}
    if unknown:
        raise ConfigError(f"{source}: {where}: unknown field(s) {sorted(unknown)} for a {kind} segment")
    speed = _number(spec, "speed", where, source, default=default_speed, positive=True)
    reverse = spec.get("reverse", False)
    if not isinstance(reverse, bool):
        raise ConfigError(f"{source}: {where}.reverse: expected true or false, got {reverse!r}")
    if reverse:
        if kind == "stop":
            raise ConfigError(f"{source}: {where}.reverse: a stop has no direction")
        return dataclasses.replace(segment_from_dict({key: value for key, value in spec.items() if key != "reverse"}, default_speed, where, source), reverse=True)
    if kind == "stop":
        duration = _number(spec, "duration", where, source)
        if duration < 0.0:
            raise ConfigError(f"{source}: {where}.duration: must be >= 0, got {duration}")
        return Segment("stop", 0.0, speed, duration=duration)
    if kind == "turn":
        angle = math.radians(_number(spec, "angle_deg", where, source))
        radius = _number(spec, "radius", where, source, positive=True)
        transition = _number(spec, "transition", where, source, default=0.0)
        if angle == 0.0:
            raise ConfigError(f"{source}: {where}.angle_deg: a turn needs a non-zero angle")
        if transition < 0.0:
            raise ConfigError(f"{source}: {where}.transition: must be >= 0")
        # Heading change = kappa * (arc + transition): each clothoid contributes kappa * T / 2.
        length = abs(angle) * radius + transition
        if abs(angle) * radius < transition:
            raise ConfigError(f"{source}: {where}.transition: {transition} m is longer than the turn allows ({abs(angle) * radius:.1f} m)")
        return Segment("turn", length, speed, radius=radius, angle=angle, transition=transition)
    length = _number(spec, "length", where, source, positive=True)
    if kind == "straight":
        return Segment("straight", length, speed)
    if kind == "clothoid":
        return Segment("clothoid", length, speed,
                       kappa_start=_number(spec, "curvature_start", where, source),
                       kappa_end=_number(spec, "curvature_end", where, source))
    if kind == "lane_change":
        return Segment("lane_change", length, speed, offset=_number(spec, "offset", where, source))
    return Segment("s_curve", length, speed, max_curvature=_number(spec, "max_curvature", where, source))


def route_from_list(raw: Any, default_speed: float, source: str, field_name: str = "segments", speed_ramp_m: float = 10.0,
                    acceleration: float | None = None, deceleration: float = 2.5, direction_change_pause_s: float = 1.0) -> Route:
    """Parse the YAML ``segments`` list into a :class:`Route` (a stop is inserted at every change of
    driving direction that has none, module docstring)."""
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{source}: {field_name}: expected a non-empty list of segments")
    parsed = [segment_from_dict(spec, default_speed, f"{field_name}[{index}]", source) for index, spec in enumerate(raw)]
    segments: list[Segment] = []
    for segment in parsed:
        moving = [previous for previous in segments if previous.kind != "stop"]
        if segment.kind != "stop" and moving and moving[-1].reverse != segment.reverse and segments[-1].kind != "stop":
            segments.append(Segment("stop", 0.0, segment.speed, duration=direction_change_pause_s))
        segments.append(segment)
    return Route(tuple(segments), speed_ramp_m=speed_ramp_m, acceleration=acceleration, deceleration=deceleration)
