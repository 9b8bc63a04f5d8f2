"""Ground truth of a recording (issue 15): a pose topic or a TUM file, a hitch-angle CSV for the
trailer, resampled at the estimate's times."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ampc_vo.errors import DatasetError
from ampc_vo.io.bag_writer import RecordingContent, write_recording
from ampc_vo.io.folder import read_dataset
from ampc_vo.io.groundtruth_log import load_log_groundtruth, truth_at
from ampc_vo.io.outputs import Trajectory, write_tum
from ampc_vo.rig import replace_camera


@pytest.mark.parametrize("format, pose_type", [("ros2-mcap", "odometry"), ("ros1", "pose")])
def test_a_pose_topic_and_a_hitch_csv_give_both_bodies(tiny_dataset, tmp_path, format, pose_type):
    dataset = read_dataset(tiny_dataset)
    rig = dataclasses.replace(dataset.rig, cameras=tuple(replace_camera(c, topic=f"/{c.name}") for c in dataset.rig.cameras))
    dataset = dataclasses.replace(dataset, rig=rig)
    log = write_recording(dataset, tmp_path / ("log.bag" if format == "ros1" else "log"), format, RecordingContent(pose_topic="/truth", pose_type=pose_type))
    truth = dataset.groundtruth
    hitch_csv = tmp_path / "hitch.csv"
    hitch_csv.write_text("timestamp,hitch_angle\n" + "".join(f"{float(t)!r},{float(a)!r}\n" for t, a in zip(truth.timestamps, truth.hitch_angle)))
    loaded = load_log_groundtruth(log, "/truth", hitch_csv, trailer_axle_x=-8.0)
    np.testing.assert_allclose(loaded.timestamps, truth.timestamps, atol=1e-9)
    np.testing.assert_allclose(loaded.T_world_tractor, truth.T_world_tractor, atol=1e-9)
    # the trailer from the hitch angle (hitch centres coincide) is the simulator's trailer
    np.testing.assert_allclose(loaded.T_world_trailer, truth.T_world_trailer, atol=1e-9)
    assert loaded.trailer_axle_x == -8.0
    with pytest.raises(DatasetError, match="ground-truth pose topic '/odom' is not in the log"):
        load_log_groundtruth(log, "/odom")
    with pytest.raises(DatasetError, match="needs its pose topic"):
        load_log_groundtruth(log)


def test_a_tum_file_and_resampling_at_other_times(short_trajectory, tmp_path):
    # truth at every second frame (1.6 m apart), resampled at the frames between: within the arc's
    # sagitta L²/(8R) = 8 mm on the 40 m radius (the chord's midpoint against the arc's)
    write_tum(tmp_path / "truth.tum", Trajectory(short_trajectory.timestamps[::2], short_trajectory.T_world_tractor[::2]))
    truth = load_log_groundtruth(tmp_path / "truth.tum")
    inner = short_trajectory.timestamps[1:-1:2]
    resampled = truth_at(truth, np.concatenate([[-5.0], inner, [99.0]]))  # times outside are left out
    np.testing.assert_allclose(resampled.timestamps, inner)
    np.testing.assert_allclose(resampled.T_world_tractor[:, :3, 3], short_trajectory.T_world_tractor[1:-1:2, :3, 3], atol=1e-2)
    np.testing.assert_allclose(resampled.T_world_tractor[:, :3, :3], short_trajectory.T_world_tractor[1:-1:2, :3, :3], atol=1e-2)  # 0.3° where the curvature ramps
    with pytest.raises(DatasetError, match="no estimate lies in the ground truth's time span"):
        truth_at(truth, np.array([100.0]))
