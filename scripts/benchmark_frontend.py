#!/usr/bin/env python
"""Time the image frontend: milliseconds per frame and per camera frame, with the breakdown
detect / track (KLT forward-backward, of it the first KLT pass, the road's plane-warped second pass
and the aperture test) / reject (epipolar RANSAC) / unproject.

    python scripts/benchmark_frontend.py [DATASET] [--frames N] [--threads T] [--max-features K] [--reference REV]

DATASET: one of our dataset folders with images (e.g. written by simulate_sequence.py) or a KITTI
odometry folder (then left-right stereo matching is timed too). Without DATASET, 4 cameras of
640x480 see a synthetic texture moving by a few pixels per frame. Images are loaded before timing.

``--reference REV``: the tracker of git revision REV (its ``ampc_vo/frontend/tracker.py``) is timed
in the same run, frame by frame in turn with this one (the order alternating), and the ratios of
the two are printed: on a machine shared with other work that ratio is steadier than either time.
"""
from __future__ import annotations

import argparse
import logging
import os
import subprocess
import sys
import time
import types
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ampc_vo.errors import AmpcError
from ampc_vo.tools.cli import exit_codes  # noqa: E402
from ampc_vo.frontend.multi_camera import MultiCameraFrontend
from ampc_vo.config import TrackerConfig
from ampc_vo.rig import Body, Camera, Rig

STAGES = ("detect", "track", "reject", "unproject")
TRACK_PARTS = ("klt", "plane_warp", "aperture")  # parts of "track", where the tracker's reports have them


def synthetic_frames(count: int, cameras: int = 4, width: int = 640, height: int = 480) -> tuple[Rig, list[dict[str, np.ndarray]]]:
    """``count`` frames of ``cameras`` pinhole cameras looking at moving random plane waves."""
    rng = np.random.default_rng(0)
    waves = 60
    frequency = rng.uniform(-0.25, 0.25, size=(cameras, waves, 2))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(cameras, waves))
    rig = Rig({"tractor": Body("tractor", 1.0)}, tuple(Camera(f"cam{index}", "tractor", "pinhole", width, height, 500.0, 500.0, width / 2 - 0.5, height / 2 - 0.5) for index in range(cameras)))
    frames = []
    for frame in range(count):
        images = {}
        for index, camera in enumerate(rig.cameras):
            shift = frame * np.array([2.0 + index, 0.7 * index - 1.0])
            along_x = frequency[index, :, 0:1] * (np.arange(width) - shift[0]) + phase[index, :, None]
            along_y = frequency[index, :, 1:2] * (np.arange(height) - shift[1])
            wave = np.cos(along_y).T @ np.cos(along_x) - np.sin(along_y).T @ np.sin(along_x)
            images[camera.name] = np.clip(128 + 12 * wave, 0, 255).astype(np.uint8)
        frames.append(images)
    return rig, frames


def reference_gftt_ms(repeats: int = 10) -> float:
    """Median time of one full-image GFTT on 640x480 (DESIGN 7 measured ~3.5 ms on an idle machine):
    the ratio tells how much the machine is loaded by other processes."""
    import cv2

    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur((rng.random((480, 640)) * 255).astype(np.uint8), (0, 0), 1.5)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        cv2.goodFeaturesToTrack(image, 300, 0.01, 10)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def dataset_frames(path: Path, count: int) -> tuple[Rig, list[dict[str, np.ndarray | None]], tuple[tuple[str, str], ...]]:
    from ampc_vo.io.kitti import is_kitti_folder, load_kitti

    if is_kitti_folder(path):
        dataset = load_kitti(path)
        return dataset.rig, [dataset.images(k) for k in range(min(count, len(dataset)))], (("left", "right"),)
    from ampc_vo.io.folder import read_dataset

    dataset = read_dataset(path, load_measurements_file=False)
    if not dataset.has_images:
        raise AmpcError(f"{path}: dataset has no images (simulate it without --no-images)")
    frames = [{camera: dataset.load_image(k, camera) for camera in dataset.camera_names} for k in range(min(count, len(dataset)))]
    return dataset.rig, frames, ()


def reference_tracker_module(revision: str) -> types.ModuleType:
    """``ampc_vo/frontend/tracker.py`` of git revision ``revision`` of this repository, imported as a
    module of its own (the rest of ``ampc_vo`` is the working tree's)."""
    root = Path(__file__).resolve().parents[1]
    path = f"{revision}:ampc_vo/frontend/tracker.py"
    shown = subprocess.run(["git", "show", path], cwd=root, capture_output=True, text=True)
    if shown.returncode != 0:
        raise AmpcError(f"--reference: git show {path} failed: {shown.stderr.strip()}")
    module = types.ModuleType("reference_tracker")
    sys.modules[module.__name__] = module  # dataclasses look their module up there
    exec(compile(shown.stdout, path, "exec"), module.__dict__)
    return module


