"""Odometry pipeline: frames of observations in, keyframe estimates out (DESIGN section 4).

Measurement sources are pluggable: anything that yields :class:`FrameObservations` in time order
(the simulator's ``Measurements.frames(rig)``, the image frontend). Per frame:

1. tractor RANSAC against the last keyframe (2-point solver, DESIGN 2.1), with a constant-velocity
   prediction filling what it cannot observe;
2. keyframe decision (:class:`KeyframePolicy`): moved ``min_distance_m``, turned
   ``min_rotation_deg``, ``max_interval_s`` elapsed, or tracks about to be lost;
3. for a keyframe: trailer RANSAC (1-point solver, DESIGN 2.2), then the smoother update, which
   publishes tractor pose, trailer pose, hitch angle and 1-sigma; these are written to the output
   files at once (:class:`~ampc_vo.io.outputs.OutputWriter`).
"""
from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from threadpoolctl import threadpool_limits

from ampc_vo.config import VoConfig, config_yaml
from ampc_vo.errors import NothingMeasuredError
from ampc_vo.geometry import make_pose, relative_pose, rot_z, yaw_of
from ampc_vo.backend.motion_init import MotionInitializer, TractorMotion, camera_pairs
from ampc_vo.observations import FrameObservations
from ampc_vo.io.outputs import OutputWriter
from ampc_vo.io.run_folder import CONFIG_FILE, TIMING_FILE, RunFolder
from ampc_vo.rig import Rig
from ampc_vo.backend.smoother import ArticulatedSmoother, KeyframeEstimate, MotionInit, MotionStatus

logger = logging.getLogger(__name__)



@dataclass(frozen=True)
class KeyframeDecision:
    is_keyframe: bool
    reason: str


_CLOCK_JITTER_PERIODS = 0.25  # interval_reached: tolerance in frame periods


def interval_reached(elapsed_s: float, interval_s: float, frame_period_s: float = 0.0) -> bool:
    """Whether ``elapsed_s`` since the last keyframe has reached ``interval_s``, up to a quarter of
    the frame period ``frame_period_s``. A camera's clock jitters by milliseconds around the frame
    rate (a log's frame times are its reference camera's capture stamps, a folder's the nominal
    times): an interval that is a whole number of frame periods, compared exactly, takes the frame
    on one clock and the next frame on the other, and every later keyframe moves with it (a
    realistic yard route from a lossless log took frame 6 for the folder's 5 as its second keyframe).
    With the tolerance both take the same frame while the jitter stays below a quarter period."""
    return elapsed_s >= interval_s - max(_CLOCK_JITTER_PERIODS * frame_period_s, 1e-9)


@dataclass(frozen=True)
class KeyframePolicy:
    """Keyframe selection from the tractor motion since the last keyframe (config ``keyframes``)."""

    min_distance_m: float
    min_rotation_rad: float
    max_interval_s: float

    @staticmethod
    def from_config(config: VoConfig) -> "KeyframePolicy":
        keyframes = config.keyframes
        return KeyframePolicy(keyframes.min_distance_m, np.radians(keyframes.min_rotation_deg), keyframes.max_interval_s)

    def decide(self, motion: TractorMotion, elapsed_s: float, frame_period_s: float = 0.0) -> KeyframeDecision:
        """``frame_period_s``: the time since the previous frame (:func:`interval_reached`)."""
        if motion.status is MotionStatus.TOO_FEW_TRACKS:
            return KeyframeDecision(True, "too few tracks")
        if interval_reached(elapsed_s, self.max_interval_s, frame_period_s):
            return KeyframeDecision(True, "interval")
        if motion.status is MotionStatus.STANDSTILL:
            return KeyframeDecision(False, "standstill")
        if motion.chord >= self.min_distance_m:
            return KeyframeDecision(True, "distance")
        if abs(motion.yaw_change) >= self.min_rotation_rad:
            return KeyframeDecision(True, "rotation")
        return KeyframeDecision(False, "moving")


