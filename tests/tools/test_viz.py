"""Rerun recording: a small run is written headlessly, verifies with ``rerun rrd verify`` and reads
back with the expected entities and components."""
from __future__ import annotations

import re

import numpy as np
import pytest

from ampc_vo.errors import AmpcError
from ampc_vo.geometry import make_pose, planar_pose
from ampc_vo.observations import CameraObservations, FrameObservations
from ampc_vo.rig import Body, Camera, Rig, camera_rotation
from ampc_vo.tools.viz import INLIER_COLOR, OUTLIER_COLOR, RerunLogger, VizConfig, recording_contents, verify_recording

FRAMES = 6


def small_rig() -> Rig:
    cameras = (
        Camera("front", "tractor", "pinhole", 64, 48, 50.0, 50.0, 31.5, 23.5, (), make_pose(camera_rotation(0.0), [3.0, 0.0, 2.5])),
        Camera("rear", "trailer", "fisheye", 64, 48, 20.0, 20.0, 31.5, 23.5, (0.01,), make_pose(camera_rotation(np.pi), [-12.0, 0.0, 3.0])),
    )
    return Rig({"tractor": Body("tractor", 0.5), "trailer": Body("trailer", -8.0)}, cameras)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("viz") / "run" / "recording.rrd"
    rng = np.random.default_rng(0)
    with RerunLogger(small_rig(), path, VizConfig(trajectory_every=2)) as viz:
        for frame in range(FRAMES):
            pixels = rng.uniform(0, 48, size=(5, 2))
            observations = FrameObservations(frame, 0.1 * frame, {
                "front": CameraObservations("front", np.arange(5), pixels, np.tile([0.0, 0.0, 1.0], (5, 1))),
                "rear": CameraObservations.empty("rear"),
            })
            viz.log_frame(
                frame, 0.1 * frame,
                T_world_tractor=planar_pose(1.0 * frame, 0.0, 0.01 * frame),
                T_world_trailer=planar_pose(1.0 * frame - 1.0, 0.0, 0.0),
                hitch_angle=0.05, hitch_sigma=0.01,
                images={"front": rng.integers(0, 255, size=(48, 64), dtype=np.uint8), "rear": None},
                observations=observations,
                inliers={"front": np.array([True, True, False, True, False])},
                outlier_pixels={"front": np.array([[10.0, 10.0]])},
                truth_T_world_tractor=planar_pose(1.0 * frame, 0.1, 0.0),
                truth_T_world_trailer=planar_pose(1.0 * frame - 1.0, 0.1, 0.0),
                truth_hitch_angle=0.04,
            )
    return path


def test_recording_verifies(recording):
    assert "1 file verified without error" in verify_recording(recording)


def test_recording_has_the_expected_entities(recording):
    contents = recording_contents(recording)
    frame_rows = {
        "/world/tractor": "Transform3D:translation",
        "/world/trailer": "Transform3D:translation",
        "/world/truth/tractor": "Transform3D:translation",
        "/world/tractor/front": "EncodedImage:blob",
        "/world/tractor/front/features": "Points2D:positions",
        "/plots/hitch_deg/estimate": "Scalars:scalars",
        "/plots/hitch_deg/upper": "Scalars:scalars",
        "/plots/hitch_deg/lower": "Scalars:scalars",
        "/plots/hitch_deg/truth": "Scalars:scalars",
    }
    for entity, component in frame_rows.items():
        assert contents.get(entity, {}).get(component) == FRAMES, (entity, contents.get(entity))
    static = {
        "/world/tractor/box": "Boxes3D:half_sizes",
        "/world/trailer/box": "Boxes3D:half_sizes",
        "/world/tractor/front": "Pinhole:image_from_camera",
        "/world/trailer/rear": "Pinhole:image_from_camera",
    }
    for entity, component in static.items():
        assert component in contents.get(entity, {}), (entity, contents.get(entity))
    for trajectory in ("tractor_estimate", "tractor_truth", "trailer_estimate", "trailer_truth"):
        assert "LineStrips3D:strips" in contents[f"/world/trajectory/{trajectory}"]
    assert "/world/trailer/rear/features" in contents  # an empty camera still logs (no points)


def test_features_are_coloured_by_inlier_and_outlier(recording):
    import subprocess
    import sys

    dump = subprocess.run([sys.executable, "-m", "rerun", "rrd", "print", "-vvv", str(recording)], capture_output=True, text=True, timeout=120).stdout
    section = dump.split("/world/tractor/front/features", 1)[1].split("Chunk(", 1)[0]
    first_row = next(line for line in section.splitlines() if re.search(r"┆ 0 +┆", line))
    colors = [int(value) for value in re.search(r"\[(\d+(?:, \d+)*)\]", first_row).group(1).split(", ")]
    packed = lambda rgb: (rgb[0] << 24) | (rgb[1] << 16) | (rgb[2] << 8) | 255  # noqa: E731
    green, red = packed(INLIER_COLOR), packed(OUTLIER_COLOR)
    # five tracked features with mask [T, T, F, T, F] and one extra rejected pixel
    assert colors == [green, green, red, green, red, red]


def test_empty_or_missing_recordings_fail_verification(tmp_path):
    empty = tmp_path / "empty.rrd"
    empty.write_bytes(b"")
    with pytest.raises(AmpcError, match="0 files verified"):
        verify_recording(empty)
    with pytest.raises(AmpcError, match="not found"):
        verify_recording(tmp_path / "missing.rrd")


def test_wrong_inlier_mask_is_a_clear_error(tmp_path):
    with RerunLogger(small_rig(), tmp_path / "bad.rrd") as viz:
        observations = FrameObservations(0, 0.0, {"front": CameraObservations("front", np.arange(2), np.zeros((2, 2)), np.tile([0.0, 0.0, 1.0], (2, 1)))})
        with pytest.raises(AmpcError, match="inlier mask"):
            viz.log_frame(0, 0.0, observations=observations, inliers={"front": np.ones(3, bool)})


def test_the_vo_configs_rerun_section_sets_what_is_logged(tmp_path):
    """``rerun.image_every`` of the VO config reaches the logger (run_odometry --rerun): the bytes
    the images add to the recording follow how many frames log them (5 of 5, 3 of 5, none)."""
    import dataclasses

    from ampc_vo.config import config_from_dict

    rng = np.random.default_rng(0)
    frames = [{camera.name: rng.integers(0, 255, (camera.height, camera.width), dtype=np.uint8) for camera in small_rig().cameras} for _ in range(5)]
    sizes = {}
    for every in (1, 2, 0):
        config = config_from_dict({"rerun": {"image_every": every, "jpeg_quality": 90}})
        viz_config = VizConfig(**dataclasses.asdict(config.rerun))
        assert viz_config.image_every == every and viz_config.jpeg_quality == 90
        path = tmp_path / f"every{every}.rrd"
        with RerunLogger(small_rig(), path, viz_config) as viz:
            for frame, images in enumerate(frames):
                viz.log_frame(frame, 0.1 * frame, T_world_tractor=np.eye(4), images=images)
        sizes[every] = path.stat().st_size
    all_images, every_other = sizes[1] - sizes[0], sizes[2] - sizes[0]
    assert all_images > 5000, sizes  # 10 noisy JPEGs of 64x48
    assert 0.45 < every_other / all_images < 0.75, sizes
