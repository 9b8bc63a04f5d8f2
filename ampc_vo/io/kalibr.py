"""A rig from a Kalibr calibration (issue 15): ``camchain.yaml`` (intrinsics and the chain
``T_cn_cnm1``) plus a layout file (which camera is which, the vehicle geometry) -> ``rig.yaml``.

Kalibr's camchain (github.com/ethz-asl/kalibr, wiki "Yaml formats"): per camera ``camN`` the
``camera_model`` (``pinhole``), ``distortion_model`` (``radtan``: OpenCV's k1 k2 p1 p2;
``equidistant``: OpenCV fisheye k1..k4, our ``fisheye`` model), ``distortion_coeffs``,
``intrinsics`` ``[fu, fv, pu, pv]``, ``resolution`` ``[width, height]``, ``rostopic``, and for every
camera after the first ``T_cn_cnm1``: the 4x4 transform taking points from camera N-1 to camera N
(camchain-imucam files also give ``T_cam_imu``; where ``T_cn_cnm1`` is missing the chain is
``T_cN_imu T_cN-1_imu^-1``; OpenVINS' copies give ``T_imu_cam`` and an OpenCV ``%YAML:1.0`` header).
Other models (omni, ds, eucm, fov, ...) are a :class:`ConfigError`.

The layout (YAML; DESIGN section 1 frames)::

    reference: cam0                  # the camchain camera whose mount was measured
    T_vehicle_reference: {translation: [x, y, z], quaternion: [qx, qy, qz, qw]}
    hitch: [x, y, z]                 # the hitch centre in the same vehicle frame (default 0 0 0:
                                     # the vehicle frame is the tractor frame)
    hitch_height: 1.2                # king-pin above the road (m)
    bodies: {tractor: {axle_x: 0.5}, trailer: {axle_x: -8.0}}    # in the body frames (as in rig.yaml,
                                     # with the trailer's box where mirror cameras see it)
    cameras:
      cam0: {name: front, body: tractor, topic: /front/image}    # topic default: Kalibr's rostopic
      cam1: {name: rear, body: trailer, readout_time: 0.03}      # rolling shutter (s, default 0)
      cam2: {name: left, body: tractor, vignetting: 0.4}         # lens fall-off (rig.yaml; default 0)

A rolling-shutter camera's ``readout_time`` (first to last row, seconds) is not in the camchain:
Kalibr's rolling-shutter calibration (``pinhole-radtan-rs``) prints a line delay, and
``readout_time = line_delay * (height - 1)``; a sensor's data sheet gives it too.

The vehicle frame is x forward, y left, z up with its axes those of the tractor (any origin: the
hitch position moves it onto the hitch). The whole rig is calibrated in one Kalibr run with the
trailer standing straight (hitch angle 0): then the trailer frame coincides with the tractor frame
and ``T_trailer_camera = T_tractor_camera`` for the trailer's cameras. So
``T_body_camN = T_tractor_vehicle T_vehicle_reference T_reference_cam0 T_cam0_camN``, with
``T_camN_cam0 = T_cN_cN-1 ... T_c1_c0`` from the chain.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ampc_vo.errors import ConfigError
from ampc_vo.geometry import invert_pose, make_pose, quat_xyzw_from_rotation, rotation_from_quat_xyzw
from ampc_vo.rig import Rig, rig_from_dict, rig_to_dict

LAYOUT_KEYS = ("reference", "T_vehicle_reference", "hitch", "hitch_height", "bodies", "cameras")
LAYOUT_CAMERA_KEYS = ("name", "body", "topic", "readout_time", "vignetting")
DISTORTION_MODELS = {"radtan": ("pinhole", 4), "equidistant": ("fisheye", 4)}


def _load_yaml(path: Path, what: str) -> Any:
    if not path.is_file():
        raise ConfigError(f"{path}: {what} not found")
    try:
        text = path.read_text()
        if text.lstrip().startswith("%YAML:"):  # OpenCV's YAML 1.0 header (camchains copied into OpenVINS, ...)
            text = text.lstrip().split("\n", 1)[1] if "\n" in text.lstrip() else ""
        return yaml.safe_load(text)
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path}: not valid YAML: {error}") from None


def _matrix(value: Any, where: str, source: str) -> np.ndarray:
    try:
        matrix = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: {where}: expected a 4x4 matrix of numbers") from None
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise ConfigError(f"{source}: {where}: expected a 4x4 matrix, got shape {matrix.shape}")
    rotation = matrix[:3, :3]
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-4) or np.linalg.det(rotation) < 0 or not np.allclose(matrix[3], [0, 0, 0, 1]):
        raise ConfigError(f"{source}: {where}: not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)")
    u, _, vt = np.linalg.svd(rotation)  # re-orthonormalise the printed rotation
    return make_pose(u @ vt, matrix[:3, 3])


def _numbers(value: Any, count: int | None, where: str, source: str) -> list[float]:
    if not isinstance(value, (list, tuple)) or (count is not None and len(value) != count):
        raise ConfigError(f"{source}: {where}: expected {count if count is not None else 'a list of'} numbers, got {value!r}")
    try:
        return [float(item) for item in value]
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: {where}: expected numbers, got {value!r}") from None


def camchain_cameras(raw: Any, source: str) -> list[tuple[str, dict]]:
    """The camchain's cameras in chain order (``cam0``, ``cam1``, ...), checked."""
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(f"{source}: expected a Kalibr camchain mapping cam0, cam1, ...")
    names = sorted((name for name in raw if str(name).startswith("cam") and str(name)[3:].isdigit()), key=lambda name: int(str(name)[3:]))
    if not names or [int(str(name)[3:]) for name in names] != list(range(len(names))):
        raise ConfigError(f"{source}: cameras must be named cam0, cam1, ... without gaps, got {sorted(map(str, raw))}")
    for index, name in enumerate(names):
        spec = raw[name]
        if not isinstance(spec, dict):
            raise ConfigError(f"{source}: {name}: expected a mapping")
        for key in ("camera_model", "intrinsics", "distortion_model", "distortion_coeffs", "resolution"):
            if key not in spec:
                raise ConfigError(f"{source}: {name}.{key}: missing")
        if index > 0 and not any(key in spec for key in ("T_cn_cnm1", "T_cam_imu", "T_imu_cam")):
            raise ConfigError(f"{source}: {name}.T_cn_cnm1: missing (the transform from {names[index - 1]} to {name})")
    return [(str(name), raw[name]) for name in names]