@dataclass
class RunSummary:
    """What a run did and how long it took (written to ``timing.json``)."""

    frames: int = 0
    keyframes: int = 0
    distance_m: float = 0.0
    seconds: float = 0.0
    seconds_per_frame: float = 0.0
    frames_per_second: float = 0.0
    backend_ms_median: float = 0.0
    backend_ms_breakdown: dict = field(default_factory=dict)
    backend_cpu_ms_median: float = 0.0  # the backend thread's CPU time per keyframe (wall time minus waiting for a core)
    statuses: dict = field(default_factory=dict)
    mode: str = "full"
    dataset: str | None = None  # the folder the frames came from (absolute; evaluate.py checks it)
    unscaled_keyframes: int = 0  # bootstrap keyframes without poses: their speed was never measured
    run_id: str | None = None  # the run that wrote the output folder (ampc_vo.io.run_folder)


def _with_chord_length(T_i_j: np.ndarray, chord: float) -> np.ndarray:
    """``T_i_j`` with its translation scaled to the signed length ``chord`` (< 0: backwards; the
    line of the translation and the rotation kept; a motion without translation moves along x)."""
    T = T_i_j.copy()
    length = float(np.linalg.norm(T[:3, 3]))
    direction = T[:3, 3] / length if length > 1e-9 else np.array([1.0, 0.0, 0.0])
    if direction[0] * chord < 0.0:
        direction = -direction
    T[:3, 3] = direction * abs(chord)
    return T


_REVERSING_M = 0.01  # a body's origin moved backwards by more than this: reversing (less: at rest, forward by default)


def _chord_measured(init: MotionInit) -> bool:
    """Whether a keyframe pair's tractor chord was measured (a 2-point or joint chord, a standstill,
    a ground-plane, stereo or wheel chord) rather than taken from the constant-velocity prediction."""
    return (init.tractor_status in (MotionStatus.OK, MotionStatus.STANDSTILL) or init.scale_chord is not None
            or init.wheel_chord is not None)


def _velocity_of(motion: np.ndarray, dt: float) -> tuple[float, float]:
    """``(yaw rate, signed speed)`` of a body's ``motion`` (``T_i_j``) over ``dt`` seconds: the speed
    is negative when the body's origin moved backwards in its own frame (reversing); a body at rest
    (the smoother's few millimetres either way) counts as forward."""
    speed = float(np.linalg.norm(motion[:2, 3])) / dt
    return yaw_of(motion) / dt, -speed if motion[0, 3] < -_REVERSING_M else speed


