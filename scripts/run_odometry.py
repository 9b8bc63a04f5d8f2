#!/usr/bin/env python
"""Run the odometry on a dataset (issues 5 and 7, DESIGN sections 4, 5).

    python scripts/run_odometry.py [DATASET] --out OUT [--config CONFIG] [--mode MODE] [--rerun FILE.rrd]
                                   [--start FRAME] [--stop FRAME] [--rig RIG.yaml] [--wheel-speed [SOURCE]]
                                   [--without-cameras CAMERA ...]

DATASET is one of: our dataset folder with images (image frontend), our dataset folder with
measurements.npz only (simulated bearings), or a KITTI odometry folder (recognised by calib.txt and
its left/right image folders; stereo pair as cross-camera correspondences), or a recording: a ROS 1
.bag, a ROS 2 bag folder or an .mcap file, with --rig RIG.yaml naming each camera's topic (issue 15).
--wheel-speed uses the wheel speed (the folder's wheel_speed.csv, or SOURCE: a log topic or a CSV
timestamp,speed) in the wheel-speed factor. --without-cameras runs as if those rig cameras were
not there (the ablation of the trailer cameras: --without-cameras trailer_left trailer_rear). Without DATASET the
built-in demo runs: the demo route is rendered into a cache folder on first use
(``$AMPC_VO_CACHE``, default ``~/.cache/ampc_vo``) and evaluated against its ground truth at the end.

Writes OUT/tractor.tum, OUT/trailer.tum, OUT/hitch.csv incrementally (a crash or Ctrl-C keeps what
was done), OUT/timing.json and OUT/config.yaml, optionally a Rerun recording, and prints a summary
(frames, keyframes, distance, fps, time per frame of the frontend and the backend). OUT holds one
run: a second run into it while the first runs is refused; the files of an earlier run are removed
first; OUT/run.json records the run (ampc_vo.io.run_folder).

Exit codes (ampc_vo.tools.cli): 0 done, 1 failed (nothing measured, disk full, worker died),
2 bad input, 130 SIGINT, 143 SIGTERM; every exit prints one line. Interrupted runs keep the
estimates written so far.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.config import MODES, SOURCES, load_config  # noqa: E402
from ampc_vo.errors import AmpcError  # noqa: E402
from ampc_vo.tools.cli import ExitContext, run_cli  # noqa: E402


def with_wheel_speed(config, source: str | None):
    """``config`` with the wheel-speed factor on and, if given, its source (a topic or a CSV)."""
    scale = dataclasses.replace(config.scale, wheel_speed=True, wheel_speed_source=source or config.scale.wheel_speed_source)
    return dataclasses.replace(config, scale=scale)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, nargs="?", default=None, help="dataset or KITTI folder (default: the built-in demo)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: out/demo for the demo; required otherwise)")
    parser.add_argument("--config", type=Path, default=None, help="VO config YAML (default: configs/vo/kitti.yaml for a KITTI folder, else the built-in defaults = configs/vo/default.yaml)")
    parser.add_argument("--mode", choices=MODES, default=None, help="override the config's mode")
    parser.add_argument("--source", choices=SOURCES, default=None, help="override the config's source (images or bearings)")
    parser.add_argument("--start", type=int, default=0, metavar="FRAME", help="first frame to run on (default 0)")
    parser.add_argument("--stop", type=int, default=None, metavar="FRAME", help="stop before this frame (default: the end)")
    parser.add_argument("--rerun", type=Path, default=None, metavar="FILE.rrd", help="write a Rerun recording")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--wheel-speed-from-groundtruth", type=float, default=None, metavar="SIGMA_M",
                        help="simulate wheel odometry from the ground truth with this noise (m) and enable the wheel-speed factor")
    parser.add_argument("--rig", type=Path, default=None, help="rig.yaml for a recording (each camera's topic)")
    parser.add_argument("--wheel-speed", nargs="?", const="", default=None, metavar="SOURCE",
                        help="use wheel speed: the dataset folder's wheel_speed.csv, or SOURCE (a log topic or a CSV timestamp,speed)")
    parser.add_argument("--without-cameras", nargs="+", default=(), metavar="CAMERA",
                        help="run as if these rig cameras were not there (an ablation, or a broken camera)")
    args = parser.parse_args(argv)
    if args.dataset is not None and args.out is None:
        parser.error("--out is required with a DATASET")
    return run_cli(lambda context: _run(args, context))


def _run(args: argparse.Namespace, context: ExitContext) -> int:
    """The run itself; errors and interrupts become exit codes in :func:`run_cli`."""
    from ampc_vo.frontend.sources import default_config_path

    config = load_config(args.config if args.config is not None else default_config_path(args.dataset))
    if args.mode:
        config = config.with_mode(args.mode)
    if args.source:
        config = dataclasses.replace(config, source=args.source)
    if args.wheel_speed is not None:
        config = with_wheel_speed(config, args.wheel_speed or None)
    logging.basicConfig(level=config.output.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    demo = args.dataset is None
    if demo:
        from ampc_vo.tools.demo import demo_dataset

        dataset_path = demo_dataset(progress=not args.no_progress)
        out = args.out or Path("out/demo")
    else:
        dataset_path, out = args.dataset, args.out
    from ampc_vo.tools.runner import run_sequence
    from ampc_vo.frontend.sources import open_sequence

    sequence = open_sequence(dataset_path, config, args.start, args.stop, rig=args.rig, progress=False if args.no_progress else None,
                             dropped_cameras=tuple(args.without_cameras))
    wheel = None
    if args.wheel_speed_from_groundtruth is not None:
        if sequence.truth is None:
            raise AmpcError(f"{dataset_path}: --wheel-speed-from-groundtruth needs ground truth")
        from ampc_vo.scale.wheel import wheel_odometry_from_poses

        config = dataclasses.replace(config, scale=dataclasses.replace(config.scale, wheel_speed=True))
        wheel = wheel_odometry_from_poses(sequence.truth.timestamps, sequence.truth.T_world_tractor, sequence.rig.axle_x("tractor"), args.wheel_speed_from_groundtruth)
    context.outputs = out  # from here on an interrupt keeps what was written there
    summary, _ = run_sequence(sequence, config, out, rerun_path=args.rerun, progress=False if args.no_progress else None, wheel_odometry=wheel)
    print(f"{dataset_path} ({sequence.kind}) -> {out}  (mode {summary.mode})")
    print(f"frames {summary.frames}  keyframes {summary.keyframes}  distance {summary.distance_m:.1f} m  "
          f"{summary.frames_per_second:.1f} frames/s  backend {summary.backend_ms_median:.1f} ms/keyframe (median)")
    print("time breakdown (median ms): " + ", ".join(f"{name} {value:.1f}" for name, value in summary.backend_ms_breakdown.items()))
    print("keyframe statuses: " + ", ".join(f"{name} {count}" for name, count in summary.statuses.items()))
    if args.rerun is not None:
        print(f"Rerun recording: {args.rerun}  (view: rerun {args.rerun})")
    if demo and sequence.truth is not None:
        from ampc_vo.tools.evaluation import evaluate_run_folder

        evaluation, written = evaluate_run_folder(out, sequence.truth, title="ampc-vo demo (rendered images)")
        print(evaluation.metrics.table())
        print("wrote " + " and ".join(str(path) for path in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
