"""Ground-truth types (DESIGN section 5): the true motion of a sequence as the simulator writes it and
the dataset readers read it (:class:`Trajectory`), and what the evaluation compares against
(:class:`GroundTruth`, also from KITTI's pose files)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Trajectory:
    """Ground-truth motion sampled at the camera rate.

    ``timestamps`` (F,) seconds; ``T_world_tractor``, ``T_world_trailer`` (F, 4, 4) with origins at
    the hitch; ``hitch_angle`` (F,) radians (``R_tractor_trailer = Rz(hitch_angle)``).
    ``speed``, ``curvature`` and ``arc_length`` of the tractor axle are filled by the simulator
    and ``None`` when read from ``groundtruth.csv``.
    """

    timestamps: np.ndarray
    T_world_tractor: np.ndarray
    T_world_trailer: np.ndarray
    hitch_angle: np.ndarray
    speed: np.ndarray | None = None
    curvature: np.ndarray | None = None
    arc_length: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def pose(self, body: str) -> np.ndarray:
        """(F, 4, 4) poses of ``body`` ('tractor' or 'trailer')."""
        if body == "tractor":
            return self.T_world_tractor
        if body == "trailer":
            return self.T_world_trailer
        raise KeyError(f"unknown body {body!r}")



@dataclass(frozen=True)
class GroundTruth:
    """Ground truth per frame: timestamps (N,), tractor and trailer poses (N, 4, 4), hitch (N,) rad."""

    timestamps: np.ndarray
    T_world_tractor: np.ndarray
    T_world_trailer: np.ndarray | None = None
    hitch_angles: np.ndarray | None = None
    trailer_axle_x: float = 0.0  # trailer ATE is measured at this point of the trailer x axis
    # the frame in which tractor poses are compared, in the tractor frame (None: the body itself;
    # KITTI: the left camera, the frame of its ground truth): truth and estimate are both taken as
    # T_world_tractor @ T_tractor_reference
    T_tractor_reference: np.ndarray | None = None



def groundtruth_of(dataset: object) -> GroundTruth | None:
    """The :class:`GroundTruth` of an opened dataset folder (``io.folder.Dataset``), ``None``
    without ``groundtruth.csv``; the trailer ATE is measured at the trailer axle."""
    trajectory = dataset.groundtruth
    if trajectory is None:
        return None
    axle_x = dataset.rig.axle_x("trailer") if dataset.rig.has_trailer else 0.0
    return GroundTruth(trajectory.timestamps, trajectory.T_world_tractor, trajectory.T_world_trailer, trajectory.hitch_angle, axle_x)
