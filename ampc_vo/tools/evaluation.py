"""Accuracy of an odometry run against ground truth, with evo (DESIGN section 7), and its plot.

Metrics (issue 5, written to ``metrics.json``):

* ``tractor_ate_m``: RMSE of tractor positions after an SE(3) (Umeyama, no scale) alignment of the
  estimate to the truth; our scale is metric, so scale errors count.
* ``tractor_ate_sim3_m``: the same after a Sim(3) alignment (scale corrected): shape error only.
* ``trailer_ate_m``: RMSE of the trailer's axle midpoint (``GroundTruth.trailer_axle_x``; the
  body origin is the hitch, shared with the tractor, so it would only repeat the tractor's error)
  after applying the **tractor's** SE(3) alignment (both bodies share the estimated world frame,
  so the trailer is not aligned on its own).
* ``tractor_rpe_percent``: mean translation error of the relative tractor motion over segments of
  10 m of ground-truth path, divided by the segment length, in percent (KITTI-style drift).
* ``tractor_rotation_drift_deg_per_100m``: mean rotation error (angle of ``R_err``, all axes) of
  the relative tractor motion over segments of 100 m of ground-truth path (KITTI's rotational
  drift). The ATE's SE(3) alignment can hide a drift in pitch (it tilts the whole estimate to fit
  the truth): the realistic motorway's estimate once pitched 0.6 deg per 100 m at 0.75 % ATE.
* ``hitch_rmse_deg`` / ``hitch_max_deg``: error of the hitch angle (wrapped difference).
* ``hitch_cornering_rmse_deg`` / ``hitch_cornering_within_2sigma``: the same and the share within
  2 sigma over the keyframes where the truth corners at ``|a| >= CORNERING_MPS2`` (the lateral
  acceleration ``a = |v| yaw rate`` of the tractor, :func:`lateral_accelerations`); ``None`` with
  fewer than ``_LEAST_CORNERING`` such keyframes.
* ``hitch_error_per_lateral_acceleration``: slope (deg per m/s^2) of the least-squares line of the
  signed hitch error over ``a`` on the keyframes where the truck moves: a hitch that follows an
  unmodelled tyre slip (its angle grows with ``a``, outward) errs in proportion to ``a``, which the
  RMSE mixes with everything else (the fast motorway check world on images: +0.44 deg per m/s^2).
* ``seconds_per_frame``: wall time per input frame of the run (from ``timing.json`` or given).

Estimates may be sparser than the truth (keyframes only): they are associated by timestamp.
Values that cannot be computed (too short a run, no trailer) are ``None`` (``null`` in JSON).
"""
from __future__ import annotations

import copy
import json
import logging
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from evo.core import filters, lie_algebra, metrics, sync
from evo.core.geometry import GeometryException
from evo.core.trajectory import PoseTrajectory3D

from ampc_vo.errors import AmpcError, DatasetError, OutputError, WriteError
from ampc_vo.geometry import wrap_angle, yaws_of
from ampc_vo.io.groundtruth import GroundTruth
from ampc_vo.io.outputs import HITCH_FILE, TRACTOR_FILE, TRAILER_FILE, HitchSeries, Trajectory, read_hitch, read_tum
from ampc_vo.io.run_folder import METRICS_FILE, PLOT_FILE, TIMING_FILE, FolderClaim, check_run_files

logger = logging.getLogger(__name__)

RPE_SEGMENT_M = 10.0
ROTATION_DRIFT_SEGMENT_M = 100.0
CORNERING_MPS2 = 0.5        # lateral acceleration (m/s^2) from which a keyframe counts as cornering
_LEAST_CORNERING = 10       # keyframes needed for the cornering figures and the slope
_MOVING_MPS = 1.0           # the slope's keyframes: the truck moves at least this fast (m/s)
_LEAST_SPREAD_MPS2 = 0.1    # ... and their lateral accelerations spread at least this much (std)


