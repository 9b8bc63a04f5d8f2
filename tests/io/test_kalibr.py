"""A rig from a Kalibr camchain and a layout (issue 15): intrinsics, the chain T_cn_cnm1, the
reference camera's measured mount, the hitch, trailer cameras at hitch angle 0."""
from __future__ import annotations

import dataclasses

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from ampc_vo.errors import ConfigError
from ampc_vo.geometry import invert_pose, make_pose, rot_x, rot_z
from ampc_vo.io.kalibr import kalibr_from_rig, load_rig_from_kalibr, rig_from_kalibr
from ampc_vo.rig import load_rig

ROOT = Path(__file__).resolve().parents[2]

# a camchain as Kalibr prints it: a forward pinhole-radtan camera, a left fisheye (equidistant)
# turned 90 degrees, and a rear camera on the trailer 12 m back
CAMCHAIN = """
cam0:
  cam_overlaps: []
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  T_cn_cnm1:
  - [0.0, 0.0, 1.0, 0.4]
  - [0.0, 1.0, 0.0, 0.0]
  - [-1.0, 0.0, 0.0, -0.9]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: []
  camera_model: pinhole
  distortion_coeffs: [0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202, 0.00020293673591811182]
  distortion_model: equidistant
  intrinsics: [190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504]
  resolution: [512, 512]
  rostopic: /cam1/image_raw
cam2:
  T_cn_cnm1:
  - [0.0, 0.0, 1.0, 0.9]
  - [0.0, 1.0, 0.0, 0.3]
  - [-1.0, 0.0, 0.0, -12.1]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]
  distortion_model: radtan
  intrinsics: [400.0, 400.0, 320.0, 240.0]
  resolution: [640, 480]
  rostopic: /cam2/image_raw
"""

# the forward camera measured in a vehicle frame whose origin is on the road below the front
# axle: 4.1 m ahead of and 1.2 m above the king-pin's ground point (x forward, y left, z up);
# the camera looks forward (optical axis = vehicle x), 2.4 m up
R_VEHICLE_FORWARD_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
LAYOUT = {
    "reference": "cam0",
    "T_vehicle_reference": {"translation": [1.5, 0.0, 2.4], "quaternion": [-0.5, 0.5, -0.5, 0.5]},
    "hitch": [-2.6, 0.0, 1.2],
    "hitch_height": 1.2,
    "bodies": {"tractor": {"axle_x": 0.4}, "trailer": {"axle_x": -8.0}},
    "cameras": {"cam0": {"name": "front", "body": "tractor", "topic": "/front/image"},
                "cam1": {"name": "left", "body": "tractor"},
                "cam2": {"name": "rear", "body": "trailer"}},
}


def _chain() -> dict:
    return yaml.safe_load(CAMCHAIN)


