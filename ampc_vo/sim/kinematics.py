"""Tractor-trailer kinematics: bicycle tractor + off-axle hitched trailer (DESIGN section 6).

State (planar): tractor rear-axle midpoint ``(x, y)``, tractor heading ``psi_A``, hitch angle
``theta`` (= psi_B - psi_A, DESIGN 1) and route arc length ``s``. With speed ``v(s)`` and
curvature ``kappa(s)`` of the tractor axle:

    x' = v cos psi_A,   y' = v sin psi_A,   psi_A' = v kappa,   s' = v
    psi_B' = (-v sin theta - psi_A' s_A cos theta) / s_B,        theta' = psi_B' - psi_A'

with ``s_A`` = tractor ``axle_x`` and ``s_B`` = -trailer ``axle_x`` (> 0). The hitch (origin of
both body frames) is ``axle - R(psi_A) (s_A, 0)``; the trailer pose is ``T_world_trailer`` with
the same origin and ``R_world_trailer = R_world_tractor Rz(theta)``. Integrated with classical RK4
at ~1 kHz and sampled at the camera rate.

**Steady-state hitch angle** (constant curvature ``kappa = 1/R``). Both axles move on circles about
the same instantaneous centre ``C``; in the tractor frame (origin at the hitch) the tractor axle is
``(s_A, 0)`` and ``C = (s_A, R)``. The trailer axle is ``b = -s_B u(theta)``; its velocity is
along the trailer heading ``u(theta)``, so the radius ``b - C`` is perpendicular to it:

    (b - C) . u(theta) = 0   <=>   -s_B - s_A cos theta - R sin theta = 0
    <=>   sin theta + kappa s_A cos theta = -kappa s_B.

Writing the left side as ``sqrt(1 + (kappa s_A)^2) sin(theta + atan(kappa s_A))``:

    theta_ss = -atan(kappa s_A) - asin(kappa s_B / sqrt(1 + (kappa s_A)^2)),

which exists when the hitch radius ``sqrt(R^2 + s_A^2) >= s_B``. The same equation follows from
``theta' = 0`` in the ODE above (``psi_B' = psi_A' = v kappa``), and for forward driving this
equilibrium is stable (the trailer "follows"), so a constant-curvature run converges to it.

**Tyre slip** (optional, ``slip`` in rad per m/s^2; 0 = the ideal kinematics above). In a turn
the tyres of a rigid axle generate their lateral force at a slip angle: the axle's velocity points
outward of its heading by ``beta = slip * a_lat`` (a linear tyre model; ``a_lat`` is the axle's
signed lateral acceleration). This is what breaks the non-holonomic constraint (NH) of DESIGN 2 on
real vehicles (DESIGN: up to ~1.5 deg in hard cornering). The route then describes the *path* of the
tractor axle (its velocity direction ``phi``, ``phi' = v kappa``); the heading is
``psi_A = phi + slip v^2 kappa`` and

    psi_A' = v kappa + slip v d(v^2 kappa)/ds
    psi_B' = v_hitch . n(psi_B + beta_B) / (s_B cos beta_B),   beta_B = -slip |v_B| psi_B'

(the trailer axle's velocity is along ``psi_B + beta_B``; solved by fixed-point iteration), with
``v_hitch = v u(phi) - s_A psi_A' n(psi_A)``. With ``slip = 0`` both reduce to the ODE above.
On a cross-slope rising ``dh/dn`` to the left the tyres also carry gravity's lateral component, so
``a_lat`` becomes ``a_lat + g dh/dn`` at each axle: the vehicle crabs and drifts downhill.

**Trailer axle groups** (:class:`AxleGroup`): a tandem or tridem steers about an effective axle
``L_eq`` behind the king-pin that moves with the turn radius; ``s_B`` above becomes ``L_eq``
(the rig's ``axle_x`` stays the group centre: a model error for the estimator, as on real trailers).

**Reversing.** On ``reverse`` segments ``v < 0`` and the ODE above is open-loop unstable
(``theta`` grows with rate ``|v| / s_B``), so a driver model steers: the segment's curvature is the
one commanded to the *trailer*, and the tractor's curvature is chosen by feedback linearisation so
that the hitch angle converges to the steady-state angle of that trailer curvature
(:func:`_derivative_reverse`, :func:`hitch_angle_for_trailer_curvature`). Reverse segments use
ideal rolling (no slip).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ampc_vo.errors import ConfigError
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.sim.routes import Route

LOGGER = logging.getLogger(__name__)
INTEGRATION_RATE_HZ = 1000.0


def steady_state_hitch_angle(curvature: float, tractor_axle_x: float, trailer_axle_x: float) -> float:
    """Analytic steady-state hitch angle (radians) for constant tractor-axle curvature (module docstring).

    ``theta_ss = -atan(kappa s_A) - asin(kappa s_B / sqrt(1 + (kappa s_A)^2))`` with
    ``s_A = tractor_axle_x``, ``s_B = -trailer_axle_x``. Raises ``ValueError`` when the turn is too
    tight for a steady state (hitch radius below ``s_B``).
    """
    s_a, s_b = tractor_axle_x, -trailer_axle_x
    ratio = curvature * s_b / math.sqrt(1.0 + (curvature * s_a) ** 2)
    if abs(ratio) > 1.0:
        raise ValueError(f"no steady state: turn radius {1.0 / abs(curvature):.2f} m too tight for s_B = {s_b} m")
    return -math.atan(curvature * s_a) - math.asin(ratio)


def _derivative(state: tuple[float, ...], route: Route, s_a: float, s_b: float) -> tuple[float, ...]:
    """Time derivative of the state (x, y, psi_A, theta, s); DESIGN 6."""
    _, _, psi_a, theta, s = state
    v, curvature = route.profile(s)
    yaw_rate_a = v * curvature
    yaw_rate_b = (-v * math.sin(theta) - yaw_rate_a * s_a * math.cos(theta)) / s_b
    return (v * math.cos(psi_a), v * math.sin(psi_a), yaw_rate_a, yaw_rate_b - yaw_rate_a, v)


_SLIP_DIFFERENCE_M = 0.05  # arc-length step of the central difference d(v^2 kappa)/ds
_SLIP_ITERATIONS = 4       # fixed-point iterations of the trailer's slip angle (|beta_B| << 1: converges fast)
GRAVITY = 9.81
TRACTOR_MAX_CURVATURE = 1.0 / 5.5   # 1/m at the tractor's rear axle: full steering lock of a 6x4 tractor
REVERSE_GAIN = 5.0                  # closed-loop hitch convergence rate, in units of |v| / s_B (settles within ~s_B / 2)


LateralSlope = Callable[[float, float], float]  # (station m, heading rad) -> rise per metre to the left


@dataclass(frozen=True)
class AxleGroup:
    """A trailer's axle group (1 = single, 2 = tandem, 3 = tridem) and where it steers from.

    In a steady turn the group rotates about a point ``L_eq`` behind the king-pin at which the
    tyres' lateral forces balance about the king-pin: ``sum_i F(alpha_i) (L + x_i) = 0`` with the
    axles at ``x_i`` about the group centre ``L``, slip angles ``alpha_i = (L_eq - L - x_i) kappa``
    and ``F(alpha) = tanh(alpha / alpha_sat)`` (equal axles). For linear tyres this is Winkler's
    equivalent wheelbase ``L_eq = L + sum x_i^2 / (n L)`` (C. B. Winkler, "Simplified analysis of
    the steady-state turning of complex vehicles", Vehicle System Dynamics 29(3), 1998); the
    saturating tyres make it move with the turn radius (tight yard turns scrub the tyres).
    """

    axles: int = 1
    spread_m: float = 1.31            # m between neighbouring axles
    saturation_rad: float = 0.08      # slip angle scale of the tanh tyre

    def positions(self) -> np.ndarray:
        return (np.arange(self.axles) - 0.5 * (self.axles - 1)) * self.spread_m

    def effective_distance(self, group_distance: float, curvature: float | np.ndarray) -> np.ndarray:
        """``L_eq`` (m behind the king-pin) for the group centre at ``group_distance``."""
        curvature = np.abs(np.atleast_1d(np.asarray(curvature, dtype=float)))
        x = self.positions()
        if self.axles == 1:
            return np.full(curvature.shape, group_distance)
        linear = group_distance + float(np.sum(x * x)) / (self.axles * group_distance)
        low = np.full(curvature.shape, x[0] - 1e-9)
        high = np.full(curvature.shape, x[-1] + 1e-9)
        scale = np.maximum(curvature, 1e-9)[:, None] / self.saturation_rad
        for _ in range(50):  # bisection on the moment balance (monotonic in L_eq)
            middle = 0.5 * (low + high)
            moment = np.sum(np.tanh((middle[:, None] - x[None, :]) * scale) * (group_distance + x[None, :]), axis=1)
            low = np.where(moment < 0.0, middle, low)
            high = np.where(moment < 0.0, high, middle)
        result = group_distance + 0.5 * (low + high)
        return np.where(curvature < 1e-6, linear, result)


class _EffectiveAxle:
    """Tabulated :meth:`AxleGroup.effective_distance` over |curvature| (the integrator's hot path)."""

    STEP = 0.001  # 1/m

    def __init__(self, group: AxleGroup | None, s_b: float) -> None:
        self.s_b = s_b
        self.table = None if group is None or group.axles == 1 else group.effective_distance(s_b, np.arange(0.0, 0.3 + self.STEP, self.STEP)).tolist()

    def __call__(self, curvature: float) -> float:
        if self.table is None:
            return self.s_b
        position = min(abs(curvature) / self.STEP, len(self.table) - 1.001)
        index = int(position)
        return self.table[index] + (self.table[index + 1] - self.table[index]) * (position - index)


def hitch_angle_for_trailer_curvature(trailer_curvature: float, tractor_axle_x: float, trailer_axle_x: float) -> float:
    """Steady-state hitch angle at which the trailer axle drives a circle of curvature
    ``trailer_curvature``: trailer radius ``R_B``, hitch radius ``sqrt(R_B^2 + s_B^2)``, tractor
    axle radius ``R_A = sqrt(R_B^2 + s_B^2 - s_A^2)`` (all about the same centre), then
    :func:`steady_state_hitch_angle` of ``1 / R_A``."""
    if abs(trailer_curvature) < 1e-9:
        return 0.0
    s_a, s_b = tractor_axle_x, -trailer_axle_x
    radius_b = 1.0 / abs(trailer_curvature)
    radius_a = math.sqrt(max(radius_b**2 + s_b**2 - s_a**2, 1e-9))
    return steady_state_hitch_angle(math.copysign(1.0 / radius_a, trailer_curvature), s_a, -s_b)


def _derivative_reverse(state: tuple[float, ...], route: Route, s_a: float, s_b: float) -> tuple[float, ...]:
    """Reversing (module docstring): the route's curvature is the trailer's; the tractor's
    curvature feedback-linearises ``theta' = v (A + B kappa_A)`` (``A = -sin theta / s_B``,
    ``B = -(1 + s_A cos theta / s_B)``, from the ODE) onto
    ``theta' = -REVERSE_GAIN |v| (theta - theta_ref) / s_B`` with ``theta_ref`` the steady-state
    hitch angle of the commanded trailer curvature; clipped at the tractor's steering lock."""
    _, _, psi_a, theta, s = state
    speed, trailer_curvature = route.profile(s)
    v = -speed
    reference = hitch_angle_for_trailer_curvature(trailer_curvature, s_a, -s_b)
    a_term = -math.sin(theta) / s_b
    b_term = -(1.0 + s_a * math.cos(theta) / s_b)
    wanted = -REVERSE_GAIN * speed * (theta - reference) / s_b
    curvature = min(max((wanted / v - a_term) / b_term, -TRACTOR_MAX_CURVATURE), TRACTOR_MAX_CURVATURE)
    yaw_rate_a = v * curvature
    yaw_rate_b = (-v * math.sin(theta) - yaw_rate_a * s_a * math.cos(theta)) / s_b
    return (v * math.cos(psi_a), v * math.sin(psi_a), yaw_rate_a, yaw_rate_b - yaw_rate_a, speed)


def _lateral_acceleration(route: Route, s: float, slope: LateralSlope | None = None, heading: float = 0.0) -> float:
    """Lateral force per mass the tractor axle's tyres supply at arc length ``s`` (m/s^2, signed:
    + to the left): ``v^2 kappa`` plus ``g dh/dn`` on a cross-slope rising ``dh/dn`` to the left."""
    v, curvature = route.profile(max(s, 0.0))
    return v * v * curvature + (GRAVITY * slope(s, heading) if slope is not None else 0.0)


def _derivative_with_slip(state: tuple[float, ...], route: Route, s_a: float, s_b: float, slip: float,
                          effective: _EffectiveAxle | None = None, slope: LateralSlope | None = None) -> tuple[float, ...]:
    """Time derivative of the state (x, y, phi, theta, s) with tyre slip (module docstring); ``phi``
    is the direction of the tractor axle's velocity, not its heading. ``effective`` gives the
    trailer's effective axle distance (multi-axle groups), ``slope`` the road's cross-slope."""
    _, _, phi, theta, s = state
    v, curvature = route.profile(s)
    step = _SLIP_DIFFERENCE_M
    lateral_rate = (_lateral_acceleration(route, s + step, slope, phi) - _lateral_acceleration(route, s - step, slope, phi)) / (2.0 * step)
    yaw_rate_a = v * curvature + slip * v * lateral_rate
    psi_a = phi + slip * _lateral_acceleration(route, s, slope, phi)
    psi_b = psi_a + theta
    hitch_vx = v * math.cos(phi) + s_a * yaw_rate_a * math.sin(psi_a)
    hitch_vy = v * math.sin(phi) - s_a * yaw_rate_a * math.cos(psi_a)
    trailer_gravity = GRAVITY * slope(s - s_b, psi_b) if slope is not None else 0.0
    beta_b = 0.0
    distance = s_b
    for _ in range(_SLIP_ITERATIONS):
        direction = psi_b + beta_b
        yaw_rate_b = (-hitch_vx * math.sin(direction) + hitch_vy * math.cos(direction)) / (distance * math.cos(beta_b))
        # trailer axle velocity v_hitch - s_B psi_B' n(psi_B)
        axle_speed = math.hypot(hitch_vx + distance * yaw_rate_b * math.sin(psi_b), hitch_vy - distance * yaw_rate_b * math.cos(psi_b))
        if effective is not None:
            distance = effective(yaw_rate_b / max(axle_speed, 1e-6))
        beta_b = -slip * (axle_speed * yaw_rate_b + trailer_gravity)
    return (v * math.cos(phi), v * math.sin(phi), v * curvature, yaw_rate_b - yaw_rate_a, v)


def _rk4_step(state: tuple[float, ...], dt: float, route: Route, s_a: float, s_b: float, slip: float = 0.0,
              effective: _EffectiveAxle | None = None, slope: LateralSlope | None = None) -> tuple[float, ...]:
    """One classical Runge-Kutta step of :func:`_derivative` (unrolled: this is the hot loop), of
    :func:`_derivative_with_slip` when ``slip`` > 0 or a multi-axle group is given, or of
    :func:`_derivative_reverse` on a reverse segment."""
    x, y, psi, theta, s = state
    half = 0.5 * dt
    if route.is_reverse(s):
        derivative, extra = _derivative_reverse, (route, s_a, s_b)
    elif slip > 0.0 or effective is not None:
        derivative, extra = _derivative_with_slip, (route, s_a, s_b, slip, effective, slope)
    else:
        derivative, extra = _derivative, (route, s_a, s_b)
    a1, b1, c1, d1, e1 = derivative(state, *extra)
    a2, b2, c2, d2, e2 = derivative((x + half * a1, y + half * b1, psi + half * c1, theta + half * d1, s + half * e1), *extra)
    a3, b3, c3, d3, e3 = derivative((x + half * a2, y + half * b2, psi + half * c2, theta + half * d2, s + half * e2), *extra)
    a4, b4, c4, d4, e4 = derivative((x + dt * a3, y + dt * b3, psi + dt * c3, theta + dt * d3, s + dt * e3), *extra)
    sixth = dt / 6.0
    return (
        x + sixth * (a1 + 2.0 * a2 + 2.0 * a3 + a4),
        y + sixth * (b1 + 2.0 * b2 + 2.0 * b3 + b4),
        psi + sixth * (c1 + 2.0 * c2 + 2.0 * c3 + c4),
        theta + sixth * (d1 + 2.0 * d2 + 2.0 * d3 + d4),
        s + sixth * (e1 + 2.0 * e2 + 2.0 * e3 + e4),
    )


def _planar_poses(position: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(F, 4, 4) poses from positions (F, 3) and yaw (F,) (vectorised ``planar_pose``)."""
    poses = np.zeros((len(yaw), 4, 4))
    cosine, sine = np.cos(yaw), np.sin(yaw)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = cosine, -sine, sine, cosine
    poses[:, 2, 2] = poses[:, 3, 3] = 1.0
    poses[:, :3, 3] = position
    return poses


def poses_from_states(
    axle_xy: np.ndarray, tractor_yaw: np.ndarray, hitch_angle: np.ndarray, tractor_axle_x: float, z: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """(F, 4, 4) ``T_world_tractor`` and ``T_world_trailer`` from axle positions (F, 2), tractor
    yaw (F,) and hitch angle (F,). The hitch is ``axle - R(psi_A) (axle_x, 0)`` (DESIGN 6)."""
    count = len(tractor_yaw)
    hitch = np.column_stack([
        axle_xy[:, 0] - tractor_axle_x * np.cos(tractor_yaw),
        axle_xy[:, 1] - tractor_axle_x * np.sin(tractor_yaw),
        np.full(count, z),
    ])
    return _planar_poses(hitch, tractor_yaw), _planar_poses(hitch, tractor_yaw + hitch_angle)


def simulate_kinematics(
    route: Route,
    rate_hz: float,
    tractor_axle_x: float,
    trailer_axle_x: float,
    initial_hitch_angle: float = 0.0,
    duration: float | None = None,
    start_time: float = 0.0,
    integration_rate_hz: float = INTEGRATION_RATE_HZ,
    slip: float = 0.0,
    samples_per_frame: int = 1,
    axle_group: AxleGroup | None = None,
    lateral_slope: LateralSlope | None = None,
) -> Trajectory:
    """Integrate the tractor-trailer ODE (module docstring) with RK4 and sample at ``rate_hz``.
    ``slip``: tyre slip angle per lateral acceleration (rad per m/s^2; 0: ideal rolling, NH exact).

    The tractor starts with its hitch at the world origin heading along +x. Without ``duration``
    the run ends at the first frame at or past the route's end. At a ``stop`` segment the state is
    held for the stop's duration (the speed profile brakes to ``CREEP_SPEED`` before it). The integration step is the frame
    period divided into ``ceil(integration_rate_hz / rate_hz)`` equal steps (~1 ms).

    ``samples_per_frame`` > 1 returns the dense motion, ``samples_per_frame`` samples per frame
    period (every ``samples_per_frame``-th sample is a frame; the frames are the same as with 1).
    Reverse segments are steered by :func:`_derivative_reverse` (ideal rolling); ``axle_group``
    moves the trailer's effective axle (:class:`AxleGroup`); ``lateral_slope(station, heading)``
    adds the cross-slope's gravity to the tyres' lateral force (drift downhill, with ``slip``).
    The returned ``speed`` is signed (negative reversing) and ``curvature`` is the tractor axle's.
    """
    if rate_hz <= 0.0:
        raise ConfigError(f"rate_hz must be positive, got {rate_hz}")
    if trailer_axle_x >= 0.0:
        raise ConfigError(f"trailer axle_x must be negative (behind the hitch), got {trailer_axle_x}")
    if not route.segments:
        raise ConfigError("route has no segments")
    if not 0.0 <= slip < 0.1:
        raise ConfigError(f"tyre slip must be in [0, 0.1) rad per m/s^2, got {slip}")
    s_a, s_b = float(tractor_axle_x), -float(trailer_axle_x)
    effective = _EffectiveAxle(axle_group, s_b) if axle_group is not None and axle_group.axles > 1 else None
    samples_per_frame = max(int(samples_per_frame), 1)
    sample_rate = rate_hz * samples_per_frame
    frame_period = 1.0 / sample_rate
    substeps = max(int(math.ceil(integration_rate_hz * frame_period - 1e-9)), 1)
    dt = frame_period / substeps
    if duration is not None:
        frame_count = (int(math.floor(duration * rate_hz + 1e-9))) * samples_per_frame + 1
    else:
        frame_count = None

    state: tuple[float, ...] = (tractor_axle_x, 0.0, 0.0, float(initial_hitch_angle), 0.0)
    states = [state]
    pending_stops = list(route.stops)
    standing = [bool(pending_stops) and pending_stops[0][0] <= 0.0]
    ends_at_rest = route.segments[-1].kind == "stop"  # then the vehicle stays where it stopped
    hold_steps = 0  # integration steps left standing still at a stop
    if standing[0]:  # a standing start: hold before the first step
        hold_steps = int(round(pending_stops.pop(0)[1] / dt))
    while True:
        if frame_count is not None and len(states) >= frame_count:
            break
        if (frame_count is None and state[4] >= route.length and not pending_stops and hold_steps == 0
                and (len(states) - 1) % samples_per_frame == 0):
            break
        for _ in range(substeps):
            if hold_steps > 0:
                hold_steps -= 1
                continue
            if ends_at_rest and not pending_stops and state[4] >= route.length:
                break
            state = _rk4_step(state, dt, route, s_a, s_b, slip, effective, lateral_slope)
            if pending_stops and state[4] >= pending_stops[0][0]:
                hold_steps = int(round(pending_stops.pop(0)[1] / dt))
        states.append(state)
        standing.append(hold_steps > 0 or (ends_at_rest and not pending_stops and state[4] >= route.length))
        if len(states) > 10_000_000:
            raise ConfigError("trajectory longer than 10 million frames: check speed and duration")
        if abs(state[3]) > math.radians(89.0):
            raise ConfigError(
                f"hitch angle reached {math.degrees(state[3]):.1f} deg (jack-knife) at t={len(states) * frame_period:.2f} s: "
                "the route is too tight for this trailer"
            )
    array = np.asarray(states)
    reverse = np.array([route.is_reverse(s) for s in array[:, 4]])
    speed = np.where(standing, 0.0, [route.speed(s) for s in array[:, 4]]) * np.where(reverse, -1.0, 1.0)
    curvature = np.array([route.curvature(s) for s in array[:, 4]])
    heading = array[:, 2].copy()
    forward = ~reverse
    if slip > 0.0:  # with slip the state holds the path direction
        heading[forward] += slip * np.array([_lateral_acceleration(route, s, lateral_slope, phi) for s, phi in array[forward][:, [4, 2]]])
    if reverse.any():  # the tractor's curvature is the controller's, not the route's (the trailer's)
        for index in np.flatnonzero(reverse):
            derivative = _derivative_reverse(tuple(array[index]), route, s_a, s_b)
            curvature[index] = derivative[2] / -derivative[4] if derivative[4] > 0.0 else 0.0
    T_world_tractor, T_world_trailer = poses_from_states(array[:, :2], heading, array[:, 3], tractor_axle_x)
    timestamps = start_time + np.arange(len(states)) * frame_period
    LOGGER.info("simulated %d samples (%.1f s, %.1f m)", len(states), timestamps[-1] - timestamps[0], array[-1, 4])
    return Trajectory(timestamps, T_world_tractor, T_world_trailer, array[:, 3].copy(), speed, curvature, array[:, 4].copy())


def axle_positions(trajectory: Trajectory, tractor_axle_x: float, trailer_axle_x: float) -> tuple[np.ndarray, np.ndarray]:
    """World positions (F, 3) of the tractor and trailer axle midpoints."""
    tractor = trajectory.T_world_tractor[:, :3, 3] + tractor_axle_x * trajectory.T_world_tractor[:, :3, 0]
    trailer = trajectory.T_world_trailer[:, :3, 3] + trailer_axle_x * trajectory.T_world_trailer[:, :3, 0]
    return tractor, trailer
