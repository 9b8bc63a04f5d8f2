"""A fleet of logs (issue 15): the odometry on many recordings (or dataset folders), each into
``OUT/<log name>/``, with ``OUT/summary.csv`` (one row per log: frames, distance, frames/s, status,
and the metrics where ground truth exists: a pose topic of each log or a ``<log name>.tum`` beside
it, with ``<log name>.hitch.csv`` beside it for the hitch angle; a dataset folder's own ground truth).

Each log is one :class:`BatchJob`, run by :func:`run_job` in a worker: local worker processes by
default (``concurrent.futures`` with spawned processes), or the tasks of a Ray cluster
(:func:`run_batch` ``ray_address``: ``ray.init(address)``; ``"local"`` starts a local cluster of
``workers`` CPUs; the optional extra ``pip install ampc-vo[fleet]``). On a cluster every node needs
ampc-vo installed and the logs, rig and ``OUT`` at the same paths (shared storage). A log's row is
also written to ``OUT/<log name>/summary.json`` when it is done: a rerun skips the logs whose run
succeeded and retries the failed ones. A failing log (corrupt file, missing topic, a crash inside
the run) gets status ``failed: <reason>`` and the others go on. Inside a worker the frontend runs in
a thread (``frontend_worker: thread``): the batch already keeps the cores busy with one log each.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import logging
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

logger = logging.getLogger(__name__)

SUMMARY_FILE = "summary.csv"
JOB_SUMMARY_FILE = "summary.json"
SUMMARY_COLUMNS = ("log", "frames", "distance_m", "frames_per_second", "status", "tractor_ate_m", "trailer_ate_m", "hitch_rmse_deg",
                   "tractor_rpe_percent")
OK = "ok"


@dataclass(frozen=True)
class BatchJob:
    """One log of a batch: where it is, the rig and VO config it runs with, where its outputs go,
    and its ground truth (a pose topic of the log and, optionally, a hitch-angle CSV)."""

    log: str
    out: str
    rig: str | None = None
    config: str | None = None
    groundtruth_topic: str | None = None
    hitch_csv: str | None = None
    groundtruth_tum: str | None = None

    @property
    def name(self) -> str:
        from ampc_vo.io.bags import log_name

        return log_name(self.log)


def _truth(job: BatchJob, sequence: object, out: Path):
    """The ground truth of a job: the pose topic (resampled at the estimate's times), else that of a
    dataset folder (``Sequence.truth``), else ``None``."""
    if job.groundtruth_topic is None and job.groundtruth_tum is None:
        return sequence.truth
    from ampc_vo.io.groundtruth_log import load_log_groundtruth, truth_at
    from ampc_vo.io.outputs import TRACTOR_FILE, read_tum

    axle_x = sequence.rig.axle_x("trailer") if sequence.rig.has_trailer else 0.0
    source = job.log if job.groundtruth_topic is not None else job.groundtruth_tum
    truth = load_log_groundtruth(source, job.groundtruth_topic, job.hitch_csv, axle_x)
    return truth_at(truth, read_tum(out / TRACTOR_FILE).timestamps)


def run_job(job: BatchJob) -> dict:
    """Run one log (module docstring) and return its summary row; never raises."""
    out = Path(job.out)
    row: dict = {"log": job.name, "frames": 0, "distance_m": None, "frames_per_second": None, "status": OK}
    try:
        from ampc_vo.config import load_config
        from ampc_vo.frontend.sources import default_config_path, open_sequence
        from ampc_vo.tools.evaluation import METRICS_FILE, evaluate_output, write_metrics
        from ampc_vo.tools.runner import run_sequence

        config = load_config(job.config if job.config is not None else default_config_path(job.log))
        config = dataclasses.replace(config, frontend_worker="thread")
        sequence = open_sequence(job.log, config, rig=job.rig, progress=False)
        summary, _ = run_sequence(sequence, config, out, progress=False)
        row.update(frames=summary.frames, distance_m=round(summary.distance_m, 3), frames_per_second=round(summary.frames_per_second, 2))
        truth = _truth(job, sequence, out)
        if truth is not None:
            metrics = evaluate_output(out, truth).metrics
            write_metrics(metrics, out / METRICS_FILE)
            row.update(tractor_ate_m=metrics.tractor_ate_m, trailer_ate_m=metrics.trailer_ate_m, hitch_rmse_deg=metrics.hitch_rmse_deg,
                       tractor_rpe_percent=metrics.tractor_rpe_percent)
    except Exception as error:  # one log's failure is reported, the batch goes on
        from ampc_vo.errors import AmpcError, first_line

        reason = first_line(error)
        if not isinstance(error, AmpcError) and reason != type(error).__name__:
            reason = f"{type(error).__name__}: {reason}"
        row["status"] = f"failed: {reason}"
        if not isinstance(error, AmpcError):
            logger.error("%s: %s", job.log, traceback.format_exc())
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / JOB_SUMMARY_FILE).write_text(json.dumps(row, indent=1), encoding="utf-8")
    except OSError as error:
        row["status"] = f"failed: cannot write {out / JOB_SUMMARY_FILE} ({error.strerror or error})"
    return row


def finished_row(job: BatchJob) -> dict | None:
    """The summary row of a job that already succeeded (``OUT/<log name>/summary.json``), else None."""
    path = Path(job.out) / JOB_SUMMARY_FILE
    try:
        row = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return row if isinstance(row, dict) and row.get("status") == OK else None


def sidecar(log: str | Path, suffix: str) -> Path | None:
    """``<log name><suffix>`` beside the log (``drive_03.bag`` -> ``drive_03.hitch.csv``), if it exists."""
    from ampc_vo.io.bags import log_name

    path = Path(log).parent / f"{log_name(log)}{suffix}"
    return path if path.is_file() else None


def make_jobs(logs: Iterable[str | Path], out: str | Path, rig: str | Path | None = None, config: str | Path | None = None,
              groundtruth_topic: str | None = None) -> list[BatchJob]:
    """One job per log into ``out/<log name>``; two logs of one name are a :class:`ConfigError`.
    Ground truth: ``groundtruth_topic`` in each log or a TUM file ``<log name>.tum`` beside it, and
    the hitch angle from ``<log name>.hitch.csv`` beside it when there is one."""
    from ampc_vo.errors import ConfigError
    from ampc_vo.io.bags import log_name

    out = Path(out)
    jobs, names = [], {}
    for log in logs:
        name = log_name(log)
        if name in names:
            raise ConfigError(f"logs {names[name]} and {log} have the same name {name!r}: their outputs would collide in {out / name}")
        names[name] = log
        hitch_csv, tum = sidecar(log, ".hitch.csv"), sidecar(log, ".tum")
        jobs.append(BatchJob(str(Path(log).resolve()), str((out / name).resolve()), None if rig is None else str(Path(rig).resolve()),
                             None if config is None else str(Path(config).resolve()), groundtruth_topic,
                             None if hitch_csv is None else str(hitch_csv.resolve()), None if tum is None else str(tum.resolve())))
    return jobs


def _run_local(jobs: list[BatchJob], workers: int, on_done: Callable[[int, dict], None]) -> None:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    if workers <= 1:
        for index, job in enumerate(jobs):
            on_done(index, run_job(job))
        return
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(run_job, job): index for index, job in enumerate(jobs)}
        for future in as_completed(futures):
            index = futures[future]
            try:
                row = future.result()
            except Exception as error:  # the worker process died (out of memory, segfault)
                row = {"log": jobs[index].name, "frames": 0, "status": f"failed: worker died ({type(error).__name__}: {error})"}
            on_done(index, row)


def _run_ray(jobs: list[BatchJob], address: str, workers: int, on_done: Callable[[int, dict], None]) -> None:
    """The jobs as Ray tasks (one CPU each) on the cluster at ``address`` (``local``: a local
    cluster of ``workers`` CPUs)."""
    try:
        import ray
    except ImportError:
        from ampc_vo.errors import ConfigError

        raise ConfigError("--ray needs Ray: pip install 'ampc-vo[fleet]' (or pip install 'ray[default]')") from None
    started_here = not ray.is_initialized()
    if started_here:
        if address == "local":
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(run_job)
        pending = {task.remote(job): index for index, job in enumerate(jobs)}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            index = pending.pop(done[0])
            try:
                row = ray.get(done[0])
            except Exception as error:  # the task's worker died
                row = {"log": jobs[index].name, "frames": 0, "status": f"failed: Ray task died ({type(error).__name__})"}
            on_done(index, row)
    finally:
        if started_here:
            ray.shutdown()


def write_summary(path: str | Path, rows: list[dict]) -> None:
    """``summary.csv`` with :data:`SUMMARY_COLUMNS` (empty where not computable)."""
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, SUMMARY_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({key: "" if row.get(key) is None else row.get(key) for key in SUMMARY_COLUMNS})


def run_batch(jobs: list[BatchJob], out: str | Path, workers: int = 1, ray_address: str | None = None, progress: bool = True) -> list[dict]:
    """Run ``jobs`` (those already done are skipped) and write ``out/summary.csv``; the rows in
    job order."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict | None] = [finished_row(job) for job in jobs]
    todo = [index for index, row in enumerate(rows) if row is None]
    if len(todo) < len(jobs):
        logger.info("%d of %d logs already done: skipped", len(jobs) - len(todo), len(jobs))
    bar = None
    if progress and todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="logs", unit="log")
    started = time.perf_counter()

    def on_done(position: int, row: dict) -> None:
        rows[todo[position]] = row
        if row["status"] != OK:
            logger.warning("%s: %s", row["log"], row["status"])
        if bar is not None:
            bar.update(1)
        write_summary(out / SUMMARY_FILE, [r for r in rows if r is not None])

    pending = [jobs[index] for index in todo]
    try:
        if ray_address is not None:
            _run_ray(pending, ray_address, max(1, workers), on_done)
        else:
            _run_local(pending, max(1, workers), on_done)
    finally:
        if bar is not None:
            bar.close()
    write_summary(out / SUMMARY_FILE, [r for r in rows if r is not None])
    logger.info("batch of %d logs in %.1f s", len(todo), time.perf_counter() - started)
    return [row for row in rows if row is not None]