def test_intrinsics_models_topics_and_the_reference_mount():
    rig = rig_from_kalibr(_chain(), LAYOUT)
    front, left, rear = rig.cameras
    assert (front.model, left.model, rear.model) == ("pinhole", "fisheye", "pinhole")
    assert (front.width, front.height, front.fx, front.fy, front.cx, front.cy) == (752, 480, 458.654, 457.296, 367.215, 248.375)
    assert front.distortion == (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    assert left.distortion[0] == pytest.approx(0.0034823894022493434)
    assert (front.topic, left.topic, rear.topic) == ("/front/image", "/cam1/image_raw", "/cam2/image_raw")
    # the forward camera: vehicle (1.5, 0, 2.4) minus the hitch (-2.6, 0, 1.2), looking along +x
    np.testing.assert_allclose(front.center, [4.1, 0.0, 1.2], atol=1e-12)
    np.testing.assert_allclose(front.R_body_camera, R_VEHICLE_FORWARD_CAMERA, atol=1e-12)
    assert (rig.hitch_height, rig.axle_x("tractor"), rig.axle_x("trailer")) == (1.2, 0.4, -8.0)


def test_the_chain_maps_points_between_cameras_as_kalibr_defines_it():
    # T_cn_cnm1 takes points from camera n-1 to camera n: a body point seen by camera n-1 and
    # carried by T_cn_cnm1 is where the rig puts it in camera n (trailer cameras at hitch angle 0)
    chain = _chain()
    rig = rig_from_kalibr(chain, LAYOUT)
    points = np.random.default_rng(0).uniform(-20, 20, (10, 4))
    points[:, 3] = 1.0
    for n in (1, 2):
        T_cn_cnm1 = np.array(chain[f"cam{n}"]["T_cn_cnm1"])
        previous, current = rig.cameras[n - 1], rig.cameras[n]
        np.testing.assert_allclose((invert_pose(current.T_body_camera) @ points.T).T,
                                   (T_cn_cnm1 @ invert_pose(previous.T_body_camera) @ points.T).T, atol=1e-9)
    # the left fisheye looks to the left (optical axis = +y of the body), the rear camera backwards
    np.testing.assert_allclose(rig.cameras[1].R_body_camera[:, 2], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(rig.cameras[2].R_body_camera[:, 2], [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(rig.cameras[1].center, [3.7, 0.9, 1.2], atol=1e-9)
    np.testing.assert_allclose(rig.cameras[2].center, [-8.4, 0.0, 1.5], atol=1e-9)


def test_a_reference_other_than_cam0_gives_the_same_rig():
    rig = rig_from_kalibr(_chain(), LAYOUT)
    layout = dict(LAYOUT, reference="cam2")
    T_vehicle_rear = make_pose(np.eye(3), np.array(LAYOUT["hitch"])) @ rig.cameras[2].T_body_camera
    from ampc_vo.geometry import quat_xyzw_from_rotation

    layout["T_vehicle_reference"] = {"translation": T_vehicle_rear[:3, 3].tolist(), "quaternion": quat_xyzw_from_rotation(T_vehicle_rear[:3, :3]).tolist()}
    other = rig_from_kalibr(_chain(), layout)
    for a, b in zip(rig.cameras, other.cameras):
        np.testing.assert_allclose(a.T_body_camera, b.T_body_camera, atol=1e-9)


@pytest.mark.parametrize("rig_file", ["default.yaml", "fisheye.yaml", "semitrailer.yaml"])
def test_a_rig_written_as_a_camchain_comes_back(rig_file):
    # the semitrailer: rolling-shutter cameras (the layout's readout_time) and the trailer's box
    rig = load_rig(ROOT / "configs" / "rigs" / rig_file)
    rig = dataclasses.replace(rig, cameras=(dataclasses.replace(rig.cameras[0], vignetting=0.4),) + rig.cameras[1:])  # photometric calibration
    camchain, layout = kalibr_from_rig(rig, reference=rig.cameras[2].name)
    back = rig_from_kalibr(yaml.safe_load(yaml.safe_dump(camchain)), yaml.safe_load(yaml.safe_dump(layout)))
    for a, b in zip(rig.cameras, back.cameras):
        np.testing.assert_allclose(a.T_body_camera, b.T_body_camera, atol=1e-9)
        assert (a.name, a.body, a.model, a.fx, a.cx, a.readout_time, a.vignetting) == (b.name, b.body, b.model, b.fx, b.cx, b.readout_time, b.vignetting)
    assert back.bodies == rig.bodies and back.hitch_height == rig.hitch_height


@pytest.mark.parametrize("change, message", [
    (lambda c, l: c["cam1"].update(distortion_model="fov"), "cam1: camera model pinhole-fov is not supported"),
    (lambda c, l: c["cam0"].update(camera_model="omni"), "cam0: camera model omni-radtan is not supported"),
    (lambda c, l: c["cam2"].pop("T_cn_cnm1"), "cam2.T_cn_cnm1: missing"),
    (lambda c, l: c["cam2"].update(T_cn_cnm1=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), "not a rigid transform"),
    (lambda c, l: l["cameras"].pop("cam2"), "expected one entry per camchain camera"),
    (lambda c, l: l.update(reference="cam7"), "reference: 'cam7' is not a camchain camera"),
    (lambda c, l: l["cameras"]["cam2"].update(body="dolly"), "unknown body 'dolly'"),
    (lambda c, l: l["cameras"]["cam1"].update(readout_time=2.0), "readout_time: rolling-shutter readout must be in"),
])
def test_bad_calibrations_are_clear_errors(change, message):
    import copy

    camchain, layout = _chain(), copy.deepcopy(LAYOUT)
    change(camchain, layout)
    with pytest.raises(ConfigError, match=message):
        rig_from_kalibr(camchain, layout)


def test_the_script_writes_a_rig_yaml(tmp_path):
    (tmp_path / "camchain.yaml").write_text(CAMCHAIN)
    (tmp_path / "layout.yaml").write_text(yaml.safe_dump(LAYOUT))
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "rig_from_kalibr.py"), str(tmp_path / "camchain.yaml"), "--layout",
                             str(tmp_path / "layout.yaml"), "--out", str(tmp_path / "rig.yaml")], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.camera_names == ["front", "left", "rear"]
    assert rig == load_rig_from_kalibr(tmp_path / "camchain.yaml", tmp_path / "layout.yaml")
    (tmp_path / "bad.yaml").write_text("cam0: {camera_model: pinhole}\n")
    failed = subprocess.run([sys.executable, str(ROOT / "scripts" / "rig_from_kalibr.py"), str(tmp_path / "bad.yaml"), "--layout",
                             str(tmp_path / "layout.yaml"), "--out", str(tmp_path / "x.yaml")], capture_output=True, text=True)
    assert failed.returncode == 2 and "bad.yaml: cam0.intrinsics: missing" in failed.stderr


def test_an_imucam_chain_without_t_cn_cnm1_and_an_opencv_header(tmp_path):
    # Kalibr's camchain-imucam gives each camera's T_cam_imu; OpenVINS' copies keep T_imu_cam only,
    # under OpenCV's %YAML:1.0 header: the chain follows as T_cn_imu T_cnm1_imu^-1
    chain = _chain()
    T_imu_cam0 = make_pose(rot_z(0.3) @ rot_x(0.1), np.array([0.2, -0.1, 0.05]))  # any IMU mount
    T_cam_imu = [invert_pose(T_imu_cam0)]
    for n in (1, 2):
        T_cam_imu.append(np.array(chain[f"cam{n}"]["T_cn_cnm1"]) @ T_cam_imu[-1])
    imucam = {key: {k: v for k, v in spec.items() if k != "T_cn_cnm1"} for key, spec in chain.items()}
    for n, T in enumerate(T_cam_imu):
        imucam[f"cam{n}"]["T_imu_cam"] = invert_pose(T).tolist()
    (tmp_path / "imucam.yaml").write_text("%YAML:1.0\n\n" + yaml.safe_dump(imucam))
    (tmp_path / "layout.yaml").write_text(yaml.safe_dump(LAYOUT))
    rig = load_rig_from_kalibr(tmp_path / "imucam.yaml", tmp_path / "layout.yaml")
    for a, b in zip(rig.cameras, rig_from_kalibr(chain, LAYOUT).cameras):
        np.testing.assert_allclose(a.T_body_camera, b.T_body_camera, atol=1e-9)
    del imucam["cam1"]["T_imu_cam"]
    with pytest.raises(ConfigError, match="cam1.T_cn_cnm1: missing"):
        rig_from_kalibr(imucam, LAYOUT)