def _intrinsics(name: str, spec: dict, source: str) -> dict:
    """rig.yaml intrinsics of one camchain camera; :class:`ConfigError` for other models."""
    model, distortion_model = spec["camera_model"], spec["distortion_model"]
    if model != "pinhole" or distortion_model not in DISTORTION_MODELS:
        raise ConfigError(f"{source}: {name}: camera model {model}-{distortion_model} is not supported "
                          f"(supported: pinhole-radtan, pinhole-equi; recalibrate with one of them)")
    rig_model, count = DISTORTION_MODELS[distortion_model]
    fu, fv, pu, pv = _numbers(spec["intrinsics"], 4, f"{name}.intrinsics", source)
    width, height = _numbers(spec["resolution"], 2, f"{name}.resolution", source)
    distortion = _numbers(spec["distortion_coeffs"], count, f"{name}.distortion_coeffs", source)
    return {"model": rig_model, "width": int(width), "height": int(height), "fx": fu, "fy": fv, "cx": pu, "cy": pv, "distortion": distortion}


def _T_cam_imu(name: str, spec: dict, source: str) -> np.ndarray | None:
    """A camera's ``T_cam_imu`` (Kalibr camchain-imucam), or the inverse of ``T_imu_cam`` (OpenVINS'
    copy of it), or ``None``."""
    if "T_cam_imu" in spec:
        return _matrix(spec["T_cam_imu"], f"{name}.T_cam_imu", source)
    if "T_imu_cam" in spec:
        return invert_pose(_matrix(spec["T_imu_cam"], f"{name}.T_imu_cam", source))
    return None


