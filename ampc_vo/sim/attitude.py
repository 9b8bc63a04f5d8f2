"""Full 6-DoF body poses on a 3D road: attitude from the road under the wheels, suspension and
vibration (issue 13; DESIGN 1: both body origins at the king-pin).

Input: the planar motion of ``kinematics.simulate_kinematics`` (hitch position, heading ``psi``,
hitch angle ``theta`` of both bodies in the horizontal plane, sampled densely). Each body's
rotation is ``R = Rz(psi) Ry(beta) Rx(phi)`` (yaw of the horizontal heading, then pitch ``beta``,
positive nose down, then roll ``phi``, positive right side down), so the body x axis projects onto
the planar heading and the planar kinematics keep holding for the horizontal motion.

**Road under the wheels** (geometric attitude; contact points at ``z = -hitch_height`` in the body
frame, DESIGN 5). With ``c_z(c) = -sin(beta) c_x + cos(beta) sin(phi) c_y + cos(beta) cos(phi) c_z``
the height of body point ``c`` above the origin:

* tractor: rear axle contacts ``(a_A, +-w, -H)`` and the front axle's middle ``(a_A + L_wb, 0, -H)``
  on the surface ``h``: ``sin(phi) = (h_L - h_R) / (2 w cos(beta))``,
  ``sin(beta) = -(h_F - h_rear) / L_wb``, king-pin height ``z_K = h_rear + a_A sin(beta) + H cos(beta) cos(phi)``;
* trailer: hangs at the tractor's king-pin (shared exactly) and stands on its axle group's contacts
  ``(a_B, +-w, -H)``: ``sin(phi)`` as above and ``-a_B sin(beta) - H cos(beta) cos(phi) = h_mid - z_K``,

each solved by fixed-point iteration (the contacts' horizontal positions depend on the attitude
only through the small tilts, so five iterations converge to well below a millimetre). The trailer
therefore pitches and rolls relative to the tractor at the fifth wheel.

**Suspension** (sprung-body rotation about the king-pin, which keeps the hitch shared): second-order
spring-damper responses ``x'' + 2 zeta omega x' + omega^2 x = omega^2 G a`` of roll to the body's
lateral acceleration ``v psi'`` and of pitch to its longitudinal acceleration ``v'`` (braking
pitches the nose down). Gains ``G`` (deg per m/s^2), natural frequencies and damping are set per
load (:class:`SuspensionParameters`) within the ranges reported for heavy trucks: sprung-mass
natural frequencies of about 1-2 Hz and damping ratios 0.2-0.4 (T. D. Gillespie, *Fundamentals of
Vehicle Dynamics*, SAE 1992, ch. 5), roll gradients of loaded tractor-semitrailers of roughly
0.5-1 deg per m/s^2 (Gillespie ch. 9; C. B. Winkler, "Rollover of heavy commercial vehicles", UMTRI
Research Review 31(4), 2000: sprung-mass roll of 4-8 deg at rollover thresholds of 0.3-0.5 g),
lower for empty ones.

**Vibration**: engine shake (a sinusoid at ``engine_hz`` of ``engine_deg`` amplitude in roll and
pitch, random phase per body) and road-induced vibration (Gaussian noise through the same
second-order filter at ``road_hz``, RMS ``road_deg_per_mps`` times the speed), rotations about the
king-pin added on top of the suspension.

**Camera mounts** (:func:`mount_vibration`): each camera's bracket shakes on its own, a small
rotation ``R_mount`` about the camera's axes (``T_body_camera @ R_mount`` is the vibrating mount):
the engine sinusoid at half amplitude on tractor mounts, plus road noise through a bracket
resonance at ``mount_hz`` with RMS ``mount_deg_per_mps`` times the speed; independent per camera.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ampc_vo.geometry import yaws_of
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.sim.road import RoadSurface

_ITERATIONS = 5


@dataclass(frozen=True)
class SuspensionParameters:
    """Second-order attitude response of one body (module docstring); gains in deg per m/s^2."""

    roll_gain_deg: float
    pitch_gain_deg: float
    roll_hz: float
    pitch_hz: float
    damping: float = 0.3


# Loaded / empty tractor and trailer (module docstring for the ranges these sit in).
SUSPENSION = {
    "loaded": {"tractor": SuspensionParameters(0.6, 0.25, 1.0, 1.4), "trailer": SuspensionParameters(0.9, 0.10, 0.7, 1.2)},
    "empty": {"tractor": SuspensionParameters(0.45, 0.35, 1.3, 1.8), "trailer": SuspensionParameters(0.4, 0.05, 1.2, 2.0)},
}


@dataclass(frozen=True)
class VehicleConfig:
    """Wheel geometry, load and body motion switches of the simulated truck (``vehicle:`` section)."""

    tractor_wheelbase_m: float = 3.8     # front axle ahead of the tractor's rear axle
    half_track_m: float = 1.0            # lateral distance of the contact points from the axle middle
    trailer_axles: int = 1               # axle group: 1 single, 2 tandem, 3 tridem
    axle_spread_m: float = 1.31
    load: str = "loaded"                 # "loaded" or "empty" (SUSPENSION)
    suspension: bool = False
    engine_hz: float = 30.0
    engine_deg: float = 0.0
    road_hz: float = 8.0
    road_deg_per_mps: float = 0.0
    mount_hz: float = 20.0               # camera bracket resonance
    mount_deg_per_mps: float = 0.0       # RMS of the mount rotation per m/s of speed

    @property
    def moves_bodies(self) -> bool:
        return self.suspension or self.engine_deg > 0.0 or self.road_deg_per_mps > 0.0 or self.mount_deg_per_mps > 0.0


@dataclass(frozen=True)
class BodyAngles:
    """Per-sample roll and pitch (radians) of the two bodies, split by cause (for tests and plots)."""

    tractor_road: np.ndarray = field(repr=False)    # (N, 2) roll, pitch from the road
    trailer_road: np.ndarray = field(repr=False)
    tractor_body: np.ndarray = field(repr=False)    # (N, 2) suspension + vibration
    trailer_body: np.ndarray = field(repr=False)


def rotation_zyx(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    rotation = np.empty((len(yaw), 3, 3))
    rotation[:, 0, 0], rotation[:, 0, 1], rotation[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    rotation[:, 1, 0], rotation[:, 1, 1], rotation[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    rotation[:, 2, 0], rotation[:, 2, 1], rotation[:, 2, 2] = -sp, cp * sr, cp * cr
    return rotation


def _small_rotation(roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ``Ry(pitch) Rx(roll)`` about the body's own axes."""
    return rotation_zyx(np.zeros_like(roll), pitch, roll)