@dataclass
class Timings:
    """What one frontend took per frame: wall and CPU seconds, and each stage's milliseconds summed
    over the cameras (``parts_reported``: whether its tracker reports the parts of "track")."""

    wall: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    stage_ms: dict[str, list[float]] = field(default_factory=lambda: {stage: [] for stage in STAGES + TRACK_PARTS})
    features: list[float] = field(default_factory=list)
    parts_reported: bool = False

    def time_frame(self, frontend: MultiCameraFrontend, index: int, images: dict[str, np.ndarray | None]) -> None:
        """Run ``frontend`` on one frame and record its times."""
        start, cpu_start = time.perf_counter(), time.process_time()
        result = frontend.process_with_details(index, 0.1 * index, images)
        self.wall.append(time.perf_counter() - start)
        self.cpu.append(time.process_time() - cpu_start)
        for stage, times in self.stage_ms.items():
            times.append(sum(report.timings_ms.get(stage, 0.0) for report in result.reports.values()))
        self.parts_reported |= any("klt" in report.timings_ms for report in result.reports.values())
        self.features.append(np.mean([len(obs) for obs in result.observations.cameras.values()]))


def print_timings(label: str, timings: Timings, cameras: int, stereo: bool) -> None:
    """Per frame and per camera frame times and the stage breakdown of one frontend."""
    wall_ms, cpu_ms = 1e3 * np.array(timings.wall), 1e3 * np.array(timings.cpu)
    print(f"{label}: {np.mean(timings.features):.0f} features per camera")
    print(f"  per frame        median {np.median(wall_ms):6.1f} ms   mean {np.mean(wall_ms):6.1f} ms   p90 {np.percentile(wall_ms, 90):6.1f} ms")
    print(f"  per camera frame median {np.median(wall_ms) / cameras:6.1f} ms")
    print(f"  CPU time per frame median {np.median(cpu_ms):6.1f} ms (all threads; wall time suffers when other processes load the machine)")
    print("  breakdown per camera frame (mean, ms; summed over cameras / cameras):")
    for stage in STAGES:
        print(f"    {stage:<10s} {np.mean(timings.stage_ms[stage]) / cameras:6.2f}")
        if stage == "track" and timings.parts_reported:
            for part in TRACK_PARTS:
                print(f"      {part:<10s} {np.mean(timings.stage_ms[part]) / cameras:6.2f}")
    accounted = sum(np.mean(timings.stage_ms[stage]) for stage in STAGES)
    print(f"    {'other':<10s} {(np.mean(wall_ms) - accounted) / cameras:6.2f}   (validation, bookkeeping{', stereo matching' if stereo else ''}; negative with threads)")


@exit_codes
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, nargs="?", help="dataset folder with images or KITTI folder (default: synthetic)")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--threads", type=int, default=1, help="cameras tracked in parallel threads")
    parser.add_argument("--max-features", type=int, default=TrackerConfig().max_features)
    parser.add_argument("--lk-window", type=int, default=TrackerConfig().lk_window)
    parser.add_argument("--cv-threads", type=int, help="cv2.setNumThreads for this process (default: OpenCV's choice)")
    parser.add_argument("--reference", metavar="REV", help="also time the tracker of git revision REV, frame by frame in turn")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.dataset is None:
        rig, frames = synthetic_frames(args.frames)
        stereo_pairs: tuple[tuple[str, str], ...] = ()
        source = "synthetic"
    else:
        rig, frames, stereo_pairs = dataset_frames(args.dataset, args.frames)
        source = str(args.dataset)
    if args.cv_threads is not None:
        import cv2

        cv2.setNumThreads(args.cv_threads)
    config = TrackerConfig(max_features=args.max_features, lk_window=args.lk_window)
    frontends = {"this tracker": MultiCameraFrontend(rig, config, stereo_pairs=stereo_pairs, threads=args.threads)}
    if args.reference:
        reference = MultiCameraFrontend(rig, config, stereo_pairs=stereo_pairs, threads=args.threads)
        module = reference_tracker_module(args.reference)
        reference.trackers = {camera.name: module.CameraTracker(camera, config, road_z=rig.ground_z) for camera in rig.cameras}
        frontends[f"reference {args.reference}"] = reference
    timings = {label: Timings() for label in frontends}
    load_before = os.getloadavg()
    for frontend in frontends.values():
        frontend.process(-1, 0.0, frames[0])  # warm-up (first detection, OpenCV initialisation)
    for index, images in enumerate(frames[1:], start=1):
        labels = list(frontends) if index % 2 else list(frontends)[::-1]
        for label in labels:
            timings[label].time_frame(frontends[label], index, images)
    load_after = os.getloadavg()
    for frontend in frontends.values():
        frontend.close()
    cameras = len(rig.cameras)
    print(f"frontend on {source}: {len(frames) - 1} frames, {cameras} cameras of {rig.cameras[0].width}x{rig.cameras[0].height}, "
          f"{args.threads} thread(s); load average {load_before[0]:.2f} before, {load_after[0]:.2f} after")
    print(f"  reference: full-image GFTT 640x480 takes {reference_gftt_ms():.1f} ms now (DESIGN 7: ~3.5 ms idle)")
    for label, timing in timings.items():
        print_timings(label, timing, cameras, bool(stereo_pairs))
    if args.reference:
        this, other = (timings[label] for label in frontends)
        print(f"this / reference {args.reference}: wall per frame median {np.median(this.wall) / np.median(other.wall):.3f} "
              f"(frame by frame {np.median(np.array(this.wall) / np.array(other.wall)):.3f}), CPU {np.median(this.cpu) / np.median(other.cpu):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
