"""Recordings from simulated sequences, and the check that a log runs as well as a folder (issue 15).

:func:`render_unsynchronised` renders a simulated route with every camera at its own capture time
(frame time + a per-camera offset; the body pose interpolated between the simulated frames,
``ampc_vo.sim.render.interpolate_pose``) into our dataset folder with ``<camera>_timestamp``
columns, the ground truth at the frame times and the simulated ``wheel_speed.csv``.
:func:`compare_log_with_folder` writes that folder as a recording (ROS 2 MCAP with compressed
images, ROS 1 bag, ...), builds the rig through a Kalibr camchain (``ampc_vo.io.kalibr``, as
``scripts/rig_from_kalibr.py`` does), runs the odometry on both and returns their metrics.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ampc_vo.config import VoConfig
from ampc_vo.rig import Rig, replace_camera

logger = logging.getLogger(__name__)


def with_topics(rig: Rig, prefix: str = "/camera") -> Rig:
    """``rig`` with each camera's topic ``<prefix>/<name>/image`` (cameras that have one keep it)."""
    return dataclasses.replace(rig, cameras=tuple(camera if camera.topic else replace_camera(camera, topic=f"{prefix}/{camera.name}/image")
                                                  for camera in rig.cameras))


def render_unsynchronised(sim_config: str | Path, out_dir: str | Path, offsets: dict[str, float], frames: int | None = None,
                          progress: bool = False) -> Path:
    """A dataset folder of ``sim_config`` whose camera ``c`` captures at frame time + ``offsets[c]``
    (s; cameras not named: 0), over the first ``frames`` frames (default: all). Rendered in this
    process (tests and experiments on short routes), with sensor noise and exposure changes but
    without motion blur and the moving vehicle."""
    from ampc_vo.io.folder import write_dataset
    from ampc_vo.io.groundtruth import Trajectory
    from ampc_vo.sim.render import Renderer, apply_sensor_effects, interpolate_pose, render_options_from_dict
    from ampc_vo.sim.simulation import simulate
    from ampc_vo.sim.wheel_odometry import write_simulated_wheel_speed
    import cv2

    result = simulate(sim_config)
    full = result.trajectory
    count = len(full) if frames is None else min(frames, len(full))
    trajectory = Trajectory(full.timestamps[:count], full.T_world_tractor[:count], full.T_world_trailer[:count], full.hitch_angle[:count],
                            None if full.speed is None else full.speed[:count], None if full.curvature is None else full.curvature[:count],
                            None if full.arc_length is None else full.arc_length[:count])
    rig = with_topics(result.rig)
    options = render_options_from_dict(result.config.render, f"{result.config.source}: render")
    if options.motion_blur_samples > 1 or options.moving_vehicle:
        logger.warning("%s: motion blur and the moving vehicle are not rendered here (ampc_vo.sim.render.render_sequence renders them, "
                       "with synchronised cameras)", sim_config)
    renderer = Renderer(result.scene, None, options)
    out_dir = Path(out_dir)
    capture = {camera.name: trajectory.timestamps + float(offsets.get(camera.name, 0.0)) for camera in rig.cameras}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=count, desc="render", unit="frame")
    for frame in range(count):
        for index, camera in enumerate(rig.cameras):
            poses = full.pose(camera.body)
            t = capture[camera.name][frame]
            base = int(np.clip(np.searchsorted(full.timestamps, t, side="right") - 1, 0, len(full) - 2))
            fraction = (t - full.timestamps[base]) / (full.timestamps[base + 1] - full.timestamps[base])
            T_world_body = interpolate_pose(poses[base], poses[base + 1], float(fraction))
            image = apply_sensor_effects(renderer.render_float(camera, T_world_body @ camera.T_body_camera), options, t, frame, index)
            path = out_dir / "images" / camera.name / f"{frame:06d}.png"
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), image)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    write_dataset(out_dir, rig, trajectory.timestamps, groundtruth=trajectory, with_images=True, camera_timestamps=capture)
    write_simulated_wheel_speed(out_dir, trajectory, result.config.seed)
    return out_dir


def write_kalibr_files(rig: Rig, folder: str | Path) -> tuple[Path, Path]:
    """``camchain.yaml`` and ``layout.yaml`` for ``rig`` (``ampc_vo.io.kalibr.kalibr_from_rig``)."""
    from ampc_vo.io.kalibr import kalibr_from_rig

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    camchain, layout = kalibr_from_rig(rig)
    for camera, spec in zip(rig.cameras, layout["cameras"].values()):
        spec["topic"] = camera.topic
    (folder / "camchain.yaml").write_text(yaml.safe_dump(camchain, sort_keys=False))
    (folder / "layout.yaml").write_text(yaml.safe_dump(layout, sort_keys=False))
    return folder / "camchain.yaml", folder / "layout.yaml"


@dataclass(frozen=True)
class LogComparison:
    """Metrics (``ampc_vo.tools.evaluation.Metrics``) of the folder run and of each log run."""

    folder: object
    logs: dict[str, object]


def compare_log_with_folder(dataset: str | Path, work: str | Path, formats: tuple[str, ...] = ("ros2-mcap", "ros1"),
                            compressed: bool = True, config: VoConfig | None = None) -> LogComparison:
    """Run ``dataset`` as a folder and as recordings in ``formats`` (module docstring; the rig of
    the recordings goes through a Kalibr camchain and the layout) and evaluate each."""
    from ampc_vo.frontend.sources import open_sequence
    from ampc_vo.io.bag_writer import RecordingContent, write_recording
    from ampc_vo.io.folder import read_dataset
    from ampc_vo.io.kalibr import load_rig_from_kalibr
    from ampc_vo.io.groundtruth import groundtruth_of
    from ampc_vo.tools.evaluation import evaluate_output
    from ampc_vo.tools.runner import run_sequence

    config = config or VoConfig()
    work = Path(work)
    folder = read_dataset(dataset)
    truth = groundtruth_of(folder)
    run_sequence(open_sequence(dataset, config), config, work / "folder", progress=False)
    folder_metrics = evaluate_output(work / "folder", truth).metrics
    camchain, layout = write_kalibr_files(folder.rig, work / "kalibr")
    rig = load_rig_from_kalibr(camchain, layout)
    suffixes = {"ros1": ".bag", "mcap": ".mcap"}
    logs = {}
    for format in formats:
        log = work / f"log-{format}{suffixes.get(format, '')}"
        content = RecordingContent(compressed=tuple(folder.camera_names) if compressed else ())
        write_recording(folder, log, format, content)
        run_sequence(open_sequence(log, config, rig=rig), config, work / f"out-{format}", progress=False)
        logs[format] = evaluate_output(work / f"out-{format}", truth).metrics
    return LogComparison(folder_metrics, logs)
