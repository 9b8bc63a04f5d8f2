#!/usr/bin/env python3
"""Benchmark the renderer: ms per 640x480 camera frame (pinhole and fisheye rigs) on the default
route's scene, the full camera pipeline of realistic routes (rolling shutter, motion blur, auto
exposure, vignetting, noise, traffic, trailer box, mount vibration, bumps: ``--realistic`` one or
more route files, default configs/sim/camera_effects_demo.yaml; ``--realistic-suite``: every
configs/sim/realistic_*.yaml), and the wall time of rendering a whole sequence with worker processes.

    PYTHONPATH=. python scripts/benchmark_render.py [--config configs/sim/demo.yaml] [--frames 20]
                                                    [--sequence-frames 40] [--processes 2]
                                                    [--realistic ROUTE.yaml ...] [--realistic-suite]
                                                    [--realistic-only]

Timings are single-process: per route the wall median and p90 and the CPU time per image (the
issue 13 budget: 100 ms per 640x480 image), with the load average at that moment (other processes
on the cores slow the wall figures, less the CPU ones).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # numpy matmuls here are tiny: threads only add overhead

import cv2  # noqa: E402
import numpy as np  # noqa: E402

REPOSITORY_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPOSITORY_ROOT))

from ampc_vo.io.groundtruth import Trajectory  # noqa: E402
from ampc_vo.sim.kinematics import simulate_kinematics
from ampc_vo.sim.render import Renderer, RenderOptions, render_sequence  # noqa: E402
from ampc_vo.rig import load_rig  # noqa: E402
from ampc_vo.sim.scene import build_scene  # noqa: E402
from ampc_vo.sim.config import load_sim_config  # noqa: E402


REALISTIC_SUITE = sorted(str(path) for path in (REPOSITORY_ROOT / "configs" / "sim").glob("realistic_*.yaml"))
BUDGET_MS = 100.0  # issue 13: realistic routes render at no more than 100 ms per image


def benchmark_realistic(config_path: str, count: int) -> float:
    """Print and return the median CPU ms per image of the whole camera pipeline
    (``render.render_frame_images``) on a route."""
    from ampc_vo.sim.render import render_frame_images, render_options_from_dict, sequence_job
    from ampc_vo.sim.simulation import simulate

    from ampc_vo.sim.camera_effects import WARP_MARGIN_PX
    from ampc_vo.sim.render import padded_camera

    result = simulate(config_path)
    renderer = Renderer(result.scene, None, render_options_from_dict(result.config.render))
    setup_started = time.process_time()
    for camera in result.rig.cameras:  # once per camera and worker process (the warp renders a padded image)
        renderer.rays_of(camera)
        renderer.rays_of(padded_camera(camera, WARP_MARGIN_PX))
    setup_cpu = time.process_time() - setup_started
    started, cpu_started = time.perf_counter(), time.process_time()
    job = sequence_job(renderer, result.rig, result.trajectory, **result.render_inputs())
    metering, metering_cpu = time.perf_counter() - started, time.process_time() - cpu_started
    frames = np.linspace(0, len(result.trajectory) - 1, count).astype(int)
    wall, cpu = [], []
    for frame in frames:
        wall_start, cpu_start = time.perf_counter(), time.process_time()
        render_frame_images(renderer, job, int(frame))
        wall.append((time.perf_counter() - wall_start) / len(result.rig.cameras))
        cpu.append((time.process_time() - cpu_start) / len(result.rig.cameras))
    wall_ms, cpu_ms = 1000 * np.array(wall), 1000 * np.array(cpu)
    readout = sorted({camera.readout_time for camera in result.rig.cameras})
    images = len(result.trajectory) * len(result.rig.cameras)
    meter_ms, meter_cpu_ms = 1000 * metering / images, 1000 * metering_cpu / images
    print(f"realistic {Path(config_path).name} ({len(result.rig.cameras)} cameras, readout {readout} s, "
          f"{len(result.config.traffic)} vehicles, trailer box {'on' if result.config.trailer_body else 'off'}; {len(frames)} frames): "
          f"wall median {np.median(wall_ms):.1f} ms/image, p90 {np.percentile(wall_ms, 90):.1f}; CPU median {np.median(cpu_ms):.1f} ms/image, "
          f"p90 {np.percentile(cpu_ms, 90):.1f}; + rays {setup_cpu:.1f} s CPU once; auto-exposure metering {meter_ms:.1f} ms/image wall, {meter_cpu_ms:.1f} CPU; "
          f"load average {os.getloadavg()[0]:.1f}{'' if np.median(cpu_ms) <= BUDGET_MS else f'  OVER the {BUDGET_MS:.0f} ms budget'}",
          flush=True)
    return float(np.median(cpu_ms))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPOSITORY_ROOT / "configs" / "sim" / "demo.yaml"))
    parser.add_argument("--frames", type=int, default=20, help="frames sampled along the route for the per-frame timing")
    parser.add_argument("--sequence-frames", type=int, default=40, help="frames of the whole-sequence timing (0: skip)")
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--realistic", nargs="*", default=[str(REPOSITORY_ROOT / "configs" / "sim" / "camera_effects_demo.yaml")],
                        help="routes of the full camera pipeline timing (none: skip)")
    parser.add_argument("--realistic-suite", action="store_true", help="time every configs/sim/realistic_*.yaml")
    parser.add_argument("--realistic-only", action="store_true", help="skip the ideal-route and sequence timings")
    args = parser.parse_args()
    cv2.setNumThreads(1)  # as in render_sequence's workers (one process per core)
    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    routes = REALISTIC_SUITE if args.realistic_suite else [route for route in args.realistic if route]
    cpu_per_route = {Path(route).stem: benchmark_realistic(route, args.frames) for route in routes}
    if len(cpu_per_route) > 1:
        slowest = max(cpu_per_route, key=cpu_per_route.get)
        print(f"slowest route {slowest}: CPU median {cpu_per_route[slowest]:.1f} ms/image (budget {BUDGET_MS:.0f} ms)")
    if args.realistic_only:
        return

    config = load_sim_config(args.config)
    rig = config.load_rig()
    trajectory = simulate_kinematics(config.route, config.rate_hz, rig.axle_x("tractor"), rig.axle_x("trailer"),
                                     config.initial_hitch_angle, config.duration)
    started = time.perf_counter()
    scene = build_scene(trajectory, np.random.default_rng(config.seed), config.scene)
    renderer = Renderer(scene, None, RenderOptions())
    print(f"scene: {len(scene.quads)} quads ({len(renderer.quads)} pieces after splitting); "
          f"textures + setup {time.perf_counter() - started:.2f} s; route {len(trajectory)} frames")

    frames = np.linspace(0, len(trajectory) - 1, args.frames).astype(int)
    for rig_name in ("default", "fisheye"):
        rig_variant = load_rig(REPOSITORY_ROOT / "configs" / "rigs" / f"{rig_name}.yaml")
        for camera in rig_variant.cameras:
            renderer.rays_of(camera)  # per-camera precomputation, once
        wall, cpu = [], []
        for frame in frames:
            for camera in rig_variant.cameras:
                pose = trajectory.pose(camera.body)[frame] @ camera.T_body_camera
                wall_start, cpu_start = time.perf_counter(), time.process_time()
                renderer.render(camera, pose)
                wall.append(time.perf_counter() - wall_start)
                cpu.append(time.process_time() - cpu_start)
        wall_ms, cpu_ms = 1000 * np.array(wall), 1000 * np.array(cpu)
        size = f"{rig_variant.cameras[0].width}x{rig_variant.cameras[0].height}"
        print(f"{rig_name:8s} rig ({size}, {len(wall_ms)} camera frames): wall median {np.median(wall_ms):.1f} ms, "
              f"p90 {np.percentile(wall_ms, 90):.1f} ms; CPU median {np.median(cpu_ms):.1f} ms")

    if args.sequence_frames > 0:
        count = min(args.sequence_frames, len(trajectory))
        part = Trajectory(trajectory.timestamps[:count], trajectory.T_world_tractor[:count],
                          trajectory.T_world_trailer[:count], trajectory.hitch_angle[:count])
        options = RenderOptions(processes=args.processes)
        with tempfile.TemporaryDirectory() as out_dir:
            started = time.perf_counter()
            render_sequence(out_dir, rig, part, scene, options, progress=False, renderer=renderer)
            elapsed = time.perf_counter() - started
        images = count * len(rig.cameras)
        print(f"sequence: {count} frames x {len(rig.cameras)} cameras = {images} PNGs in {elapsed:.1f} s with "
              f"{options.processes} processes ({1000 * elapsed / images:.0f} ms per image; "
              f"a 60 s, 10 Hz, 4-camera sequence would take ~{2400 * elapsed / images / 60:.1f} min)")


if __name__ == "__main__":
    main()
