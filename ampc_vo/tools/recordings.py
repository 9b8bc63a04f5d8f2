"""Recordings from simulated sequences, and the check that a log runs as well as a folder (issue 15).

:func:`render_unsynchronised` renders a simulated route with every camera at its own capture time
(frame time + a per-camera offset; the body pose interpolated between the simulated frames,
``ampc_vo.sim.motion.sample_poses``) into our dataset folder with ``<camera>_timestamp``
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
    (s; cameras not named: 0), over the first ``frames`` frames (default: all): the simulator's own
    per-camera timing (``cameras:`` offsets, ``sim.camera_timing``) with every effect the route
    file turns on; the rig is written with a topic per camera (:func:`with_topics`)."""
    import dataclasses

    from ampc_vo.rig import save_rig
    from ampc_vo.sim.camera_settings import camera_settings_from_dict
    from ampc_vo.sim.config import load_sim_config
    from ampc_vo.sim.simulation import simulate_dataset

    config = load_sim_config(sim_config)
    cameras = camera_settings_from_dict({name: {"offset_ms": 1e3 * float(offset)} for name, offset in offsets.items()}, f"{sim_config}: offsets")
    config = dataclasses.replace(config, cameras=cameras, duration=None if frames is None else (frames - 1) / config.rate_hz)
    result = simulate_dataset(config, out_dir, with_images=True, progress=progress)
    save_rig(with_topics(result.rig), Path(out_dir) / "rig.yaml")
    return Path(out_dir)


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
                            compressed: bool = True, config: VoConfig | None = None, image_format: str = "jpeg") -> LogComparison:
    """Run ``dataset`` as a folder and as recordings in ``formats`` (module docstring; the rig of
    the recordings goes through a Kalibr camchain and the layout) and evaluate each. ``compressed``:
    the images as ``CompressedImage`` in ``image_format`` (``jpeg``, quality 95, or the lossless
    ``png``), else raw ``Image`` messages."""
    from ampc_vo.frontend.sources import open_sequence
    from ampc_vo.io.bag_writer import RecordingContent, recording_time_origin, write_recording
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
        content = RecordingContent(compressed=tuple(folder.camera_names) if compressed else (), image_format=image_format)
        write_recording(folder, log, format, content)
        run_sequence(open_sequence(log, config, rig=rig), config, work / f"out-{format}", progress=False)
        on_log_clock = dataclasses.replace(truth, timestamps=truth.timestamps + recording_time_origin(folder, content))
        logs[format] = evaluate_output(work / f"out-{format}", on_log_clock).metrics
    return LogComparison(folder_metrics, logs)