def chain_poses(cameras: list[tuple[str, dict]], source: str) -> list[np.ndarray]:
    """``T_cam0_camN`` of every camera from the chain ``T_cN_cN-1``; a camera without it (an
    imucam file converted by other tools) takes ``T_cN_imu T_cN-1_imu^-1`` from both cameras'
    ``T_cam_imu`` (Kalibr's definition of the chain)."""
    T_cam_cam0 = [np.eye(4)]
    for (previous_name, previous), (name, spec) in zip(cameras[:-1], cameras[1:]):
        if "T_cn_cnm1" in spec:
            T_cn_cnm1 = _matrix(spec["T_cn_cnm1"], f"{name}.T_cn_cnm1", source)
        else:
            T_previous_imu, T_imu = _T_cam_imu(previous_name, previous, source), _T_cam_imu(name, spec, source)
            if T_previous_imu is None or T_imu is None:
                raise ConfigError(f"{source}: {name}.T_cn_cnm1: missing, and {previous_name} or {name} has no T_cam_imu to derive it from")
            T_cn_cnm1 = T_imu @ invert_pose(T_previous_imu)
        T_cam_cam0.append(T_cn_cnm1 @ T_cam_cam0[-1])
    return [invert_pose(T) for T in T_cam_cam0]


def _layout_pose(value: Any, where: str, source: str) -> np.ndarray:
    if not isinstance(value, dict) or set(value) - {"translation", "quaternion"}:
        raise ConfigError(f"{source}: {where}: expected {{translation: [x, y, z], quaternion: [qx, qy, qz, qw]}}")
    translation = _numbers(value.get("translation"), 3, where + ".translation", source)
    quaternion = np.array(_numbers(value.get("quaternion"), 4, where + ".quaternion", source))
    if abs(np.linalg.norm(quaternion) - 1.0) > 1e-6:
        raise ConfigError(f"{source}: {where}.quaternion: not a unit quaternion (norm {np.linalg.norm(quaternion):.6f}); order is x y z w")
    return make_pose(rotation_from_quat_xyzw(quaternion), np.array(translation))


def rig_from_kalibr(camchain: Any, layout: Any, camchain_source: str = "camchain", layout_source: str = "layout") -> Rig:
    """The :class:`Rig` of a parsed camchain and layout (module docstring)."""
    cameras = camchain_cameras(camchain, camchain_source)
    if not isinstance(layout, dict):
        raise ConfigError(f"{layout_source}: expected a mapping with {', '.join(LAYOUT_KEYS)}")
    unknown = sorted(set(layout) - set(LAYOUT_KEYS))
    if unknown:
        raise ConfigError(f"{layout_source}: unknown keys {unknown} (known: {list(LAYOUT_KEYS)})")
    for key in ("reference", "T_vehicle_reference", "bodies", "cameras"):
        if key not in layout:
            raise ConfigError(f"{layout_source}: {key}: missing")
    names = [name for name, _ in cameras]
    specs = layout["cameras"]
    if not isinstance(specs, dict) or sorted(map(str, specs)) != sorted(names):
        raise ConfigError(f"{layout_source}: cameras: expected one entry per camchain camera {names}, got {sorted(map(str, specs or {}))}")
    reference = str(layout["reference"])
    if reference not in names:
        raise ConfigError(f"{layout_source}: reference: {reference!r} is not a camchain camera {names}")
    hitch = np.array(_numbers(layout.get("hitch", [0.0, 0.0, 0.0]), 3, "hitch", layout_source))
    T_tractor_vehicle = make_pose(np.eye(3), -hitch)
    T_vehicle_reference = _layout_pose(layout["T_vehicle_reference"], "T_vehicle_reference", layout_source)
    T_cam0_cam = chain_poses(cameras, camchain_source)
    T_tractor_cam0 = T_tractor_vehicle @ T_vehicle_reference @ invert_pose(T_cam0_cam[names.index(reference)])
    rig_cameras = []
    for (name, spec), T_cam0_camera in zip(cameras, T_cam0_cam):
        entry = specs[name]
        if not isinstance(entry, dict) or "name" not in entry or "body" not in entry or set(entry) - set(LAYOUT_CAMERA_KEYS):
            raise ConfigError(f"{layout_source}: cameras.{name}: expected {{name, body[, topic, readout_time, vignetting]}}, got {entry!r}")
        T_body_camera = T_tractor_cam0 @ T_cam0_camera  # trailer cameras too: calibrated at hitch angle 0
        topic = entry.get("topic", spec.get("rostopic"))
        camera = {"name": str(entry["name"]), "body": entry["body"], **_intrinsics(name, spec, camchain_source),
                  "T_body_camera": {"translation": [float(v) for v in T_body_camera[:3, 3]],
                                    "quaternion": [float(v) for v in quat_xyzw_from_rotation(T_body_camera[:3, :3])]}}
        if topic is not None:
            camera["topic"] = str(topic)
        for key in ("readout_time", "vignetting"):  # checked by rig_from_dict
            if key in entry:
                camera[key] = entry[key]
        rig_cameras.append(camera)
    raw = {"hitch_height": layout.get("hitch_height", 0.0), "bodies": layout["bodies"], "cameras": rig_cameras}
    return rig_from_dict(raw, source=f"{layout_source} + {camchain_source}")