@dataclass(frozen=True)
class Metrics:
    """The numbers of ``metrics.json`` (issue 5); ``None`` when not computable."""

    frames: int
    distance_m: float
    tractor_ate_m: float
    tractor_ate_sim3_m: float
    trailer_ate_m: float | None
    tractor_rpe_percent: float | None
    hitch_rmse_deg: float | None
    hitch_max_deg: float | None
    seconds_per_frame: float | None
    sim3_scale: float = 1.0
    # honesty of the published hitch sigma: shares of keyframes whose error is within 2 and 3
    # sigma (a Gaussian: 95.4 % and 99.7 %), and the median sigma
    hitch_within_2sigma: float | None = None
    hitch_within_3sigma: float | None = None
    hitch_sigma_median_deg: float | None = None
    tractor_rotation_drift_deg_per_100m: float | None = None
    hitch_cornering_rmse_deg: float | None = None
    hitch_cornering_within_2sigma: float | None = None
    hitch_error_per_lateral_acceleration: float | None = None

    def to_dict(self) -> dict:
        return {key: _json_number(value) for key, value in asdict(self).items()}

    def table(self) -> str:
        """A two-column text table (used by ``scripts/evaluate.py``)."""
        rows = []
        for key, value in self.to_dict().items():
            text = "-" if value is None else (f"{value:d}" if isinstance(value, int) else f"{value:.4g}")
            rows.append(f"{key:<22s} {text:>12s}")
        return "\n".join(rows)


@dataclass
class Evaluation:
    """Metrics plus the aligned series used by :func:`plot_evaluation`."""

    metrics: Metrics
    tractor_estimate_xy: np.ndarray
    tractor_truth_xy: np.ndarray
    trailer_estimate_xy: np.ndarray | None = None
    trailer_truth_xy: np.ndarray | None = None
    hitch_timestamps: np.ndarray | None = None
    hitch_estimate: np.ndarray | None = None
    hitch_sigma: np.ndarray | None = None
    hitch_truth_timestamps: np.ndarray | None = None
    hitch_truth: np.ndarray | None = None
    extra: dict = field(default_factory=dict)


def _json_number(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _evo_trajectory(timestamps: np.ndarray, poses: np.ndarray) -> PoseTrajectory3D:
    return PoseTrajectory3D(poses_se3=[np.asarray(pose, dtype=float) for pose in poses], timestamps=np.asarray(timestamps, dtype=float))


def _path_length(positions: np.ndarray) -> float:
    if len(positions) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(positions, axis=0), axis=1)))


def _associate(truth: PoseTrajectory3D, estimate: PoseTrajectory3D, max_diff: float) -> tuple[PoseTrajectory3D, PoseTrajectory3D]:
    try:
        return sync.associate_trajectories(truth, estimate, max_diff=max_diff)
    except sync.SyncException as error:
        raise AmpcError(f"cannot associate estimate with ground truth by timestamp: {error}") from None


def _aligned(estimate: PoseTrajectory3D, truth: PoseTrajectory3D, correct_scale: bool) -> tuple[PoseTrajectory3D, np.ndarray, np.ndarray, float]:
    """A copy of ``estimate`` aligned to ``truth`` (Umeyama; SE(3) or Sim(3)) and the alignment.

    Collinear positions (straight driving) make Umeyama degenerate: then the first poses are
    aligned instead (``align_origin``), with a warning.
    """
    aligned = copy.deepcopy(estimate)
    try:
        rotation, translation, scale = aligned.align(truth, correct_scale=correct_scale)
    except GeometryException:
        logger.warning("positions are collinear: Umeyama alignment degenerate, aligning the first poses instead")
        aligned = copy.deepcopy(estimate)
        transform = aligned.align_origin(truth)
        rotation, translation, scale = transform[:3, :3], transform[:3, 3], 1.0
    return aligned, rotation, translation, float(scale)


def _ape_rmse(truth: PoseTrajectory3D, estimate: PoseTrajectory3D) -> float:
    metric = metrics.APE(metrics.PoseRelation.translation_part)
    metric.process_data((truth, estimate))
    return float(metric.get_statistic(metrics.StatisticsType.rmse))


def _mean_segment_error(truth: PoseTrajectory3D, estimate: PoseTrajectory3D, relation: "metrics.PoseRelation", segment_m: float) -> float | None:
    """Mean evo RPE error of ``relation`` over ``segment_m`` segments of the truth's path (pairs
    chosen on the ground truth, ``pairs_from_reference``, so that a scale error of the estimate
    does not change which pairs are compared); ``None`` when the run is too short or too sparse."""
    metric = metrics.RPE(relation, delta=segment_m, delta_unit=metrics.Unit.meters, all_pairs=True, pairs_from_reference=True)
    try:
        metric.process_data((truth, estimate))
    except (metrics.MetricsException, filters.FilterException) as error:  # too few poses (sparse run) for the segments
        logger.warning("RPE over %g m not computable from %d poses (too sparse for the segment length): %s", segment_m, truth.num_poses, error)
        return None
    return float(np.mean(metric.error))


