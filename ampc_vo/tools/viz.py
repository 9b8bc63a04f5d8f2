"""Rerun recordings of an odometry run, saved headlessly to ``.rrd`` (DESIGN sections 4, 7).

Entity layout (world frame z up; body frames x forward, y left, z up; cameras OpenCV axes):

* ``world/tractor``, ``world/trailer``: estimated body poses (``Transform3D`` per frame) with a
  static ``box`` child (``Boxes3D``) and one child per camera (static ``T_body_camera`` and
  ``Pinhole``, so the frustum rides on the body); the camera entity also gets the image and its
  ``features`` (``Points2D``, green = inlier, red = outlier).
* ``world/truth/tractor``, ``world/truth/trailer``: ground-truth bodies as wireframe boxes.
* ``world/trajectory/{tractor,trailer}_{estimate,truth}``: trajectories (``LineStrips3D``).
* ``plots/hitch_deg/{estimate,upper,lower,truth}``: hitch angle and ±1 sigma (``Scalars``, degrees).

Timelines: ``frame`` (sequence) and ``time`` (seconds). Every :class:`RerunLogger` owns its own
``rr.RecordingStream`` (no global recording).
"""
from __future__ import annotations

import logging
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ampc_vo.config import RecordingConfig
from ampc_vo.errors import AmpcError
from ampc_vo.geometry import quat_xyzw_from_rotation
from ampc_vo.observations import FrameObservations
from ampc_vo.rig import Rig

logger = logging.getLogger(__name__)

INLIER_COLOR = (40, 220, 60)
OUTLIER_COLOR = (230, 40, 40)
ESTIMATE_COLOR = {"tractor": (30, 120, 255), "trailer": (255, 150, 20)}
TRUTH_COLOR = (170, 170, 170)
HITCH_SERIES = ("estimate", "upper", "lower", "truth")
_CHUNK_LINE = re.compile(r"^Chunk\(.*\) with (\d+) rows .* - (/\S*) - data columns: \[(.*)\]$")


@dataclass(frozen=True)
class VizConfig(RecordingConfig):
    """What to log (:class:`~ampc_vo.config.RecordingConfig`, the VO config's ``rerun`` section) and
    how it looks. Box geometry is in body coordinates (metres; origin at the hitch)."""

    frustum_distance_m: float = 1.0      # drawn depth of the camera frusta
    tractor_box_center: tuple[float, float, float] = (2.5, 0.0, 1.6)
    tractor_box_half_size: tuple[float, float, float] = (3.3, 1.25, 1.6)
    trailer_box_center: tuple[float, float, float] = (-6.3, 0.0, 2.0)
    trailer_box_half_size: tuple[float, float, float] = (6.8, 1.25, 2.0)


def _transform(pose: np.ndarray) -> rr.Transform3D:
    return rr.Transform3D(translation=pose[:3, 3], quaternion=rr.Quaternion(xyzw=quat_xyzw_from_rotation(pose[:3, :3])))


