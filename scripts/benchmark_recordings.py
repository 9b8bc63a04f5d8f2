#!/usr/bin/env python
"""Reading speed of recordings against our dataset folder (issue 15).

    python scripts/benchmark_recordings.py [DATASET] [--frames N]

Writes the first N frames of DATASET (default: the demo sequence, rendered on first use) as a ROS 2
MCAP bag with JPEG images, a ROS 1 bag with raw images and a ROS 2 sqlite3 bag into a temporary
folder, then prints for each: the index pass (s), and images decoded per second through
``load_image`` (all cameras of each frame, in frame order as the frontend reads them), beside the
folder's PNG images.
"""
from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing


def _read_all(dataset, frames: int) -> float:
    started = time.perf_counter()
    for frame in range(frames):
        for camera in dataset.camera_names:
            dataset.load_image(frame, camera)
    return frames * len(dataset.camera_names) / (time.perf_counter() - started)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, nargs="?", default=None, help="dataset folder with images (default: the demo)")
    parser.add_argument("--frames", type=int, default=100, help="frames to write and read (default 100)")
    args = parser.parse_args(argv)
    from ampc_vo.io.bag_writer import RecordingContent, write_recording
    from ampc_vo.io.bags import read_recording
    from ampc_vo.io.folder import read_dataset
    from ampc_vo.tools.recordings import with_topics

    if args.dataset is None:
        from ampc_vo.tools.demo import demo_dataset

        args.dataset = demo_dataset()
    folder = read_dataset(args.dataset)
    folder = dataclasses.replace(folder, rig=with_topics(folder.rig))
    frames = min(args.frames, len(folder))
    work = Path(tempfile.mkdtemp(prefix="ampc_vo_bench_"))
    try:
        print(f"{args.dataset}: {frames} frames x {len(folder.camera_names)} cameras")
        print(f"folder (PNG)            {_read_all(folder, frames):7.1f} images/s")
        cases = (("ros2-mcap", "", tuple(folder.camera_names), "MCAP, JPEG"), ("ros1", ".bag", (), "ROS 1, raw"), ("ros2-sqlite3", "", (), "sqlite3, raw"))
        for format, suffix, compressed, label in cases:
            subset = dataclasses.replace(folder, timestamps=folder.timestamps[:frames], frames=folder.frames[:frames])
            log = write_recording(subset, work / f"{format}{suffix}", format, RecordingContent(compressed=compressed))
            size = sum(path.stat().st_size for path in ([log] if log.is_file() else log.rglob("*"))) / 1e6
            started = time.perf_counter()
            recording = read_recording(log, folder.rig, progress=False)
            index = time.perf_counter() - started
            print(f"{label:<22s}  {_read_all(recording, frames):7.1f} images/s  index {index:5.2f} s  {size:6.1f} MB")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