def relative_pose_error_percent(truth: PoseTrajectory3D, estimate: PoseTrajectory3D, segment_m: float = RPE_SEGMENT_M) -> float | None:
    """Mean translation error over ``segment_m`` segments of the truth's path, in percent of it
    (:func:`_mean_segment_error`). ``None`` when the run is shorter."""
    if _path_length(truth.positions_xyz) < segment_m * 0.9:
        return None
    error = _mean_segment_error(truth, estimate, metrics.PoseRelation.translation_part, segment_m)
    return None if error is None else error / segment_m * 100.0


def rotation_drift_deg_per_100m(truth: PoseTrajectory3D, estimate: PoseTrajectory3D, segment_m: float = ROTATION_DRIFT_SEGMENT_M) -> float | None:
    """Mean rotation angle error (degrees) of the relative motion over ``segment_m`` segments of
    the truth's path, per 100 m (:func:`_mean_segment_error`). ``None`` when the run is shorter
    than a segment."""
    if _path_length(truth.positions_xyz) < segment_m:
        return None
    error = _mean_segment_error(truth, estimate, metrics.PoseRelation.rotation_angle_deg, segment_m)
    return None if error is None else error / segment_m * 100.0


def hitch_errors(estimate: HitchSeries, truth_timestamps: np.ndarray, truth_angles: np.ndarray, max_diff: float) -> np.ndarray:
    """Wrapped errors (radians) of the estimates that have a truth sample within ``max_diff`` s."""
    return hitch_matches(estimate, truth_timestamps, truth_angles, max_diff)[0]


def sigma_coverage(errors: np.ndarray, sigmas: np.ndarray, factor: float) -> float | None:
    """Share of estimates whose |error| is at most ``factor`` times their published 1-sigma
    (an infinite sigma covers anything; a NaN sigma covers nothing)."""
    if not errors.size:
        return None
    with np.errstate(invalid="ignore"):
        return float(np.mean(np.abs(errors) <= factor * sigmas))


def hitch_matches(estimate: HitchSeries, truth_timestamps: np.ndarray, truth_angles: np.ndarray, max_diff: float) -> tuple[np.ndarray, np.ndarray]:
    """``(errors, matched)``: wrapped errors (radians) of the estimates with a truth sample within
    ``max_diff`` s, and the boolean mask of those estimates."""
    order = np.argsort(truth_timestamps)
    sorted_times = truth_timestamps[order]
    index = np.clip(np.searchsorted(sorted_times, estimate.timestamps), 1, max(len(sorted_times) - 1, 1))
    left = np.clip(index - 1, 0, len(sorted_times) - 1)
    right = np.clip(index, 0, len(sorted_times) - 1)
    nearest = np.where(np.abs(sorted_times[left] - estimate.timestamps) <= np.abs(sorted_times[right] - estimate.timestamps), left, right)
    matched = np.abs(sorted_times[nearest] - estimate.timestamps) <= max_diff
    return np.asarray(wrap_angle(estimate.angles[matched] - truth_angles[order][nearest[matched]]), dtype=float), matched


