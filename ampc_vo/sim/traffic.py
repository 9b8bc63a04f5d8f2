"""Moving bodies in the simulated world: traffic and the trailer's box (issue 13).

Both appear in the rendered images (as per-frame quads, :func:`vehicle_quads`) and in the bearing
measurements (landmarks on their surfaces move with them: tracks on them are consistent outliers
to the static world; they also hide what lies behind them).

**Traffic** (sim config ``traffic:``, a list of vehicles)::

    traffic:
      - {kind: leading, gap_m: 18, gap_variation_m: 4, size: van}     # ahead in our lane, moving with us
      - {kind: oncoming, start_m: 80, speed_mps: 12, lateral_m: 3.5}   # the other lane, towards us
      - {kind: overtaking, start_m: -25, relative_speed_mps: 4, lateral_m: 3.5}
      - {kind: crossing, at_m: 60, time_s: 6, speed_mps: 8, size: truck}  # crosses the road at arc length 60 m at 6 s

Positions are along the road's centre line (``scene.route_centerline``; arc length ``s``, lateral
offset to the left): ``leading``: ``s = s_truck(t) + gap + gap_variation sin(2 pi t / 20 s)``;
``oncoming``: ``s = start - speed t``, heading reversed; ``overtaking``: ``s = s_truck(t) + start +
relative_speed t``; ``crossing``: from the centre-line point at ``at_m`` along its left normal,
``(t - time_s) speed`` metres (it may drive through buildings: the scene has no side streets).
``s_truck`` is the tractor's arc length at time ``t``; start positions of ``oncoming`` are absolute
arc lengths. Sizes (length, width, height in m): car 4.5 x 1.8 x 1.5, van 5.5 x 2.0 x 2.4, truck
12 x 2.5 x 3.6.

**The trailer's box** (sim config ``trailer_body:``): a box attached to the trailer pose,
``length_m`` long from ``front_x_m`` (ahead of the king-pin) backwards, ``width_m`` wide, from
``floor_height_m`` above the road to ``floor_height_m + height_m``; the tractor's (mirror) cameras see
it, the trailer's own cameras do not (they are mounted on it; a trailer camera inside the box is a
ConfigError).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ampc_vo.errors import ConfigError
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.sim.motion import PoseSampler
from ampc_vo.sim.scene import Centerline, Quad
from ampc_vo.sim.traffic_config import TrailerBodySpec, VehicleSpec, trailer_body_from_dict, traffic_from_list  # noqa: F401

_GAP_PERIOD_S = 20.0  # s, period of the leading vehicle's gap variation

__all__ = ["VehicleSpec", "TrailerBodySpec", "traffic_from_list", "trailer_body_from_dict", "DynamicScene", "build_dynamic_scene",
           "vehicle_quads", "box_faces"]

def vehicle_quads(T_world_vehicle: np.ndarray, length: float = 4.5, width: float = 1.8, height: float = 1.5,
                  texture: str = "metal") -> list[Quad]:
    """A box (4 sides and the roof) at ``T_world_vehicle`` (origin at the box's ground centre)."""
    R, p = T_world_vehicle[:3, :3], T_world_vehicle[:3, 3]
    x, y, z = R[:, 0], R[:, 1], R[:, 2]
    rear_right = p - 0.5 * length * x - 0.5 * width * y
    front_right = p + 0.5 * length * x - 0.5 * width * y
    rear_left = p - 0.5 * length * x + 0.5 * width * y
    top = rear_right + height * z
    return [
        Quad(rear_right, x, z, length, height, "box", texture, 2.0),
        Quad(rear_left, x, z, length, height, "box", texture, 2.0),
        Quad(rear_right, y, z, width, height, "box", texture, 2.0),
        Quad(front_right, y, z, width, height, "box", texture, 2.0),
        Quad(top, x, y, length, width, "box", texture, 2.0),
    ]


def box_faces(length: float, width: float, height: float, texture: str) -> list[Quad]:
    """The 4 sides and the roof of a box in its own frame (origin at the centre of its bottom)."""
    return vehicle_quads(np.eye(4), length, width, height, texture)


def _transform_quad(T: np.ndarray, quad: Quad) -> Quad:
    R, p = T[:3, :3], T[:3, 3]
    return Quad(R @ quad.origin + p, R @ quad.axis_u, R @ quad.axis_v, quad.width, quad.height, quad.kind, quad.texture, quad.texture_scale)


@dataclass(frozen=True)
class DynamicScene:
    """Moving bodies: ``B`` box-shaped bodies with poses at any time, their faces in the body frame,
    and landmarks on those faces (body frame). Body ``b`` is a traffic vehicle or the trailer box
    (``attached_to[b] == 'trailer'``; its pose follows the trailer's)."""

    vehicles: tuple[VehicleSpec, ...]
    centerline: Centerline
    truck_times: np.ndarray          # (F,) trajectory times
    truck_arc: np.ndarray            # (F,) tractor arc length along the centre line at those times
    trailer_body: TrailerBodySpec | None
    pose_trajectory: Trajectory | None
    hitch_height: float
    faces: tuple[tuple[Quad, ...], ...]     # per body, in the body frame
    attached_to: tuple[str, ...]            # per body: '' (traffic) or the rig body it is fixed to
    landmark_body: np.ndarray               # (L,) body index of each dynamic landmark
    landmark_face: np.ndarray               # (L,) face index within its body
    landmark_points: np.ndarray             # (L, 3) in the body frame
    road: Any = None                        # sim.road.RoadSurface the traffic drives on (None: z = 0)
    attached_sampler: Any = None            # motion.PoseSampler of the trailer (bodies fixed to it)

    @property
    def body_count(self) -> int:
        return len(self.faces)

    # ------------------------------------------------------------------ poses
    def _road_frame(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Point, tangent and left normal of the centre line at arc lengths ``s`` (straight beyond its ends)."""
        line = self.centerline
        s = np.asarray(s, float)
        index = np.clip(np.searchsorted(line.arc_length, s) - 1, 0, len(line.arc_length) - 2)
        fraction = (s - line.arc_length[index]) / (line.arc_length[index + 1] - line.arc_length[index])
        point = line.points[index] + fraction[:, None] * (line.points[index + 1] - line.points[index])
        tangent = line.tangents[index] + np.clip(fraction, 0, 1)[:, None] * (line.tangents[index + 1] - line.tangents[index])
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        normal = np.cross(np.array([0.0, 0.0, 1.0]), tangent)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        return point, tangent, normal

    def poses(self, body: int, times: np.ndarray) -> np.ndarray:
        """(N, 4, 4) ``T_world_body`` of body ``body`` at ``times`` (module docstring)."""
        times = np.atleast_1d(np.asarray(times, float))
        if self.attached_to[body]:
            spec = self.trailer_body
            T_trailer_box = np.eye(4)
            T_trailer_box[:3, 3] = (spec.front_x_m - 0.5 * spec.length_m, 0.0, spec.floor_height_m - self.hitch_height)
            return self.attached_sampler(times) @ T_trailer_box
        vehicle = self.vehicles[body]
        truck = np.interp(times, self.truck_times, self.truck_arc)
        heading_sign = 1.0
        if vehicle.kind == "leading":
            s = truck + vehicle.gap_m + vehicle.gap_variation_m * np.sin(2 * np.pi * times / _GAP_PERIOD_S)
        elif vehicle.kind == "overtaking":
            s = truck + vehicle.start_m + vehicle.relative_speed_mps * times
        elif vehicle.kind == "oncoming":
            s, heading_sign = vehicle.start_m - vehicle.speed_mps * times, -1.0
        else:
            s = np.full(len(times), vehicle.at_m)
        point, tangent, normal = self._road_frame(s)
        if vehicle.kind == "crossing":
            position = point + normal * ((times - vehicle.time_s) * vehicle.speed_mps)[:, None] + vehicle.lateral_m * tangent
            x_axis = normal
        else:
            position = point + vehicle.lateral_m * normal
            x_axis = heading_sign * tangent
        z_axis = np.tile([0.0, 0.0, 1.0], (len(times), 1))
        y_axis = np.cross(z_axis, x_axis)
        result = np.tile(np.eye(4), (len(times), 1, 1))
        result[:, :3, 0], result[:, :3, 1], result[:, :3, 2] = x_axis, y_axis, z_axis
        if self.road is not None:  # on the 3D road: at the surface height under the vehicle
            position = position.copy()
            position[:, 2] = self.road.height(position[:, :2])
        result[:, :3, 3] = position
        return result

    # ------------------------------------------------------------------ what cameras see
    def visible_bodies(self, camera: Any) -> list[int]:
        """Bodies a camera can see: all but the ones fixed to its own body."""
        return [body for body in range(self.body_count) if self.attached_to[body] != camera.body]

    def quads_at(self, time: float, camera: Any) -> list[Quad]:
        """World quads of the bodies ``camera`` sees, at ``time`` (the renderer's extra quads)."""
        quads: list[Quad] = []
        for body in self.visible_bodies(camera):
            T = self.poses(body, np.array([time]))[0]
            quads += [_transform_quad(T, face) for face in self.faces[body]]
        return quads

    def landmarks_at(self, indices: np.ndarray, times: np.ndarray) -> np.ndarray:
        """World points (N, 3) of dynamic landmarks ``indices`` at per-point ``times`` (N,)."""
        indices = np.asarray(indices, np.int64)
        times = np.broadcast_to(np.asarray(times, float), indices.shape)
        points = np.zeros((len(indices), 3))
        for body in np.unique(self.landmark_body[indices]):
            mask = self.landmark_body[indices] == body
            poses = self.poses(int(body), times[mask])
            points[mask] = np.einsum("nij,nj->ni", poses[:, :3, :3], self.landmark_points[indices[mask]]) + poses[:, :3, 3]
        return points


def build_dynamic_scene(vehicles: tuple[VehicleSpec, ...], trailer_body: TrailerBodySpec | None, trajectory: Trajectory, rig: Any,
                        centerline: Centerline, landmark_density: float, rng: np.random.Generator,
                        pose_trajectory: Trajectory | None = None, road: Any = None) -> DynamicScene | None:
    """The moving bodies of a simulation and their landmarks (``landmark_density`` per m^2 of face);
    ``None`` when there are none. A trailer camera inside the trailer box is a ConfigError."""
    if not vehicles and trailer_body is None:
        return None
    faces, attached = [], []
    for vehicle in vehicles:
        faces.append(tuple(box_faces(*vehicle.size, vehicle.texture)))
        attached.append("")
    if trailer_body is not None:
        if not rig.has_trailer:
            raise ConfigError("trailer_body: the rig has no trailer")
        faces.append(tuple(box_faces(trailer_body.length_m, trailer_body.width_m, trailer_body.height_m, trailer_body.texture)))
        attached.append("trailer")
        box_origin = np.array([trailer_body.front_x_m - 0.5 * trailer_body.length_m, 0.0, trailer_body.floor_height_m - rig.hitch_height])
        half = np.array([0.5 * trailer_body.length_m, 0.5 * trailer_body.width_m, 0.5 * trailer_body.height_m])
        for camera in rig.cameras:
            if camera.body == "trailer":
                relative = camera.T_body_camera[:3, 3] - (box_origin + np.array([0.0, 0.0, half[2]]))
                if np.all(np.abs(relative) < half - 1e-3):
                    raise ConfigError(f"trailer_body: camera {camera.name!r} at {camera.T_body_camera[:3, 3].tolist()} is inside the trailer box")
    bodies, face_index, points = [], [], []
    for body, body_faces in enumerate(faces):
        for index, face in enumerate(body_faces):
            count = rng.poisson(landmark_density * face.width * face.height)
            coordinates = rng.uniform(0.0, 1.0, size=(count, 2)) * np.array([face.width, face.height])
            points.append(face.points(coordinates))
            bodies.append(np.full(count, body))
            face_index.append(np.full(count, index))
    arc = trajectory.arc_length
    if arc is None:
        steps = np.linalg.norm(np.diff(trajectory.T_world_tractor[:, :2, 3], axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
    return DynamicScene(
        vehicles=tuple(vehicles), centerline=centerline, truck_times=np.asarray(trajectory.timestamps, float),
        truck_arc=np.asarray(arc, float) - float(arc[0]), trailer_body=trailer_body,
        pose_trajectory=trajectory if pose_trajectory is None else pose_trajectory, hitch_height=float(rig.hitch_height),
        faces=tuple(faces), attached_to=tuple(attached), landmark_body=np.concatenate(bodies).astype(np.int64),
        landmark_face=np.concatenate(face_index).astype(np.int64), landmark_points=np.concatenate(points).reshape(-1, 3),
        attached_sampler=PoseSampler.of(trajectory if pose_trajectory is None else pose_trajectory, "trailer") if trailer_body is not None else None,
        road=road)
