"""MotionInitializer (DESIGN 2.1): a standstill must be physically possible (issue 16)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ampc_vo.backend.motion_init import MotionInitializer
from ampc_vo.backend.smoother import MotionStatus
from ampc_vo.config import VoConfig
from ampc_vo.geometry import make_pose
from ampc_vo.observations import CameraObservations, FrameObservations
from ampc_vo.rig import load_rig
from ampc_vo.solvers import ackermann_motion

RIG = load_rig(Path(__file__).resolve().parents[2] / "configs" / "rigs" / "default.yaml")


def _unit(points_camera: np.ndarray) -> np.ndarray:
    return points_camera / np.linalg.norm(points_camera, axis=1, keepdims=True)


def _pair(yaw_change: float, chord: float, rng: np.random.Generator) -> tuple[FrameObservations, FrameObservations]:
    """Frames 0.1 s apart: the front camera sees the world moved by the Ackermann motion, the left
    camera mostly sees something rigidly attached to the tractor (bearings unchanged)."""
    T_i_j = make_pose(*ackermann_motion(yaw_change, chord, RIG.axle_x("tractor")))
    front = RIG.camera("front")
    in_front = np.column_stack([rng.uniform(-8, 8, 60), rng.uniform(-3, 1, 60), rng.uniform(8, 30, 60)])  # camera frame at i
    T_body_front = front.T_body_camera
    points_body_i = in_front @ T_body_front[:3, :3].T + T_body_front[:3, 3]
    T_front_j = np.linalg.inv(T_i_j @ T_body_front)
    in_front_j = points_body_i @ T_front_j[:3, :3].T + T_front_j[:3, 3]
    attached = np.column_stack([rng.uniform(-2, 2, 200), rng.uniform(-1, 1, 200), rng.uniform(3, 8, 200)])  # left camera frame
    first, second = {}, {}
    for name, before, after in (("front", in_front, in_front_j), ("left", attached, attached)):
        ids = np.arange(len(before))
        first[name] = CameraObservations(name, ids, np.zeros((len(ids), 2)), _unit(before))
        second[name] = CameraObservations(name, ids, np.zeros((len(ids), 2)), _unit(after))
    return FrameObservations(0, 0.0, first), FrameObservations(1, 0.1, second)


def test_parallax_standstill_is_overruled_when_the_truck_cannot_have_stopped() -> None:
    """Turning at 5 m/s, the mirror's tracks on the tractor-fixed box have no parallax and make the
    median parallax say 'standstill'; braking from 5 m/s to rest within 0.1 s is impossible, so the
    motion is estimated (the box tracks are outliers of it)."""
    initializer = MotionInitializer(RIG, VoConfig(mode="tractor_only"))
    first, second = _pair(np.radians(2.0), 0.5, np.random.default_rng(4))
    predicted = make_pose(*ackermann_motion(np.radians(1.5), 0.5, RIG.axle_x("tractor")))
    assert initializer.tractor(first, second, predicted).status is MotionStatus.STANDSTILL  # speed unknown: no gate
    tractor = initializer.tractor(first, second, predicted, speed_before=5.0)
    assert tractor.status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE)
    yaw = np.arctan2(tractor.T_i_j[1, 0], tractor.T_i_j[0, 0])
    assert np.degrees(yaw) == pytest.approx(2.0, abs=0.1)


def test_standstill_stays_when_the_truck_was_slow_enough_to_stop() -> None:
    """The same tracks after creeping at 0.3 m/s (it can stop within the pair): a standstill."""
    initializer = MotionInitializer(RIG, VoConfig(mode="tractor_only"))
    first, second = _pair(0.0, 0.0, np.random.default_rng(4))
    predicted = make_pose(*ackermann_motion(0.0, 0.03, RIG.axle_x("tractor")))
    assert initializer.tractor(first, second, predicted, speed_before=0.3).status is MotionStatus.STANDSTILL
    assert initializer.tractor(first, second, predicted, speed_before=-0.5).status is MotionStatus.STANDSTILL  # reversing slowly
    assert initializer.tractor(first, second, predicted, speed_before=5.0).status is not MotionStatus.STANDSTILL  # no stop from 5 m/s in 0.1 s
