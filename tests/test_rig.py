"""Rig model: camera projection round trips (both models) and rig.yaml validation / round trip."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from ampc_vo.errors import ConfigError
from ampc_vo.geometry import make_pose
from ampc_vo.rig import Camera, camera_rotation, load_rig, replace_camera, rig_to_dict, save_rig

PINHOLE = Camera("pin", "tractor", "pinhole", 640, 480, 320.0, 321.0, 319.5, 239.5, (-0.12, 0.03, 0.001, -0.0005, -0.002))
PINHOLE_PLAIN = Camera("plain", "tractor", "pinhole", 640, 480, 320.0, 320.0, 319.5, 239.5)
FISHEYE = Camera("fish", "tractor", "fisheye", 640, 480, 240.0, 240.0, 319.5, 239.5, (0.02, -0.004, 0.0005, 0.0))
CAMERAS = {"pinhole": PINHOLE, "pinhole_plain": PINHOLE_PLAIN, "fisheye": FISHEYE}


def _on_border(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    return (np.abs(pixels[:, 0] + 0.5) < 1e-6) | (np.abs(pixels[:, 0] - camera.width + 0.5) < 1e-6) | (
        np.abs(pixels[:, 1] + 0.5) < 1e-6) | (np.abs(pixels[:, 1] - camera.height + 0.5) < 1e-6)


def _pixel_strategy(camera: Camera):
    return st.tuples(st.floats(-0.5, camera.width - 0.5), st.floats(-0.5, camera.height - 0.5))


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_unproject_project_round_trip_over_the_whole_image(name):
    camera = CAMERAS[name]
    u, v = np.meshgrid(np.linspace(-0.5, camera.width - 0.5, 65), np.linspace(-0.5, camera.height - 0.5, 49))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    bearings = camera.unproject(pixels)
    assert np.allclose(np.linalg.norm(bearings, axis=1), 1.0, atol=1e-12)
    projected, valid = camera.project(bearings * 7.3)
    assert np.all(valid | _on_border(camera, pixels))  # exact border pixels may round outside
    assert np.max(np.abs(projected - pixels)) < 1e-9


@settings(max_examples=200, deadline=None)
@given(data=st.data(), name=st.sampled_from(sorted(CAMERAS)))
def test_round_trip_property(data, name):
    camera = CAMERAS[name]
    pixel = np.array([data.draw(_pixel_strategy(camera))])
    depth = data.draw(st.floats(0.2, 500.0))
    bearing = camera.unproject(pixel)
    projected, valid = camera.project(bearing * depth)
    assert valid[0] or _on_border(camera, pixel)[0]
    assert np.max(np.abs(projected - pixel)) < 1e-9
    again = camera.unproject(projected)
    assert np.max(np.abs(again - bearing)) < 1e-9


def test_points_behind_a_pinhole_camera_are_invalid():
    _, valid = PINHOLE_PLAIN.project(np.array([[0.0, 0.0, -1.0], [0.1, 0.0, 1.0]]))
    assert valid.tolist() == [False, True]


def test_camera_rotation_points_the_optical_axis():
    forward = camera_rotation(0.0) @ np.array([0.0, 0.0, 1.0])
    left = camera_rotation(np.pi / 2) @ np.array([0.0, 0.0, 1.0])
    down = camera_rotation(0.0, np.deg2rad(10.0)) @ np.array([0.0, 0.0, 1.0])
    assert np.allclose(forward, [1, 0, 0]) and np.allclose(left, [0, 1, 0])
    assert down[2] < 0 and np.isclose(np.degrees(np.arcsin(-down[2])), 10.0)


@pytest.mark.parametrize("rig_name", ["default", "fisheye"])
def test_save_load_round_trip_is_identical(tmp_path, repo_root, rig_name):
    rig = load_rig(repo_root / "configs" / "rigs" / f"{rig_name}.yaml")
    save_rig(rig, tmp_path / "rig.yaml")
    again = load_rig(tmp_path / "rig.yaml")
    assert again.bodies == rig.bodies and again.camera_names == rig.camera_names
    for camera in rig.cameras:
        other = again.camera(camera.name)
        for key in ("body", "model", "width", "height", "fx", "fy", "cx", "cy", "distortion"):
            assert getattr(other, key) == getattr(camera, key)
        # quaternion -> rotation -> quaternion is exact to the last bit or two
        assert np.max(np.abs(other.T_body_camera - camera.T_body_camera)) < 1e-15


def test_default_rig_matches_the_design(default_rig):
    assert default_rig.axle_x("tractor") == pytest.approx(0.5) and default_rig.axle_x("trailer") == pytest.approx(-8.0)
    assert [camera.body for camera in default_rig.cameras] == ["tractor", "tractor", "trailer", "trailer"]
    rear = default_rig.camera("rear")
    assert np.allclose(rear.R_body_camera[:, 2][:2] / np.linalg.norm(rear.R_body_camera[:, 2][:2]), [-1.0, 0.0])


def _broken(tmp_path: Path, default_rig, change) -> Path:
    raw = copy.deepcopy(rig_to_dict(default_rig))
    change(raw)
    path = tmp_path / "broken_rig.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def _set(path: tuple, value):
    def change(raw):
        target = raw
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
    return change


def _delete(path: tuple):
    def change(raw):
        target = raw
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]
    return change


@pytest.mark.parametrize(
    "change, field, problem",
    [
        (_set(("cameras", 2, "body"), "dolly"), "cameras[2].body", "unknown body"),
        (_set(("bodies", "dolly"), {"axle_x": -3.0}), "bodies.dolly", "unknown body"),
        (_set(("cameras", 0, "T_body_camera", "quaternion"), [0.1, 0.2, 0.3, 0.4]), "cameras[0].T_body_camera.quaternion", "not a unit quaternion"),
        (_delete(("cameras", 1, "fx")), "cameras[1].fx", "missing"),
        (_delete(("cameras", 3, "cy")), "cameras[3].cy", "missing"),
        (_set(("bodies", "trailer", "axle_x"), 2.0), "bodies.trailer.axle_x", "behind the hitch"),
        (_set(("cameras", 0, "model"), "orthographic"), "cameras[0].model", "unknown camera model"),
        (_set(("cameras", 0, "fx"), -5.0), "cameras[0].fx", "positive"),
        (_set(("cameras", 1, "name"), "front"), "cameras", "duplicate camera names"),
        (_delete(("bodies", "tractor")), "bodies.tractor", "missing"),
        # a YAML boolean is not a focal length (it used to read as fx = 1.0)
        (_set(("cameras", 0, "fx"), True), "cameras[0].fx", "expected a number"),
        # a fractional image size used to be truncated silently
        (_set(("cameras", 0, "width"), 640.7), "cameras[0].width", "whole number of pixels"),
        (_set(("cameras", 1, "cx"), 5000.0), "cameras[1].cx", "principal point must lie in the image"),
        (_set(("cameras", 1, "cy"), -10.0), "cameras[1].cy", "principal point must lie in the image"),
        # misspelt keys used to be ignored (here: the distortion would silently be zero)
        (_set(("cameras", 0, "distorsion"), [0.1]), "cameras[0].distorsion", "unknown key"),
        (_set(("cameras", 0, "T_body_camera", "rotation"), [0.0, 0.0, 0.0]), "cameras[0].T_body_camera.rotation", "unknown key"),
        (_set(("bodies", "trailer", "axle"), -8.0), "bodies.trailer.axle", "unknown key"),
        (_set(("camera",), []), "camera", "unknown key"),
        (_set(("bodies", "trailer", "box"), {"front_x": 1.0, "rear_x": -12.0, "half_width": 1.25, "bottom_z": 0.0}), "bodies.trailer.box.top_z", "missing"),
        (_set(("bodies", "trailer", "box"), {"front_x": -12.0, "rear_x": 1.0, "half_width": 1.25, "bottom_z": 0.0, "top_z": 2.7}),
         "bodies.trailer.box", "front_x > rear_x"),
        (_set(("bodies", "trailer", "box"), {"front_x": 1000.0, "rear_x": -12000.0, "half_width": 1250.0, "bottom_z": 0.0, "top_z": 2700.0}),
         "bodies.trailer.box", "millimetres"),
    ],
)
def test_rig_validation_errors_name_file_and_field(tmp_path, default_rig, change, field, problem):
    path = _broken(tmp_path, default_rig, change)
    with pytest.raises(ConfigError) as error:
        load_rig(path)
    message = str(error.value)
    assert str(path) in message and field in message and problem in message, message


def test_missing_and_invalid_rig_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_rig(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("bodies: [unclosed")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_rig(bad)
    bad.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")  # an image saved as rig.yaml: was a UnicodeDecodeError traceback
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_rig(bad)


def test_bearings_in_body_rotate_into_the_body_frame():
    camera = Camera("c", "tractor", "pinhole", 640, 480, 320.0, 320.0, 319.5, 239.5,
                    T_body_camera=make_pose(camera_rotation(np.pi / 2), np.array([1.0, 1.0, 2.0])))
    bearing = camera.bearings_in_body(np.array([[319.5, 239.5]]))
    assert np.allclose(bearing, [[0.0, 1.0, 0.0]])


def test_hitch_height_readout_time_and_topic_round_trip(tmp_path, default_rig):
    raw = rig_to_dict(default_rig)
    raw["hitch_height"] = 1.2
    raw["cameras"][0]["readout_time"] = 0.03
    raw["cameras"][1]["topic"] = "/cam_left/image_raw/compressed"
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(raw))
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.hitch_height == 1.2 and rig.ground_z == -1.2
    assert rig.cameras[0].readout_time == 0.03 and rig.cameras[0].topic is None
    assert rig.cameras[1].topic == "/cam_left/image_raw/compressed" and rig.cameras[1].readout_time == 0.0
    save_rig(rig, tmp_path / "again.yaml")
    again = load_rig(tmp_path / "again.yaml")
    assert again.hitch_height == 1.2
    assert [(c.readout_time, c.topic) for c in again.cameras] == [(c.readout_time, c.topic) for c in rig.cameras]
    assert again.cameras[0] != replace_camera(again.cameras[0], readout_time=0.0)  # readout_time is part of equality


def test_vignetting_round_trips_and_gives_the_cos4_fall_off(tmp_path, default_rig):
    raw = rig_to_dict(default_rig)
    raw["cameras"][0]["vignetting"] = 0.6
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(raw))
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.cameras[0].vignetting == 0.6 and rig.cameras[1].vignetting == 0.0
    save_rig(rig, tmp_path / "again.yaml")
    again = load_rig(tmp_path / "again.yaml")
    assert [c.vignetting for c in again.cameras] == [c.vignetting for c in rig.cameras]
    assert again.cameras[0] != replace_camera(again.cameras[0], vignetting=0.0)
    camera = rig.cameras[0]
    illumination = camera.relative_illumination()
    assert illumination.shape == (camera.height, camera.width) and illumination.dtype == np.float32
    for u, v in ((0, 0), (camera.width - 1, camera.height - 1), (100, 400)):  # pinhole: tan alpha from the pixel's offset
        angle = np.arctan(np.hypot((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy))
        assert illumination[v, u] == pytest.approx(1.0 - 0.6 * (1.0 - np.cos(angle) ** 4), rel=1e-5)
    assert illumination.max() == pytest.approx(1.0, abs=1e-4)
    np.testing.assert_allclose(camera.relative_illumination(step=8), illumination, atol=5e-4)  # sampled and interpolated
    np.testing.assert_array_equal(rig.cameras[1].relative_illumination(), 1.0)
    raw["cameras"][0]["vignetting"] = 1.0
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError, match="vignetting: the strength of the cos\\^4 fall-off must be in"):
        load_rig(tmp_path / "bad.yaml")


@pytest.mark.parametrize("change, problem", [
    (lambda raw: raw.update(hitch_height=-0.5), "hitch_height: the king-pin's height above the road must be >= 0"),
    (lambda raw: raw.update(hitch_height="high"), "hitch_height: expected a number"),
    (lambda raw: raw["cameras"][0].update(readout_time=2.0), "cameras[0].readout_time: rolling-shutter readout must be in [0, 1) s"),
    (lambda raw: raw["cameras"][0].update(topic=""), "cameras[0].topic: expected a topic name"),
])
def test_new_rig_keys_are_validated(tmp_path, default_rig, change, problem):
    raw = rig_to_dict(default_rig)
    change(raw)
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError) as error:
        load_rig(tmp_path / "rig.yaml")
    assert problem in str(error.value)


def test_trailer_box_round_trip(tmp_path, default_rig):
    """``bodies.trailer.box`` (the trailer's outline, which the tractor's mirror cameras see) is
    read, kept exactly through save/load, and absent by default."""
    assert default_rig.bodies["trailer"].box is None
    raw = rig_to_dict(default_rig)
    raw["bodies"]["trailer"]["box"] = {"front_x": 0.8, "rear_x": -12.4, "half_width": 1.25, "bottom_z": 0.0, "top_z": 2.7}
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(raw))
    rig = load_rig(tmp_path / "rig.yaml")
    box = rig.bodies["trailer"].box
    np.testing.assert_allclose(box.lower(), [-12.4, -1.25, 0.0])
    np.testing.assert_allclose(box.upper(), [0.8, 1.25, 2.7])
    save_rig(rig, tmp_path / "again.yaml")
    assert load_rig(tmp_path / "again.yaml").bodies == rig.bodies
