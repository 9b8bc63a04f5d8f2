"""The odometry on a simulated sequence, scored against its truth: the shared step of the robustness
experiments (``scripts/experiment_tyre_slip.py``, ``scripts/experiment_calibration.py``).

:func:`score_on_simulation` runs the pipeline on the simulated bearings of a
:class:`~ampc_vo.sim.simulation.SimulationResult` and returns the evaluation metrics; given another
rig (e.g. :func:`miscalibrated_rig`), the measurements are un-projected and the rig's geometry is
used with that rig's calibration, as a real system runs with its (imperfect) calibration file.
"""
from __future__ import annotations

import math
import tempfile
from dataclasses import replace

import numpy as np

from ampc_vo.config import VoConfig
from ampc_vo.io.groundtruth import GroundTruth
from ampc_vo.tools.evaluation import Metrics, evaluate_output
from ampc_vo.geometry import make_pose, rot_x, rot_y, rot_z
from ampc_vo.backend.pipeline import run_on_frames
from ampc_vo.rig import Rig

# rotation of a camera about its own axes (OpenCV: x right, y down, z forward; DESIGN 1)
CAMERA_AXES = {"tilt": rot_x, "pan": rot_y, "roll": rot_z}


def simulation_truth(result: object) -> GroundTruth:
    """The :class:`GroundTruth` of a simulation result (trailer ATE at the trailer axle)."""
    truth = result.trajectory
    return GroundTruth(truth.timestamps, truth.T_world_tractor, truth.T_world_trailer, truth.hitch_angle, result.rig.axle_x("trailer"))


def score_on_simulation(result: object, config: VoConfig, rig: Rig | None = None) -> Metrics:
    """Metrics of the odometry (``config``) on the simulated bearings of ``result``, run with ``rig``
    (default: the rig that was simulated)."""
    rig = result.rig if rig is None else rig
    with tempfile.TemporaryDirectory() as out:
        run_on_frames(rig, config, result.measurements.frames(rig), out, len(result.trajectory), progress=False)
        return evaluate_output(out, simulation_truth(result)).metrics


def miscalibrated_rig(rig: Rig, cameras: tuple[str, ...], axis: str, degrees: float) -> Rig:
    """``rig`` with the mounts of ``cameras`` rotated by ``degrees`` about their own ``axis``
    (``tilt``: camera x, ``pan``: camera y, ``roll``: the optical axis): a calibration error."""
    if axis not in CAMERA_AXES:
        raise ValueError(f"unknown camera axis {axis!r} (expected one of {sorted(CAMERA_AXES)})")
    error = make_pose(CAMERA_AXES[axis](math.radians(degrees)), np.zeros(3))
    unknown = set(cameras) - set(rig.camera_names)
    if unknown:
        raise ValueError(f"rig has no camera(s) {sorted(unknown)}; cameras: {rig.camera_names}")
    return replace(rig, cameras=tuple(replace(camera, T_body_camera=camera.T_body_camera @ error) if camera.name in cameras else camera
                                 for camera in rig.cameras))