def _second_order(signal: np.ndarray, dt: float, frequency_hz: float, damping: float) -> np.ndarray:
    """Response of ``x'' + 2 zeta w x' + w^2 x = w^2 u`` (unit static gain) to samples ``u`` (N, ...),
    semi-implicit Euler at the sample rate (stable for ``w dt < 1``), starting at rest in equilibrium."""
    omega = 2.0 * np.pi * frequency_hz
    x = np.array(signal[0], dtype=float)
    rate = np.zeros_like(x)
    out = np.empty_like(signal, dtype=float)
    for index in range(len(signal)):
        rate = rate + dt * (omega * omega * (signal[index] - x) - 2.0 * damping * omega * rate)
        x = x + dt * rate
        out[index] = x
    return out


def _body_accelerations(times: np.ndarray, position: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Longitudinal ``v'`` and lateral ``v psi'`` accelerations (N,) of a body at its axle's
    horizontal positions (N, 2) with heading ``yaw``."""
    velocity = np.gradient(position, times, axis=0)
    heading = np.column_stack([np.cos(yaw), np.sin(yaw)])
    speed = np.einsum("ij,ij->i", velocity, heading)
    yaw_rate = np.gradient(np.unwrap(yaw), times)
    return np.gradient(speed, times), speed * yaw_rate


def _tractor_on_road(hitch_xy: np.ndarray, yaw: np.ndarray, road: RoadSurface, axle_x: float, wheelbase: float, half_track: float,
                     hitch_height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """King-pin height, pitch and roll (N,) that put the tractor's rear contacts and front axle on the road."""
    count = len(yaw)
    pitch = np.zeros(count)
    roll = np.zeros(count)
    body_points = np.array([[axle_x, half_track, -hitch_height], [axle_x, -half_track, -hitch_height], [axle_x + wheelbase, 0.0, -hitch_height]])
    for _ in range(_ITERATIONS):
        rotation = rotation_zyx(yaw, pitch, roll)
        contacts_xy = hitch_xy[:, None, :] + np.einsum("nij,kj->nki", rotation[:, :2, :], body_points)
        heights = road.height(contacts_xy)                    # (N, 3): left, right, front
        rear = 0.5 * (heights[:, 0] + heights[:, 1])
        pitch = np.arcsin(np.clip(-(heights[:, 2] - rear) / wheelbase, -1.0, 1.0))
        roll = np.arcsin(np.clip((heights[:, 0] - heights[:, 1]) / (2.0 * half_track * np.cos(pitch)), -1.0, 1.0))
    hitch_z = rear + axle_x * np.sin(pitch) + hitch_height * np.cos(pitch) * np.cos(roll)
    return hitch_z, pitch, roll


def _trailer_on_road(hitch: np.ndarray, yaw: np.ndarray, road: RoadSurface, axle_x: float, half_track: float,
                     hitch_height: float) -> tuple[np.ndarray, np.ndarray]:
    """Pitch and roll (N,) that put the trailer's axle-group contacts on the road, hanging at ``hitch`` (N, 3)."""
    count = len(yaw)
    pitch = np.zeros(count)
    roll = np.zeros(count)
    body_points = np.array([[axle_x, half_track, -hitch_height], [axle_x, -half_track, -hitch_height]])
    for _ in range(_ITERATIONS):
        rotation = rotation_zyx(yaw, pitch, roll)
        contacts_xy = hitch[:, None, :2] + np.einsum("nij,kj->nki", rotation[:, :2, :], body_points)
        heights = road.height(contacts_xy)
        middle = 0.5 * (heights[:, 0] + heights[:, 1])
        roll = np.arcsin(np.clip((heights[:, 0] - heights[:, 1]) / (2.0 * half_track * np.cos(pitch)), -1.0, 1.0))
        # -a sin(b) - H cos(b) cos(r) = middle - z_K, solved for b by fixed point (|H / a| << 1)
        pitch = np.arcsin(np.clip((middle - hitch[:, 2] + hitch_height * np.cos(pitch) * np.cos(roll)) / -axle_x, -1.0, 1.0))
    return pitch, roll


def _body_motion(accelerations: tuple[np.ndarray, np.ndarray], speed: np.ndarray, dt: float, parameters: SuspensionParameters,
                 vehicle: VehicleConfig, rng: np.random.Generator) -> np.ndarray:
    """(N, 2) roll, pitch of suspension and vibration (module docstring)."""
    longitudinal, lateral = accelerations
    count = len(speed)
    angles = np.zeros((count, 2))
    if vehicle.suspension:
        angles[:, 0] = _second_order(np.radians(parameters.roll_gain_deg) * lateral, dt, parameters.roll_hz, parameters.damping)
        angles[:, 1] = _second_order(-np.radians(parameters.pitch_gain_deg) * longitudinal, dt, parameters.pitch_hz, parameters.damping)
    times = np.arange(count) * dt
    if vehicle.engine_deg > 0.0:
        phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
        angles += np.radians(vehicle.engine_deg) * np.sin(2.0 * np.pi * vehicle.engine_hz * times[:, None] + phases[None, :])
    if vehicle.road_deg_per_mps > 0.0:
        noise = _second_order(rng.normal(0.0, 1.0, size=(count, 2)), dt, vehicle.road_hz, 0.3)
        noise /= max(float(np.std(noise)), 1e-12)
        angles += np.radians(vehicle.road_deg_per_mps) * np.abs(speed)[:, None] * noise
    return angles


def mount_vibration(rig, trajectory: Trajectory, vehicle: VehicleConfig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Per camera name, (N, 3, 3) rotations ``R_mount`` of its bracket over the (dense) trajectory's
    samples (module docstring); identities when the vehicle has no engine or mount vibration."""
    count = len(trajectory)
    dt = float(np.median(np.diff(trajectory.timestamps))) if count > 1 else 0.0
    speed = np.abs(trajectory.speed) if trajectory.speed is not None else np.zeros(count)
    times = trajectory.timestamps - trajectory.timestamps[0]
    result = {}
    for camera in rig.cameras:
        angles = np.zeros((count, 3))
        if vehicle.engine_deg > 0.0 and camera.body == "tractor":
            phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
            angles += 0.5 * np.radians(vehicle.engine_deg) * np.sin(2.0 * np.pi * vehicle.engine_hz * times[:, None] + phases[None, :])
        if vehicle.mount_deg_per_mps > 0.0 and count > 2:
            noise = _second_order(rng.normal(0.0, 1.0, size=(count, 3)), dt, vehicle.mount_hz, 0.2)
            noise /= max(float(np.std(noise)), 1e-12)
            angles += np.radians(vehicle.mount_deg_per_mps) * speed[:, None] * noise
        result[camera.name] = rotation_zyx(angles[:, 2], angles[:, 1], angles[:, 0])
    return result


def hitch_angle_of(T_world_tractor: np.ndarray, T_world_trailer: np.ndarray) -> np.ndarray:
    """Yaw of ``R_tractor_trailer`` (DESIGN 1): the trailer's heading in the tractor's xy plane."""
    relative = np.einsum("nji,njk->nik", T_world_tractor[:, :3, :3], T_world_trailer[:, :3, :3])
    return yaws_of(relative)


def poses_on_road(planar: Trajectory, road: RoadSurface, tractor_axle_x: float, trailer_axle_x: float, hitch_height: float,
                  vehicle: VehicleConfig, rng: np.random.Generator) -> tuple[Trajectory, BodyAngles]:
    """The planar motion lifted onto the road, with suspension and vibration (module docstring).
    Returns the 6-DoF trajectory (same timestamps, speed, curvature and arc length; hitch angle as
    the yaw of ``R_tractor_trailer``) and the body angles by cause."""
    count = len(planar)
    tractor_yaw = yaws_of(planar.T_world_tractor)
    trailer_yaw = yaws_of(planar.T_world_trailer)
    hitch_xy = planar.T_world_tractor[:, :2, 3]
    hitch_z, tractor_pitch, tractor_roll = _tractor_on_road(hitch_xy, tractor_yaw, road, tractor_axle_x, vehicle.tractor_wheelbase_m,
                                                            vehicle.half_track_m, hitch_height)
    hitch = np.column_stack([hitch_xy, hitch_z])
    trailer_pitch, trailer_roll = _trailer_on_road(hitch, trailer_yaw, road, trailer_axle_x, vehicle.half_track_m, hitch_height)
    R_tractor = rotation_zyx(tractor_yaw, tractor_pitch, tractor_roll)
    R_trailer = rotation_zyx(trailer_yaw, trailer_pitch, trailer_roll)
    zeros = np.zeros((count, 2))
    tractor_body, trailer_body = zeros, zeros
    if vehicle.moves_bodies and count > 2:
        dt = float(np.median(np.diff(planar.timestamps)))
        speed = planar.speed if planar.speed is not None else np.zeros(count)
        parameters = SUSPENSION[vehicle.load]
        tractor_axle = hitch_xy + tractor_axle_x * planar.T_world_tractor[:, :2, 0]
        trailer_axle = hitch_xy + trailer_axle_x * planar.T_world_trailer[:, :2, 0]
        tractor_body = _body_motion(_body_accelerations(planar.timestamps, tractor_axle, tractor_yaw), speed, dt, parameters["tractor"], vehicle, rng)
        trailer_body = _body_motion(_body_accelerations(planar.timestamps, trailer_axle, trailer_yaw), speed, dt, parameters["trailer"], vehicle, rng)
        R_tractor = R_tractor @ _small_rotation(tractor_body[:, 0], tractor_body[:, 1])
        R_trailer = R_trailer @ _small_rotation(trailer_body[:, 0], trailer_body[:, 1])
    T_world_tractor = np.tile(np.eye(4), (count, 1, 1))
    T_world_trailer = np.tile(np.eye(4), (count, 1, 1))
    T_world_tractor[:, :3, :3], T_world_tractor[:, :3, 3] = R_tractor, hitch
    T_world_trailer[:, :3, :3], T_world_trailer[:, :3, 3] = R_trailer, hitch
    trajectory = Trajectory(planar.timestamps, T_world_tractor, T_world_trailer, hitch_angle_of(T_world_tractor, T_world_trailer),
                            planar.speed, planar.curvature, planar.arc_length)
    angles = BodyAngles(np.column_stack([tractor_roll, tractor_pitch]), np.column_stack([trailer_roll, trailer_pitch]), tractor_body, trailer_body)
    return trajectory, angles