class OdometryPipeline:
    """Keyframe selection, initialisation and smoothing over a stream of frames (module docstring)."""

    def __init__(self, rig: Rig, config: VoConfig, writer: OutputWriter | None = None,
                 wheel_odometry: Callable[[float, float], float] | None = None) -> None:
        """``wheel_odometry(t_i, t_j)``: chord (m) of the tractor axle midpoint between two times
        (``None``: not measured then), used when ``scale.wheel_speed`` is on: in the optional
        WheelSpeedFactor and as the measured chord of the scale bootstrap."""
        self.rig = rig
        self.wheel_odometry = wheel_odometry
        self.config = config
        self.writer = writer
        self.policy = KeyframePolicy.from_config(config)
        self.initializer = MotionInitializer(rig, config)
        self.smoother = ArticulatedSmoother(rig, config)
        self.estimates: list[KeyframeEstimate] = []
        self._last_keyframe: FrameObservations | None = None
        self._velocity: np.ndarray | None = None  # last tractor motion per second: (yaw rate, signed speed; < 0 reversing)
        self._speed_measured_at: float | None = None  # the newest keyframe whose chord was measured (time, s)
        self._trailer_velocity: tuple[float, float] | None = None
        self._hitch: float | None = None
        self._frames = 0
        self._previous_timestamp = 0.0  # the previous frame's time (s): the frame period of interval_reached
        self._distance = 0.0
        self._statuses: dict[str, int] = {}
        self._bootstrapping = True
        self._deferring = False  # latest: the start's publication waits for the hitch (_publish_start_if_observed)
        self._deferred_since = 0.0
        self._bootstrap: list[tuple[FrameObservations, TractorMotion | None]] = []
        self._bootstrap_speeds: list[float | None] = []  # measured metric speed of each bootstrap pair
        self._unscaled_frames = 0  # bootstrap keyframes dropped: their speed was never measured

    # ------------------------------------------------------------------ prediction
    def _predicted(self, elapsed_s: float, velocity: tuple[float, float] | None) -> np.ndarray:
        """Constant-velocity tractor (or trailer) motion over ``elapsed_s``: arc of the last yaw rate
        and signed speed (backwards when reversing; before any motion was estimated a straight 1 m/s guess, used only as the RANSAC
        chord prior of the scale bootstrap: it never reaches the outputs)."""
        yaw_rate, speed = velocity if velocity is not None else (0.0, 1.0)
        yaw = yaw_rate * elapsed_s
        chord = speed * elapsed_s
        return make_pose(rot_z(yaw), chord * np.array([np.cos(0.5 * yaw), np.sin(0.5 * yaw), 0.0]))

    # ------------------------------------------------------------------ frames
    def process(self, frame: FrameObservations) -> list[KeyframeEstimate]:
        """Consume one frame; returns the estimates published by it (often none)."""
        self._frames += 1
        if self._last_keyframe is None:
            self._last_keyframe, self._previous_timestamp = frame, frame.timestamp
            self._bootstrap.append((frame, None))
            return []
        elapsed = frame.timestamp - self._last_keyframe.timestamp
        frame_period, self._previous_timestamp = frame.timestamp - self._previous_timestamp, frame.timestamp
        if elapsed <= 0:
            logger.warning("frame %d: timestamp %.6f not after the last keyframe's %.6f: skipped", frame.frame, frame.timestamp, self._last_keyframe.timestamp)
            return []
        if self._bootstrapping:
            return self._process_bootstrap(frame, elapsed, frame_period)
        predicted = self._predicted(elapsed, self._velocity)
        if self._clearly_no_keyframe(frame, predicted, elapsed, frame_period):
            return []
        # constant-speed prediction: sigma from the smooth-speed acceleration sigma (DESIGN 2.3)
        acceleration = self.config.scale.smooth_speed_sigma_mps2 or 1.0
        predicted_chord = float(np.linalg.norm(predicted[:2, 3]))
        prediction_sigma = 0.1 + 0.25 * predicted_chord + acceleration * elapsed**2
        wheel = self._wheel_chord(self._last_keyframe, frame)
        if wheel is not None:  # wheel odometry measures the chord: the prediction takes it
            predicted, prediction_sigma = _with_chord_length(predicted, wheel), self.config.scale.wheel_speed_sigma_m
        tractor = self.initializer.tractor(self._last_keyframe, frame, predicted, prediction_sigma if self._velocity is not None else None,
                                           speed_before=self._speed_before, hitch=self._hitch,
                                           speed_age=self._speed_age)
        decision = self.policy.decide(tractor, elapsed, frame_period)
        if not decision.is_keyframe:
            return []
        return self._add_keyframe(frame, tractor, elapsed)

    @property
    def _speed_before(self) -> float | None:
        """The tractor's signed speed over the last keyframe interval (m/s; None before one is known)."""
        return float(self._velocity[1]) if self._velocity is not None else None

    @property
    def _speed_age(self) -> float:
        """Seconds from the newest keyframe whose chord was measured to the last keyframe (0 before
        one is known): the speed before is the constant-velocity prediction's since then."""
        if self._speed_measured_at is None or self._last_keyframe is None:
            return 0.0
        return max(self._last_keyframe.timestamp - self._speed_measured_at, 0.0)

    def _clearly_no_keyframe(self, frame: FrameObservations, predicted: np.ndarray, elapsed: float, frame_period: float) -> bool:
        """True when the constant-velocity prediction is far below the keyframe thresholds
        (``keyframes.prediction_gate``) and the tracks shared with the last keyframe are plenty:
        the frame cannot be a keyframe and its tractor RANSAC is skipped (about 20 ms per frame)."""
        gate = self.config.keyframes.prediction_gate
        if gate <= 0.0 or self._velocity is None or interval_reached(elapsed, gate * self.policy.max_interval_s, frame_period):
            return False
        if np.linalg.norm(predicted[:2, 3]) >= gate * self.config.keyframes.min_distance_m or abs(yaw_of(predicted)) >= gate * self.policy.min_rotation_rad:
            return False
        shared = sum(len(pair) for pair in camera_pairs(self.rig, "tractor", self._last_keyframe, frame))
        return shared >= 4 * self.config.keyframes.min_tracks

    def _wheel_chord(self, first: FrameObservations, second: FrameObservations) -> float | None:
        """The wheel-odometry chord (m) between two frames when ``scale.wheel_speed`` is on and the
        wheel odometry covers both times, else ``None``."""
        if not self.config.scale.wheel_speed or self.wheel_odometry is None:
            return None
        chord = self.wheel_odometry(first.timestamp, second.timestamp)
        return None if chord is None else float(chord)

    def _add_keyframe(self, frame: FrameObservations, tractor: TractorMotion, elapsed: float, replay: bool = False) -> list[KeyframeEstimate]:
        """Add a keyframe to the smoother (published as in lagged mode while the start's publication
        is deferred: :meth:`_replay_bootstrap`, :meth:`_publish_start_if_observed`; ``replay``: a
        keyframe of the bootstrap's replay, which ends it only once all are in); what it publishes is
        written and returned."""
        predicted_trailer = self._predicted(elapsed, self._trailer_velocity) if self._trailer_velocity is not None else None
        init = self.initializer.keyframe(self._last_keyframe, frame, tractor, self._hitch, predicted_trailer, speed_before=self._speed_before,
                                         speed_age=self._speed_age)
        chord = self._wheel_chord(self._last_keyframe, frame)
        if chord is not None:
            init = dataclasses.replace(init, wheel_chord=chord)
        if _chord_measured(init):
            self._speed_measured_at = frame.timestamp
        self._statuses[init.tractor_status.value] = self._statuses.get(init.tractor_status.value, 0) + 1
        if self.smoother.keyframe_count == 0:
            self.smoother.add_keyframe(self._last_keyframe, _first_init())
        published = self.smoother.add_keyframe(frame, init, deferred=self._deferring)
        self._last_keyframe = frame
        self._after_publish(published)
        if self._deferring and not replay:
            published += self._publish_start_if_observed()
        return published

    # ------------------------------------------------------------------ scale bootstrap
    def _process_bootstrap(self, frame: FrameObservations, elapsed: float, frame_period: float) -> list[KeyframeEstimate]:
        """Before metric scale was observed (straight start: DESIGN 2.3), keyframes are taken by
        time or rotation and buffered; once ``bootstrap_pairs`` keyframe pairs had an observable
        chord (or ``bootstrap_max_s`` passed with at least one), their median speed scales the
        buffered straight motions and all are replayed. Without any measured chord nothing is
        published (no speed is assumed, issue 14): the buffer waits for one, keeping at most
        ``bootstrap_max_s`` of keyframes (older ones get no poses, with a warning)."""
        scale = self.config.scale
        wheel = self._wheel_chord(self._last_keyframe, frame)  # wheel odometry measures the chord directly
        predicted = self._predicted(elapsed, None) if wheel is None else _with_chord_length(self._predicted(elapsed, None), wheel)
        tractor = self.initializer.tractor(self._last_keyframe, frame, predicted, hitch=self._hitch)
        rotation = abs(tractor.yaw_change) >= self.policy.min_rotation_rad
        observed = tractor.status is MotionStatus.OK and tractor.chord >= self.config.keyframes.standstill_distance_m
        if not (observed or rotation or tractor.status is MotionStatus.TOO_FEW_TRACKS or interval_reached(elapsed, scale.bootstrap_interval_s, frame_period)):
            return []
        measured = (wheel, scale.wheel_speed_sigma_m) if wheel is not None else self.initializer.measured_chord(self._last_keyframe, frame, tractor)
        self._bootstrap.append((frame, tractor))
        self._bootstrap_speeds.append(None if measured is None else measured[0] / elapsed)
        self._last_keyframe = frame
        speeds = self._bootstrap_speed_samples()
        waited = frame.timestamp - self._bootstrap[0][0].timestamp
        if len(speeds) < scale.bootstrap_pairs and waited < scale.bootstrap_max_s:
            return []
        if not speeds:
            self._drop_unscaled_bootstrap(frame, waited)
            return []
        speed = float(np.median(speeds))
        logger.info("frame %d: metric scale bootstrapped after %.1f s from %d keyframe pairs: %.2f m/s", frame.frame, waited, len(speeds), speed)
        return self._replay_bootstrap(speed)

    def _bootstrap_speed_samples(self) -> list[float]:
        """Measured speeds (m/s) of the buffered bootstrap keyframe pairs: a measured metric chord
        (ground plane, stereo) where there is one, else the 2-point chord of an ``ok`` motion
        (weak on a straight start, DESIGN 2.3); pairs with neither give none."""
        return [measured_speed if measured_speed is not None else motion.chord / (kf.timestamp - previous.timestamp)
                for (previous, _), (kf, motion), measured_speed in zip(self._bootstrap, self._bootstrap[1:], self._bootstrap_speeds)
                if measured_speed is not None or (motion is not None and motion.status is MotionStatus.OK)]

    def _drop_unscaled_bootstrap(self, frame: FrameObservations, waited: float) -> None:
        """No metric chord within ``bootstrap_max_s``: keep waiting for one, but only over the last
        ``bootstrap_max_s``; the keyframes before get no poses (nothing measured their speed)."""
        horizon = frame.timestamp - self.config.scale.bootstrap_max_s
        keep = next(index for index, (kf, _) in enumerate(self._bootstrap) if kf.timestamp >= horizon or kf is frame)
        if keep == 0:
            return
        dropped = self._bootstrap[:keep]
        if not self._unscaled_frames:
            logger.warning("frame %d: no metric motion measured in %.0f s (nothing tracked, standing, or a straight start without "
                           "ground-plane or stereo scale): no poses until it is; no speed is assumed", frame.frame, waited)
        self._unscaled_frames += len(dropped)
        self._bootstrap = [(self._bootstrap[keep][0], None)] + self._bootstrap[keep + 1:]
        self._bootstrap_speeds = self._bootstrap_speeds[keep:]

    def _replay_bootstrap(self, speed: float) -> list[KeyframeEstimate]:
        """Add the buffered bootstrap keyframes to the smoother, their unmeasured chords at ``speed``.
        Nothing was published while they waited for scale: with ``output.publish: latest`` they are
        published as in lagged mode, each when it leaves the window during the replay and the rest
        with the window's estimate once the hitch is observed (:meth:`_publish_start_if_observed`,
        at the replay's end or later; DESIGN 11, "The hitch is held at a standstill"), not with the
        estimate each had as the newest keyframe: a standing start's keyframes at rest then carry
        the hitch angle the drive-off measured, and the first moving keyframe (a chord of a few
        centimetres) the next ones' motion."""
        buffered, self._bootstrap = self._bootstrap, []
        self._bootstrapping = False
        self._deferring = self.config.output.publish == "latest"
        self._deferred_since = buffered[-1][0].timestamp  # the bootstrap's end: latest waits at most lag_s from here
        self._last_keyframe = buffered[0][0]
        published: list[KeyframeEstimate] = []
        for (previous, _), (frame, tractor) in zip(buffered, buffered[1:]):
            elapsed = frame.timestamp - previous.timestamp
            if tractor.status is not MotionStatus.OK and tractor.status is not MotionStatus.STANDSTILL:
                chord = speed * elapsed
                direction = tractor.T_i_j[:3, 3] / max(np.linalg.norm(tractor.T_i_j[:3, 3]), 1e-12)
                if tractor.status is MotionStatus.TOO_FEW_TRACKS:
                    direction = np.array([1.0, 0.0, 0.0])
                T_i_j = tractor.T_i_j.copy()
                T_i_j[:3, 3] = direction * chord
                tractor = TractorMotion(T_i_j, tractor.status, tractor.estimate, tractor.shared_tracks)
            published += self._add_keyframe(frame, tractor, elapsed, replay=True)
        if self._deferring:
            published += self._publish_start_if_observed()
        return published

    def _publish_start_if_observed(self) -> list[KeyframeEstimate]:
        """With ``output.publish: latest``, the start's keyframes (the scale bootstrap's, and those
        after it while the hitch is not yet observed) wait until the newest keyframe's hitch sigma
        is at most ``output.latest_start_hitch_sigma_deg``, or at most ``smoother.lag_s`` after the
        bootstrap's end (latest output lags by no more than the window): then the window is
        published with its estimate (:meth:`ArticulatedSmoother.publish_window`) and publication is
        causal from there on; until then keyframes are published as they leave the window (lagged).
        A standing start measures the hitch only as it drives off: at the end of the bootstrap (a
        reversing start parked at -35 deg: after 0.17 m) the window's hitch was 3 deg off with a
        sigma of 8.5 deg, honest but no use for a jack-knife warning; 1.5 s later it is known to a
        degree (DESIGN 11, "The hitch is held at a standstill"). Without a hitch sigma (no trailer,
        mode separate, marginals off) or with the threshold null: at once. Returns what it published."""
        threshold = self.config.output.latest_start_hitch_sigma_deg
        window = self.smoother.window_indices()
        sigma = self.smoother.hitch_sigma(window[-1]) if window else None
        if threshold is not None and sigma is not None and sigma > np.radians(threshold):
            waited = self._last_keyframe.timestamp - self._deferred_since
            if waited < self.config.smoother.lag_s:
                return []
            logger.info("frame %d: hitch angle not measured to %.1f deg within the lag (sigma %.1f deg): latest publication starts",
                        self._last_keyframe.frame, threshold, np.degrees(sigma))
        return self._publish_deferred_start()

    def _publish_deferred_start(self) -> list[KeyframeEstimate]:
        """End the start's deferred publication: the window with its current estimate, written and
        returned; causal publication from here on."""
        self._deferring = False
        published = self.smoother.publish_window()
        self._after_publish(published)
        return published

    def finish(self) -> list[KeyframeEstimate]:
        """End of the stream: a bootstrap still waiting for scale is replayed with the median of
        the speeds it measured (fewer than ``bootstrap_pairs``), or, with none, publishes nothing
        (no speed is assumed); with ``output.publish: lagged`` the keyframes still in the window
        are published."""
        published: list[KeyframeEstimate] = []
        if self._bootstrapping and len(self._bootstrap) > 1:
            speeds = self._bootstrap_speed_samples()
            if speeds:
                logger.info("stream ended during the scale bootstrap: scale from %d keyframe pairs", len(speeds))
                published += self._replay_bootstrap(float(np.median(speeds)))
            else:
                self._unscaled_frames += len(self._bootstrap)
                logger.warning("stream ended before any metric motion was measured: no poses for its last %d keyframes", len(self._bootstrap))
        if self._deferring:  # the hitch never observed at the start: what the window has
            published += self._publish_deferred_start()
        remaining = self.smoother.flush()
        self._after_publish(remaining)
        wheel_scale = self.smoother.wheel_scale()
        if wheel_scale is not None:
            scale, sigma = wheel_scale
            logger.info("wheel odometry scale calibrated online: %.4f%s (its reading over the true distance)", scale,
                        "" if sigma is None else f" +- {sigma:.4f}")
        return published + remaining

    def _after_publish(self, published: list[KeyframeEstimate]) -> None:
        """Write what the smoother published and update the motion model from its newest keyframes."""
        for estimate in published:
            if self.estimates:
                self._distance += float(np.linalg.norm(estimate.T_world_tractor[:2, 3] - self.estimates[-1].T_world_tractor[:2, 3]))
            self.estimates.append(estimate)
            if self.writer is not None:
                self.writer.write(estimate.timestamp, estimate.T_world_tractor, estimate.T_world_trailer, estimate.hitch_angle, estimate.hitch_sigma)
        window = self.smoother.window_indices()
        if len(window) < 2:
            return
        newest, previous = self.smoother.estimate(window[-1]), self.smoother.estimate(window[-2])
        if newest.hitch_angle is not None:
            self._hitch = newest.hitch_angle
        dt = newest.timestamp - previous.timestamp
        if dt <= 0 or newest.tractor_status == MotionStatus.TOO_FEW_TRACKS.value:
            return
        motion = relative_pose(previous.T_world_tractor, newest.T_world_tractor)
        self._velocity = _velocity_of(motion, dt)
        if newest.T_world_trailer is not None and previous.T_world_trailer is not None:
            self._trailer_velocity = _velocity_of(relative_pose(previous.T_world_trailer, newest.T_world_trailer), dt)

    def run(self, frames: Iterable[FrameObservations], total: int | None = None, progress: bool | None = None,
            on_frame: Callable[[FrameObservations | None, list[KeyframeEstimate]], None] | None = None) -> RunSummary:
        """Process every frame (with a tqdm progress bar if enabled) and summarise the run.
        ``on_frame(frame, published)`` is called after every frame with the estimates it published,
        and once more at the end with ``frame=None`` and the estimates :meth:`finish` published."""
        show = self.config.output.progress if progress is None else progress
        iterator = frames
        bar = None
        if show:
            import sys

            from tqdm import tqdm

            # redrawn at most every 0.2 s on a terminal; every 10 s into a log file (no wall of lines)
            bar = tqdm(frames, total=total, unit="frame", desc=f"odometry ({self.config.mode})", leave=False,
                       mininterval=0.2 if sys.stderr.isatty() else 10.0)
            iterator = bar
        started = time.perf_counter()
        # the backend's numpy work is on small arrays: BLAS threads would only spin, taking the
        # core the frontend's process (or thread) runs on (whole pipeline 5-10 % faster)
        blas_limit = threadpool_limits(limits=1, user_api="blas")
        try:
            for frame in iterator:
                published = self.process(frame)
                if on_frame is not None:
                    on_frame(frame, published)
                if bar is not None and self.estimates:
                    last = self.estimates[-1]
                    bar.set_postfix(kf=len(self.estimates), dist=f"{self._distance:.0f}m", hitch="-" if last.hitch_angle is None else f"{np.degrees(last.hitch_angle):.1f}°",
                                    refresh=False)
            remaining = self.finish()
            if on_frame is not None:
                on_frame(None, remaining)
        except BaseException as error:
            # an error in the source (or Ctrl-C): publish what the window holds, then re-raise
            logger.error("run stopped at frame %d (%s): writing the keyframes still in the window", self._frames, type(error).__name__)
            self._salvage()
            raise
        finally:
            blas_limit.restore_original_limits()
            if bar is not None:
                bar.close()
        return self.summary(time.perf_counter() - started)

    def _salvage(self) -> None:
        """Publish the keyframes still in the smoother's window after an interrupted run."""
        try:
            self._after_publish(self.smoother.publish_window() if self._deferring else self.smoother.flush())
        except Exception as error:  # the run is already failing: keep its error, log this one
            logger.error("could not publish the last window: %s", error)

    def summary(self, seconds: float) -> RunSummary:
        timings = self.smoother.timings
        breakdown = {}
        if timings:
            for name in ("factors", "optimisation", "marginals"):
                breakdown[name] = float(np.median([getattr(t, name) for t in timings]) * 1e3)
        return RunSummary(
            frames=self._frames, keyframes=len(self.estimates), distance_m=self._distance, seconds=seconds,
            seconds_per_frame=seconds / max(self._frames, 1), frames_per_second=self._frames / seconds if seconds > 0 else 0.0,
            backend_ms_median=float(np.median([t.total for t in timings]) * 1e3) if timings else 0.0,
            backend_ms_breakdown=breakdown, backend_cpu_ms_median=float(np.median([t.cpu for t in timings]) * 1e3) if timings else 0.0,
            statuses=dict(self._statuses), mode=self.config.mode, unscaled_keyframes=self._unscaled_frames,
        )