def default_blueprint(rig: Rig) -> rrb.Blueprint:
    """3D world view, one 2D view per camera (image with features) and the hitch-angle plot."""
    camera_views = [rrb.Spatial2DView(origin=f"world/{camera.body}/{camera.name}", name=camera.name) for camera in rig.cameras]
    right = [rrb.Grid(*camera_views)]
    if rig.has_trailer:
        right.append(rrb.TimeSeriesView(origin="plots/hitch_deg", name="hitch angle (deg)"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="world"),
            rrb.Vertical(*right, row_shares=[2, 1][: len(right)]),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RerunLogger:
    """Writes one odometry run to an ``.rrd`` file (headless) through its own recording stream.

    Use as a context manager or call :meth:`close`; every frame call :meth:`log_frame`.
    """

    def __init__(self, rig: Rig, path: str | Path, config: VizConfig | None = None, application_id: str = "ampc_vo") -> None:
        self.rig = rig
        self.path = Path(path)
        self.config = config or VizConfig()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise AmpcError(f"{self.path}: cannot create the folder of the recording ({error})") from None
        self.stream = rr.RecordingStream(application_id)
        self.stream.save(self.path, default_blueprint=default_blueprint(rig))
        self._estimate: dict[str, list[np.ndarray]] = {"tractor": [], "trailer": []}
        self._truth: dict[str, list[np.ndarray]] = {"tractor": [], "trailer": []}
        self._frames_logged = 0
        self._closed = False
        self._log_static()

    # ------------------------------------------------------------------ static content
    def _log_static(self) -> None:
        config = self.config
        stream = self.stream
        stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        boxes = {
            "tractor": (config.tractor_box_center, config.tractor_box_half_size),
            "trailer": (config.trailer_box_center, config.trailer_box_half_size),
        }
        for body in self.rig.bodies:
            center, half_size = boxes[body]
            stream.log(f"world/{body}/box", rr.Boxes3D(centers=[center], half_sizes=[half_size], colors=[ESTIMATE_COLOR[body]], labels=[body]), static=True)
            stream.log(f"world/truth/{body}/box", rr.Boxes3D(centers=[center], half_sizes=[half_size], colors=[TRUTH_COLOR]), static=True)
        for camera in self.rig.cameras:
            entity = f"world/{camera.body}/{camera.name}"
            stream.log(entity, _transform(camera.T_body_camera), static=True)
            stream.log(
                entity,
                rr.Pinhole(image_from_camera=camera.K, resolution=[camera.width, camera.height], camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=config.frustum_distance_m),
                static=True,
            )
        if self.rig.has_trailer:
            styles = {
                "estimate": ((30, 120, 255), 2.0, "estimate"),
                "upper": ((120, 170, 255), 1.0, "+1 sigma"),
                "lower": ((120, 170, 255), 1.0, "-1 sigma"),
                "truth": ((60, 60, 60), 1.5, "truth"),
            }
            for series, (color, width, name) in styles.items():
                stream.log(f"plots/hitch_deg/{series}", rr.SeriesLines(colors=[color], widths=[width], names=[name]), static=True)

    # ------------------------------------------------------------------ per frame
    def log_frame(
        self,
        frame: int,
        timestamp: float,
        T_world_tractor: np.ndarray | None = None,
        T_world_trailer: np.ndarray | None = None,
        hitch_angle: float | None = None,
        hitch_sigma: float | None = None,
        images: dict[str, np.ndarray | None] | None = None,
        observations: FrameObservations | None = None,
        inliers: dict[str, np.ndarray] | None = None,
        outlier_pixels: dict[str, np.ndarray] | None = None,
        truth_T_world_tractor: np.ndarray | None = None,
        truth_T_world_trailer: np.ndarray | None = None,
        truth_hitch_angle: float | None = None,
    ) -> None:
        """Log one frame. ``inliers[camera]`` is a boolean mask over ``observations.cameras[camera]``
        (all inliers if absent); ``outlier_pixels[camera]`` (K, 2) are extra features drawn as
        outliers (e.g. the frontend's ``TrackingReport.rejected_pixels``). Angles in radians
        (plotted in degrees)."""
        if self._closed:
            raise AmpcError(f"{self.path}: recording already closed")
        stream = self.stream
        config = self.config
        stream.set_time("frame", sequence=int(frame))
        stream.set_time("time", duration=float(timestamp))
        for body, pose in (("tractor", T_world_tractor), ("trailer", T_world_trailer)):
            if pose is not None and body in self.rig.bodies:
                stream.log(f"world/{body}", _transform(pose))
                self._estimate[body].append(np.asarray(pose)[:3, 3].copy())
        for body, pose in (("tractor", truth_T_world_tractor), ("trailer", truth_T_world_trailer)):
            if pose is not None and body in self.rig.bodies:
                stream.log(f"world/truth/{body}", _transform(pose))
                self._truth[body].append(np.asarray(pose)[:3, 3].copy())
        if config.trajectory_every > 0 and self._frames_logged % config.trajectory_every == 0:
            self._log_trajectories()

        if images and config.image_every > 0 and self._frames_logged % config.image_every == 0:
            for name, image in images.items():
                if image is None:
                    continue
                camera = self.rig.camera(name)
                stream.log(f"world/{camera.body}/{name}", rr.Image(image).compress(jpeg_quality=config.jpeg_quality))
        if observations is not None:
            for name, camera_observations in observations.cameras.items():
                camera = self.rig.camera(name)
                mask = np.ones(len(camera_observations), bool) if inliers is None or name not in inliers else np.asarray(inliers[name], bool)
                if mask.shape != (len(camera_observations),):
                    raise AmpcError(f"inlier mask of camera {name} has shape {mask.shape}, expected ({len(camera_observations)},)")
                pixels = camera_observations.pixels
                extra = None if outlier_pixels is None else outlier_pixels.get(name)
                if extra is not None and len(extra):
                    pixels = np.concatenate([pixels, np.asarray(extra, dtype=float).reshape(-1, 2)])
                    mask = np.concatenate([mask, np.zeros(len(pixels) - len(mask), bool)])
                colors = np.where(mask[:, None], INLIER_COLOR, OUTLIER_COLOR).astype(np.uint8)
                stream.log(f"world/{camera.body}/{name}/features", rr.Points2D(pixels, colors=colors, radii=2.0))

        if self.rig.has_trailer:
            if hitch_angle is not None and np.isfinite(hitch_angle):
                stream.log("plots/hitch_deg/estimate", rr.Scalars(np.degrees(hitch_angle)))
                if hitch_sigma is not None and np.isfinite(hitch_sigma):
                    stream.log("plots/hitch_deg/upper", rr.Scalars(np.degrees(hitch_angle + hitch_sigma)))
                    stream.log("plots/hitch_deg/lower", rr.Scalars(np.degrees(hitch_angle - hitch_sigma)))
            if truth_hitch_angle is not None and np.isfinite(truth_hitch_angle):
                stream.log("plots/hitch_deg/truth", rr.Scalars(np.degrees(truth_hitch_angle)))
        self._frames_logged += 1

    def _log_trajectories(self) -> None:
        for body in self.rig.bodies:
            if len(self._estimate[body]) >= 2:
                self.stream.log(f"world/trajectory/{body}_estimate", rr.LineStrips3D([np.array(self._estimate[body])], colors=[ESTIMATE_COLOR[body]], radii=0.05))
            if len(self._truth[body]) >= 2:
                self.stream.log(f"world/trajectory/{body}_truth", rr.LineStrips3D([np.array(self._truth[body])], colors=[TRUTH_COLOR], radii=0.04))

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Write the final trajectories and flush the file (idempotent)."""
        if self._closed:
            return
        self._log_trajectories()
        self.stream.flush()
        self.stream.disconnect()
        self._closed = True
        logger.info("wrote Rerun recording %s (%d frames)", self.path, self._frames_logged)

    def __enter__(self) -> "RerunLogger":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------- reading recordings back
def _rerun_cli(*arguments: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """Run the ``rerun`` command line of this interpreter's rerun-sdk (``python -m rerun``)."""
    try:
        return subprocess.run([sys.executable, "-m", "rerun", *arguments], capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        raise AmpcError(f"cannot run the rerun command line: {error}") from None


def verify_recording(path: str | Path) -> str:
    """Run ``rerun rrd verify``; returns its message or raises :class:`AmpcError`.

    The command exits 0 for an empty file too, so success requires "1 file verified without error".
    """
    path = Path(path)
    if not path.is_file():
        raise AmpcError(f"{path}: recording not found")
    result = _rerun_cli("rrd", "verify", str(path))
    message = (result.stdout + result.stderr).strip()
    if result.returncode != 0 or "1 file verified without error" not in message:
        raise AmpcError(f"{path}: rerun rrd verify failed: {message[-500:]}")
    return message


def recording_contents(path: str | Path) -> dict[str, dict[str, int]]:
    """Entity paths of an ``.rrd`` file with their component columns and row counts:
    ``{"/world/tractor": {"Transform3D:translation": 12, ...}, ...}`` (from ``rerun rrd print``)."""
    result = _rerun_cli("rrd", "print", str(path))
    if result.returncode != 0:
        raise AmpcError(f"{path}: rerun rrd print failed: {result.stderr.strip()[-500:]}")
    contents: dict[str, dict[str, int]] = {}
    for line in result.stdout.splitlines():
        match = _CHUNK_LINE.match(line.strip())
        if match is None:
            continue
        rows, entity, columns = int(match.group(1)), match.group(2), match.group(3).split()
        components = contents.setdefault(entity, {})
        for column in columns:
            components[column] = components.get(column, 0) + rows
    return contents