def load_rig_from_kalibr(camchain_path: str | Path, layout_path: str | Path) -> Rig:
    """:func:`rig_from_kalibr` of two files; errors name the file and the field."""
    camchain_path, layout_path = Path(camchain_path), Path(layout_path)
    return rig_from_kalibr(_load_yaml(camchain_path, "Kalibr camchain"), _load_yaml(layout_path, "layout"), str(camchain_path), str(layout_path))


# ---------------------------------------------------------------------- the inverse (tests, exports)
def kalibr_from_rig(rig: Rig, reference: str | None = None) -> tuple[dict, dict]:
    """A camchain and a layout that :func:`rig_from_kalibr` turns back into ``rig`` (cameras in rig
    order; the reference is the first camera unless named; the vehicle frame is the tractor
    frame). Trailer cameras are written as Kalibr sees them at hitch angle 0."""
    reference = reference or rig.cameras[0].name
    camchain: dict[str, dict] = {}
    layout_cameras: dict[str, dict] = {}
    previous = None
    for index, camera in enumerate(rig.cameras):
        key = f"cam{index}"
        if camera.model == "pinhole":
            distortion = list(camera.distortion) + [0.0] * (4 - len(camera.distortion))
            if len(distortion) > 4 and any(distortion[4:]):
                raise ConfigError(f"camera {camera.name!r}: k3 has no place in Kalibr's radtan model")
            distortion_model = "radtan"
        else:
            distortion = list(camera.distortion) + [0.0] * (4 - len(camera.distortion))
            distortion_model = "equidistant"
        spec = {"camera_model": "pinhole", "intrinsics": [float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)],
                "distortion_model": distortion_model, "distortion_coeffs": [float(v) for v in distortion[:4]],
                "resolution": [camera.width, camera.height]}
        if camera.topic:
            spec["rostopic"] = camera.topic
        if previous is not None:
            spec["T_cn_cnm1"] = (invert_pose(camera.T_body_camera) @ previous.T_body_camera).tolist()
        camchain[key] = spec
        layout_cameras[key] = {"name": camera.name, "body": camera.body}
        for name in ("readout_time", "vignetting"):
            if getattr(camera, name):
                layout_cameras[key][name] = float(getattr(camera, name))
        previous = camera
    T_body_reference = rig.camera(reference).T_body_camera
    layout = {"reference": f"cam{rig.camera_names.index(reference)}",
              "T_vehicle_reference": {"translation": [float(v) for v in T_body_reference[:3, 3]],
                                      "quaternion": [float(v) for v in quat_xyzw_from_rotation(T_body_reference[:3, :3])]},
              "hitch": [0.0, 0.0, 0.0], "hitch_height": float(rig.hitch_height),
              "bodies": rig_to_dict(rig)["bodies"], "cameras": layout_cameras}
    return camchain, layout