def _first_init() -> MotionInit:
    return MotionInit(np.eye(4), MotionStatus.FIRST)


def run_on_frames(rig: Rig, config: VoConfig, frames: Iterable[FrameObservations], out_dir: str | Path | None = None, total: int | None = None, progress: bool | None = None,
                  wheel_odometry: Callable[[float, float], float] | None = None,
                  on_frame: Callable[[FrameObservations | None, list[KeyframeEstimate]], None] | None = None,
                  source_seconds: list[float] | None = None, dataset: str | Path | None = None) -> tuple[RunSummary, list[KeyframeEstimate]]:
    """Run the pipeline on any source of frames; with ``out_dir``, write the outputs incrementally,
    ``timing.json`` and the config used (``config.yaml``) into it as one run
    (:class:`~ampc_vo.io.run_folder.RunFolder`: locked, earlier files removed, provenance in
    ``run.json``). ``on_frame``: see :meth:`OdometryPipeline.run`; ``source_seconds``: time spent
    producing each frame (the frontend), filled while ``frames`` is consumed, added to the timing
    breakdown; ``dataset``: the folder the frames come from, recorded in the summary.

    A run that published no pose raises :class:`~ampc_vo.errors.NothingMeasuredError` at the end
    (after ``timing.json``): nothing was measured, and no motion is made up.
    """
    with_trailer = rig.has_trailer and config.mode != "tractor_only"
    if out_dir is None:
        pipeline = OdometryPipeline(rig, config, wheel_odometry=wheel_odometry)
        summary = _with_source(pipeline.run(frames, total, progress, on_frame), source_seconds, dataset)
        _require_measured(summary)
        return summary, pipeline.estimates
    with RunFolder(out_dir, dataset=dataset) as run, OutputWriter(out_dir, with_trailer=with_trailer, run=run) as writer:
        run.write_text(CONFIG_FILE, run.tag + "\n" + config_yaml(config))
        pipeline = OdometryPipeline(rig, config, writer, wheel_odometry=wheel_odometry)
        summary = dataclasses.replace(_with_source(pipeline.run(frames, total, progress, on_frame), source_seconds, dataset), run_id=run.run_id)
        if config.output.write_timing:
            run.write_text(TIMING_FILE, json.dumps(asdict(summary), indent=2) + "\n")
        _require_measured(summary)
    return summary, pipeline.estimates


