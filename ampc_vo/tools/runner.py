"""Run the odometry on an opened :class:`~ampc_vo.frontend.sources.Sequence`: outputs, timing, Rerun (issue 7).

What ``scripts/run_odometry.py`` does, as a library call: the source's frames go through
:class:`~ampc_vo.backend.pipeline.OdometryPipeline`; the keyframe estimates are written to ``OUT`` as they
are published (``tractor.tum``, ``trailer.tum``, ``hitch.csv``: a crash or Ctrl-C keeps what was
written), then ``timing.json`` (with the frontend's share) and ``config.yaml``. With a Rerun path,
every frame's images and tracked features (tracked: green, rejected by the frontend: red), the
ground truth, and every published estimate (bodies, trajectories, hitch angle with its 1-sigma)
go into an ``.rrd`` file.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ampc_vo.config import VoConfig
from ampc_vo.errors import DatasetError
from ampc_vo.observations import FrameObservations
from ampc_vo.backend.pipeline import RunSummary, run_on_frames
from ampc_vo.backend.smoother import KeyframeEstimate
from ampc_vo.frontend.sources import FrameStep, Sequence

logger = logging.getLogger(__name__)


@dataclass
class SourceTimer:
    """Wall time spent producing each frame (the frontend for image sources), in seconds."""

    seconds: list[float]

    def wrap(self, steps: Iterator[FrameStep], on_step: Callable[[FrameStep], None]) -> Iterator[FrameObservations]:
        """Yield the observations of ``steps``, timing each step and handing it to ``on_step``."""
        iterator = iter(steps)
        while True:
            started = time.perf_counter()
            try:
                step = next(iterator)
            except StopIteration:
                return
            # the step's own production time when it was produced in a worker thread, else the wait
            self.seconds.append(step.seconds if step.seconds is not None else time.perf_counter() - started)
            on_step(step)
            yield step.observations


def _truth_at(sequence: Sequence, frame: int, timestamp: float) -> tuple[np.ndarray | None, np.ndarray | None, float | None]:
    """Ground-truth tractor pose, trailer pose and hitch angle of a frame (``None`` when absent)."""
    truth = sequence.truth
    if truth is None or len(truth.timestamps) == 0:
        return None, None, None
    index = int(np.argmin(np.abs(truth.timestamps - timestamp)))
    if abs(truth.timestamps[index] - timestamp) > 1e-3:
        return None, None, None
    trailer = None if truth.T_world_trailer is None else truth.T_world_trailer[index]
    hitch = None if truth.hitch_angles is None else float(truth.hitch_angles[index])
    return truth.T_world_tractor[index], trailer, hitch


def sequence_wheel_odometry(sequence: Sequence, config: VoConfig) -> Callable[[float, float], float | None] | None:
    """The chord of the sequence's wheel speed (``Sequence.wheel_speed``) when ``scale.wheel_speed``
    is on; a :class:`DatasetError` when it is on and the sequence has none."""
    if not config.scale.wheel_speed:
        if sequence.wheel_speed is not None:
            logger.info("%s: has wheel speed; set scale.wheel_speed: true (run_odometry.py --wheel-speed) to use it", sequence.path)
        return None
    if sequence.wheel_speed is None:
        raise DatasetError(f"{sequence.path}: scale.wheel_speed is on but there is no wheel speed "
                           f"(a wheel_speed.csv in the dataset folder, or scale.wheel_speed_source: a log topic or CSV)")
    from ampc_vo.scale.wheel import wheel_odometry_from_speed

    return wheel_odometry_from_speed(sequence.wheel_speed.timestamps, sequence.wheel_speed.speed)


def run_sequence(sequence: Sequence, config: VoConfig, out_dir: str | Path, rerun_path: str | Path | None = None,
                 progress: bool | None = None, wheel_odometry: Callable[[float, float], float] | None = None) -> tuple[RunSummary, list[KeyframeEstimate]]:
    """Run the pipeline over ``sequence`` writing into ``out_dir`` (module docstring)."""
    timer = SourceTimer([])
    recorder = None
    if rerun_path is not None:
        from ampc_vo.tools.viz import RerunLogger, VizConfig

        recorder = RerunLogger(sequence.rig, rerun_path, VizConfig(**dataclasses.asdict(config.rerun)))

    def log_step(step: FrameStep) -> None:
        if recorder is None:
            return
        observations = step.observations
        tractor, trailer, hitch = _truth_at(sequence, observations.frame, observations.timestamp)
        rejected = None
        if step.frontend is not None:
            rejected = {name: report.rejected_pixels for name, report in step.frontend.reports.items()}
        recorder.log_frame(observations.frame, observations.timestamp, images=step.images, observations=observations,
                           outlier_pixels=rejected, truth_T_world_tractor=tractor, truth_T_world_trailer=trailer, truth_hitch_angle=hitch)

    def log_published(_: FrameObservations | None, published: list[KeyframeEstimate]) -> None:
        if recorder is None:
            return
        for estimate in published:
            recorder.log_frame(estimate.frame, estimate.timestamp, T_world_tractor=estimate.T_world_tractor, T_world_trailer=estimate.T_world_trailer,
                               hitch_angle=estimate.hitch_angle, hitch_sigma=estimate.hitch_sigma)

    steps = sequence.steps(images=recorder is not None and config.rerun.image_every > 0)  # images cross from a frontend process only for a recording
    if wheel_odometry is None:
        wheel_odometry = sequence_wheel_odometry(sequence, config)
    try:
        return run_on_frames(sequence.rig, config, timer.wrap(steps, log_step), out_dir, len(sequence), progress,
                             wheel_odometry, on_frame=log_published, source_seconds=timer.seconds, dataset=sequence.path)
    finally:
        close = getattr(steps, "close", None)
        if close is not None:  # stops a frontend worker process now, not when the traceback is freed
            close()
        if recorder is not None:
            recorder.close()
