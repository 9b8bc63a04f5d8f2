#!/usr/bin/env python
"""Write one of our dataset folders as a recording (issue 15; ``ampc_vo.io.bag_writer``).

    python scripts/dataset_to_log.py DATASET --out LOG [--format ros2-mcap|ros2-sqlite3|ros1|mcap]
                                     [--compressed] [--pose-topic TOPIC] [--wheel-speed-topic TOPIC]
                                     [--time-origin SECONDS]

Each camera's images go on its rig topic (cameras without one: /camera/<name>/image; the rig
written beside the log as LOG.rig.yaml names them), stamped with the camera's capture time;
--compressed writes JPEG CompressedImage messages; --pose-topic adds the ground-truth tractor pose
(nav_msgs/Odometry), --wheel-speed-topic the folder's wheel_speed.csv (TwistStamped). Every stamp is
written plus --time-origin seconds (default: the whole seconds that make the earliest capture time
non-negative, 0 for most folders; a log's time cannot be negative).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.tools.cli import exit_codes  # noqa: E402


@exit_codes
def main(argv: list[str] | None = None) -> int:
    from ampc_vo.io.bag_writer import FORMATS

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, help="dataset folder with images")
    parser.add_argument("--out", type=Path, required=True, help="the log to write (a .bag file, a .mcap file or a ROS 2 bag folder)")
    parser.add_argument("--format", choices=FORMATS, default="ros2-mcap")
    parser.add_argument("--compressed", action="store_true", help="JPEG CompressedImage instead of raw mono8 Image")
    parser.add_argument("--pose-topic", default=None, help="write the ground-truth tractor pose on this topic")
    parser.add_argument("--wheel-speed-topic", default=None, help="write the folder's wheel_speed.csv on this topic")
    parser.add_argument("--time-origin", type=float, default=None, help="seconds added to every stamp (default: see above)")
    args = parser.parse_args(argv)
    from ampc_vo.io.bag_writer import RecordingContent, recording_time_origin, write_recording
    from ampc_vo.io.folder import read_dataset
    from ampc_vo.io.wheel_speed import WHEEL_SPEED_FILE, read_wheel_speed_csv
    from ampc_vo.rig import save_rig
    from ampc_vo.tools.recordings import with_topics

    dataset = read_dataset(args.dataset)
    dataset = dataclasses.replace(dataset, rig=with_topics(dataset.rig))
    wheel = None
    if args.wheel_speed_topic is not None:
        samples = read_wheel_speed_csv(args.dataset / WHEEL_SPEED_FILE)
        wheel = (samples.timestamps, samples.speed)
    content = RecordingContent(compressed=tuple(dataset.camera_names) if args.compressed else (), pose_topic=args.pose_topic,
                               wheel_speed=wheel, wheel_speed_topic=args.wheel_speed_topic or RecordingContent.wheel_speed_topic,
                               time_origin=args.time_origin)
    log = write_recording(dataset, args.out, args.format, content)
    rig_path = log.parent / f"{log.name}.rig.yaml"
    save_rig(dataset.rig, rig_path)
    origin = recording_time_origin(dataset, content)
    shifted = f"; stamps {origin:+.0f} s from the folder's times" if origin else ""
    print(f"{log} ({args.format}, {len(dataset)} frames){shifted}; rig with topics: {rig_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