def lateral_accelerations(timestamps: np.ndarray, T_world_tractor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(a, speed)`` (N,) of the tractor at each truth sample: its lateral acceleration ``|v| yaw
    rate`` (m/s^2, positive turning left, by central differences of the horizontal path and the
    unwrapped yaw) and its speed (m/s); zeros for fewer than 3 samples."""
    if len(timestamps) < 3:
        return np.zeros(len(timestamps)), np.zeros(len(timestamps))
    positions = T_world_tractor[:, :2, 3]
    velocity = np.gradient(positions, timestamps, axis=0)
    yaw = np.unwrap(yaws_of(T_world_tractor))
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    return speed * np.gradient(yaw, timestamps), speed


def cornering_figures(errors: np.ndarray, sigmas: np.ndarray, lateral: np.ndarray, speed: np.ndarray) -> tuple[float | None, float | None, float | None]:
    """``(RMSE deg, share within 2 sigma, slope deg per m/s^2)`` of hitch ``errors`` (radians) with
    their ``sigmas`` at keyframes of lateral acceleration ``lateral`` and ``speed`` (module
    docstring; ``None`` where too few keyframes qualify)."""
    cornering = np.abs(lateral) >= CORNERING_MPS2
    rmse = within = slope = None
    if np.count_nonzero(cornering) >= _LEAST_CORNERING:
        rmse = float(np.degrees(np.sqrt(np.mean(errors[cornering] ** 2))))
        within = sigma_coverage(errors[cornering], sigmas[cornering], 2.0)
    moving = speed >= _MOVING_MPS
    if np.count_nonzero(moving) >= _LEAST_CORNERING and np.std(lateral[moving]) >= _LEAST_SPREAD_MPS2:
        slope = float(np.degrees(np.polyfit(lateral[moving], errors[moving], 1)[0]))
    return rmse, within, slope


def evaluate(
    truth: GroundTruth,
    tractor: Trajectory,
    trailer: Trajectory | None = None,
    hitch: HitchSeries | None = None,
    seconds_per_frame: float | None = None,
    max_time_diff: float = 0.01,
) -> Evaluation:
    """Compute :class:`Metrics` of an estimate against ground truth (see module docstring)."""
    if len(tractor) < 2:
        raise AmpcError(f"need at least 2 tractor poses to evaluate, got {len(tractor)}")
    reference = np.eye(4) if truth.T_tractor_reference is None else np.asarray(truth.T_tractor_reference, dtype=float)
    truth_tractor = _evo_trajectory(truth.timestamps, truth.T_world_tractor @ reference)
    ref, est = _associate(truth_tractor, _evo_trajectory(tractor.timestamps, tractor.poses @ reference), max_time_diff)
    if ref.num_poses < 2:
        raise AmpcError(f"only {ref.num_poses} estimated poses match ground-truth timestamps (max_diff {max_time_diff} s)")
    est_se3, rotation, translation, _ = _aligned(est, ref, correct_scale=False)
    tractor_ate = _ape_rmse(ref, est_se3)
    est_sim3, _, _, scale = _aligned(est, ref, correct_scale=True)
    tractor_ate_sim3 = _ape_rmse(ref, est_sim3)
    rpe = relative_pose_error_percent(ref, est)
    rotation_drift = rotation_drift_deg_per_100m(ref, est)

    trailer_ate = None
    trailer_est_xy = trailer_truth_xy = None
    if trailer is not None and len(trailer) >= 2 and truth.T_world_trailer is not None:
        lever = np.eye(4)
        lever[0, 3] = truth.trailer_axle_x
        trailer_ref, trailer_est = _associate(_evo_trajectory(truth.timestamps, truth.T_world_trailer @ lever), _evo_trajectory(trailer.timestamps, trailer.poses @ lever), max_time_diff)
        trailer_est.transform(lie_algebra.se3(rotation, translation))
        trailer_ate = _ape_rmse(trailer_ref, trailer_est)
        trailer_est_xy, trailer_truth_xy = trailer_est.positions_xyz[:, :2], trailer_ref.positions_xyz[:, :2]

    hitch_rmse = hitch_max = within_2 = within_3 = sigma_median = None
    cornering_rmse = cornering_within = slope = None
    if hitch is not None and len(hitch) > 0 and truth.hitch_angles is not None:
        errors, matched = hitch_matches(hitch, truth.timestamps, truth.hitch_angles, max_time_diff)
        if errors.size:
            hitch_rmse = float(np.degrees(np.sqrt(np.mean(errors**2))))
            hitch_max = float(np.degrees(np.max(np.abs(errors))))
            sigmas = hitch.sigmas[matched]
            within_2, within_3 = sigma_coverage(errors, sigmas, 2.0), sigma_coverage(errors, sigmas, 3.0)
            sigma_median = float(np.degrees(np.median(sigmas)))
            lateral, speed = lateral_accelerations(truth.timestamps, truth.T_world_tractor)
            order = np.argsort(truth.timestamps)
            at = hitch.timestamps[matched]
            cornering_rmse, cornering_within, slope = cornering_figures(
                errors, sigmas, np.interp(at, truth.timestamps[order], lateral[order]), np.interp(at, truth.timestamps[order], speed[order]))

    result = Metrics(
        frames=int(ref.num_poses),
        distance_m=_path_length(ref.positions_xyz),
        tractor_ate_m=tractor_ate,
        tractor_ate_sim3_m=tractor_ate_sim3,
        trailer_ate_m=trailer_ate,
        tractor_rpe_percent=rpe,
        hitch_rmse_deg=hitch_rmse,
        hitch_max_deg=hitch_max,
        seconds_per_frame=None if seconds_per_frame is None else float(seconds_per_frame),
        sim3_scale=float(scale),
        hitch_within_2sigma=within_2,
        hitch_within_3sigma=within_3,
        hitch_sigma_median_deg=sigma_median,
        tractor_rotation_drift_deg_per_100m=rotation_drift,
        hitch_cornering_rmse_deg=cornering_rmse,
        hitch_cornering_within_2sigma=cornering_within,
        hitch_error_per_lateral_acceleration=slope,
    )
    return Evaluation(
        metrics=result,
        tractor_estimate_xy=est_se3.positions_xyz[:, :2],
        tractor_truth_xy=ref.positions_xyz[:, :2],
        trailer_estimate_xy=trailer_est_xy,
        trailer_truth_xy=trailer_truth_xy,
        hitch_timestamps=None if hitch is None else hitch.timestamps,
        hitch_estimate=None if hitch is None else hitch.angles,
        hitch_sigma=None if hitch is None else hitch.sigmas,
        hitch_truth_timestamps=truth.timestamps if truth.hitch_angles is not None else None,
        hitch_truth=truth.hitch_angles,
    )


# ---------------------------------------------------------------------- files
def _read_timing(output_dir: str | Path, key: str) -> object:
    """One entry of ``OUT/timing.json`` (the run summary the pipeline writes), or ``None`` when the
    file or the entry is absent or unreadable (logged)."""
    path = Path(output_dir) / TIMING_FILE
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8")).get(key)
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError) as error:
        logger.warning("%s: unreadable timing file (%s)", path, error)
        return None


def read_seconds_per_frame(output_dir: str | Path) -> float | None:
    """``seconds_per_frame`` from ``OUT/timing.json`` (written by the pipeline), or ``None``."""
    value = _read_timing(output_dir, "seconds_per_frame")
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        logger.warning("%s: unreadable timing file (seconds_per_frame %r is not a number)", Path(output_dir) / TIMING_FILE, value)
        return None


def require_run_dataset(output_dir: str | Path, dataset_dir: str | Path) -> None:
    """:class:`~ampc_vo.errors.OutputError` when the run in ``output_dir`` read another dataset
    folder than ``dataset_dir`` (``run.json``, else ``timing.json``): nothing is evaluated or written."""
    from ampc_vo.io.run_folder import read_run

    record = read_run(output_dir)
    recorded = record.dataset if record is not None and record.dataset else _read_timing(output_dir, "dataset")
    if isinstance(recorded, str) and Path(recorded).resolve() != Path(dataset_dir).resolve():
        raise OutputError(f"{output_dir}: the run read {recorded}, not {Path(dataset_dir).resolve()}: "
                          "evaluating it against another sequence's ground truth would give wrong metrics (nothing written)")


RUN_OUTPUTS = (TRACTOR_FILE, TRAILER_FILE, HITCH_FILE, TIMING_FILE)


def evaluate_output(output_dir: str | Path, truth: GroundTruth, seconds_per_frame: float | None = None, max_time_diff: float = 0.01) -> Evaluation:
    """Evaluate the files of an odometry run in ``output_dir`` (DESIGN section 5): only files the
    run recorded in its ``run.json`` are read (:func:`~ampc_vo.io.run_folder.check_run_files`:
    a stale file of another run is an :class:`~ampc_vo.errors.OutputError`, as is a run still writing)."""
    output_dir = Path(output_dir)
    files = check_run_files(output_dir, RUN_OUTPUTS).present
    if TRACTOR_FILE not in files:
        raise DatasetError(f"{output_dir}: no {TRACTOR_FILE}; is this an odometry output folder?")
    tractor = read_tum(files[TRACTOR_FILE])
    trailer = read_tum(files[TRAILER_FILE]) if TRAILER_FILE in files else None
    hitch = read_hitch(files[HITCH_FILE]) if HITCH_FILE in files else None
    if seconds_per_frame is None and TIMING_FILE in files:
        seconds_per_frame = read_seconds_per_frame(output_dir)
    return evaluate(truth, tractor, trailer, hitch, seconds_per_frame, max_time_diff)


def evaluate_run_folder(output_dir: str | Path, truth: GroundTruth, seconds_per_frame: float | None = None, max_time_diff: float = 0.01,
                        title: str = "", plot: bool = True) -> tuple[Evaluation, list[Path]]:
    """Evaluate the run in ``output_dir`` and write ``metrics.json`` (with the run's id) and, with
    ``plot``, ``evaluation.png`` there, holding the folder's lock meanwhile; returns the evaluation
    and the files written."""
    output_dir = Path(output_dir)
    evaluation = evaluate_output(output_dir, truth, seconds_per_frame, max_time_diff)
    with FolderClaim(output_dir) as claim:
        written = [claim.path(METRICS_FILE)]
        write_metrics(evaluation.metrics, written[0], run_id=claim.run_id)
        if plot:
            written.append(claim.path(PLOT_FILE))
            plot_evaluation(evaluation, written[-1], title=title or str(output_dir))
    return evaluation, written


def write_metrics(metrics_result: Metrics, path: str | Path, run_id: str | None = None) -> None:
    """Write ``metrics.json`` (non-finite values as ``null``; ``run_id``: the run evaluated)."""
    data = metrics_result.to_dict() | ({} if run_id is None else {"run_id": run_id})
    try:
        Path(path).write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    except OSError as error:
        raise WriteError(f"{path}: cannot write ({error.strerror or error})") from None


def plot_evaluation(evaluation: Evaluation, path: str | Path, title: str = "") -> None:
    """PNG with the top view (estimate vs truth, tractor and trailer) and the hitch angle over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    has_hitch = evaluation.hitch_estimate is not None and evaluation.hitch_truth is not None
    figure, axes = plt.subplots(1, 2 if has_hitch else 1, figsize=(13 if has_hitch else 7, 5.5), squeeze=False)
    top = axes[0, 0]
    top.plot(*evaluation.tractor_truth_xy.T, color="black", lw=1.5, label="tractor truth")
    top.plot(*evaluation.tractor_estimate_xy.T, color="tab:blue", lw=1.0, ls="--", label="tractor estimate")
    if evaluation.trailer_estimate_xy is not None:
        top.plot(*evaluation.trailer_truth_xy.T, color="gray", lw=1.5, label="trailer truth")
        top.plot(*evaluation.trailer_estimate_xy.T, color="tab:orange", lw=1.0, ls="--", label="trailer estimate")
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    m = evaluation.metrics
    top.set_title(f"top view (SE(3)-aligned)  ATE {m.tractor_ate_m:.3f} m over {m.distance_m:.0f} m")
    top.legend(loc="best", fontsize=8)
    top.grid(alpha=0.3)
    if has_hitch:
        hitch_axis = axes[0, 1]
        hitch_axis.plot(evaluation.hitch_truth_timestamps, np.degrees(evaluation.hitch_truth), color="black", lw=1.5, label="truth")
        angle = np.degrees(evaluation.hitch_estimate)
        sigma = np.degrees(np.nan_to_num(evaluation.hitch_sigma, nan=0.0))
        hitch_axis.plot(evaluation.hitch_timestamps, angle, color="tab:red", lw=1.0, label="estimate")
        hitch_axis.fill_between(evaluation.hitch_timestamps, angle - sigma, angle + sigma, color="tab:red", alpha=0.25, label="±1σ")
        rmse = "-" if m.hitch_rmse_deg is None else f"{m.hitch_rmse_deg:.3f}°"
        hitch_axis.set_title(f"hitch angle  RMSE {rmse}")
        hitch_axis.set_xlabel("time [s]")
        hitch_axis.set_ylabel("hitch angle [deg]")
        hitch_axis.legend(loc="best", fontsize=8)
        hitch_axis.grid(alpha=0.3)
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