def _require_measured(summary: RunSummary) -> None:
    """:class:`NothingMeasuredError` for a run that published no keyframe (issue 14); a warning
    when some keyframes had too few tracks (their motion is the constant-velocity prediction)."""
    predicted = summary.statuses.get(MotionStatus.TOO_FEW_TRACKS.value, 0)
    if summary.keyframes and predicted:
        logger.warning("%d of %d keyframes had too few tracks: their motion is the constant-velocity prediction, not a measurement "
                       "(keyframe statuses in timing.json)", predicted, summary.keyframes)
    if summary.keyframes:
        return
    if summary.frames < 2:
        raise NothingMeasuredError(f"{summary.frames} frame(s): motion needs at least 2; no poses written")
    raise NothingMeasuredError(f"no motion measured in {summary.frames} frames (nothing to track: blank or featureless images, "
                               "or standing still, or no metric scale observed); no poses written")


def _with_source(summary: RunSummary, source_seconds: list[float] | None, dataset: str | Path | None) -> RunSummary:
    """``summary`` with the dataset folder and the median time per frame of the measurement source
    as ``frontend`` (ms)."""
    if dataset is not None:
        summary = dataclasses.replace(summary, dataset=str(Path(dataset).resolve()))
    if not source_seconds:
        return summary
    breakdown = {"frontend": float(np.median(source_seconds) * 1e3), **summary.backend_ms_breakdown}
    return dataclasses.replace(summary, backend_ms_breakdown=breakdown)
