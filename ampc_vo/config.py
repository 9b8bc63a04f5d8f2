"""Typed configuration of the odometry (``configs/vo/*.yaml``): one frozen dataclass per section.

Every value is validated on load; problems (unknown keys, wrong types, out-of-range values, unknown
mode) raise :class:`ConfigError` naming the file and the field, e.g.
``configs/vo/x.yaml: smoother.lag_s: must be > 0, got -1``. Missing keys take the defaults below,
so a config file only needs the values it changes. Degrees appear only in fields named ``*_deg``.
"""
from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ampc_vo.errors import ConfigError

# ---------------------------------------------------------------------- frontend settings
@dataclass(frozen=True)
class TrackerConfig:
    """Settings of one camera's tracker (pixels unless marked otherwise)."""

    max_features: int = 300          # target number of tracked features per camera
    grid_rows: int = 6               # replenishment grid
    grid_cols: int = 8
    replenish_ratio: float = 0.85    # detect new corners when fewer than this share of max_features remain
    max_per_cell_factor: float = 2.0 # a cell keeps at most this times its share of tracks (oldest first)
    quality_level: float = 0.001     # GFTT quality relative to the best corner of the searched region
    min_distance_px: float = 12.0    # GFTT minimum distance, also the exclusion radius around tracks
    block_size: int = 3              # GFTT block size (at the detection scale)
    detect_downscale: int = 2        # detect corners on an image downscaled by 1 (full size), 2 or 4 (faster)
    lk_window: int = 15              # LK window side (15: same accuracy as 21 on rendered images, 25 % faster)
    lk_levels: int = 4               # pyramid levels above the base image (4: side cameras move 40-120 px per frame at
                                     # 8 m/s, 10 Hz; 3 levels lose most of them; KLT survival 77% -> 89% on the demo
                                     # route, scripts/measure_klt_survival.py; OpenCV caps it where a level gets
                                     # smaller than the window: 4 is the deepest for 640x480 with a 15 px window)
    fb_levels: int = 1               # pyramid levels of the backward pass (it starts at the answer)
    lk_iterations: int = 20
    lk_epsilon: float = 0.03
    fb_threshold_px: float = 1.0     # forward-backward error above which a track is dropped
    exposure_compensation: bool = True  # KLT refined against the previous image rescaled by the exposure change
                                     # between the two images (vignetting.exposure_ratio): KLT assumes equal grey levels
    exposure_min_change: float = 0.01  # relative exposure change below which the first pass stands: the measure reads the
                                     # scene's own brightness changes (perspective, resolution) in cameras looking along the
                                     # motion as 0.1-0.7 % without any exposure change (vignetting.exposure_ratio)
    aperture_ratio: float = 0.1      # aperture test (0: none): new features must be corners (structure tensor's smaller
                                     # eigenvalue >= this share of the larger) and a track is dropped where its window is
                                     # an edge along its motion (gradient energy along the motion < this share of the
                                     # largest). On an edge KLT cannot measure the motion along it and the track slides:
                                     # road points flow along lane markings in forward motion, so the flow and the ground-
                                     # plane chord came out short (motorway at 25 m/s: chord 0.60-0.92 of the truth)
    border_px: float = 4.0           # tracks closer than this to the image border are dropped
    vignetting_fit_pairs: int = 40   # a camera whose rig.yaml gives no vignetting: its fall-off fitted to the tracks of
                                     # this many image pairs, then divided out (0: never; frontend/vignetting.py)
    vignetting_min_strength: float = 0.1  # a fitted strength below this is left in the images (at most 8 % darker at
                                     # 50 degrees off axis; rendered images without vignetting fit 0.00-0.02)
    plane_warp: bool = True          # second KLT pass for road tracks through the road plane's homography (tracker.py
                                     # step 2b): translation-only KLT reads a road patch that expands and shears
                                     # between frames short (motorway 25 m/s, exact road-plane warp: 0.86-0.97 of the
                                     # flow, 0.99-1.00 with the pass; scripts/measure_road_flow.py)
    plane_warp_range_m: float = 40.0 # road region: pixels whose ray meets the calibrated road plane within this range
    plane_warp_threshold_px: float = 3.0  # RANSAC threshold of the frame-to-frame road homography
    plane_warp_min_tracks: int = 12  # fewer road tracks than this: no second pass
    plane_warp_levels: int = 2       # pyramid levels of the second pass (it starts at the homography's prediction)
    ransac_threshold_px: float = 1.5 # outlier threshold (converted to radians with the focal length)
    ransac_iterations: int = 32      # essential-matrix hypotheses per frame (8-point samples)
    min_tracks_for_ransac: int = 16  # below this, no outlier rejection
    jump_fraction: float = 0.25      # re-initialise when fewer than this share of tracks survive ...
    jump_min_tracks: int = 30        # ... and at least this many tracks were there to begin with
    min_contrast: float = 2.0        # image standard deviation (grey levels) below which a frame is blank
    seed: int = 0                    # RANSAC sampling seed

    def __post_init__(self) -> None:
        positive = ("max_features", "grid_rows", "grid_cols", "lk_window", "ransac_iterations", "block_size")
        for name in positive:
            if int(getattr(self, name)) <= 0:
                raise ConfigError(f"frontend: {name} must be positive, got {getattr(self, name)!r}")
        if self.lk_levels < 0 or self.fb_levels < 0:
            raise ConfigError(f"frontend: lk_levels and fb_levels must be >= 0, got {self.lk_levels}, {self.fb_levels}")
        if self.detect_downscale not in (1, 2, 4):
            raise ConfigError(f"frontend: detect_downscale must be 1, 2 or 4, got {self.detect_downscale}")
        if self.lk_window % 2 == 0:
            raise ConfigError(f"frontend: lk_window must be odd, got {self.lk_window}")
        if not 0.0 <= self.aperture_ratio < 1.0:
            raise ConfigError(f"frontend: aperture_ratio must be in [0, 1), got {self.aperture_ratio}")
        if not 0.0 < self.quality_level < 1.0:
            raise ConfigError(f"frontend: quality_level must be in (0, 1), got {self.quality_level}")
        if self.plane_warp_range_m <= 0.0 or self.plane_warp_threshold_px <= 0.0 or self.plane_warp_min_tracks < 4 or self.plane_warp_levels < 0:
            raise ConfigError("frontend: plane_warp_range_m and plane_warp_threshold_px must be positive, plane_warp_min_tracks >= 4, plane_warp_levels >= 0")
        if self.vignetting_fit_pairs < 0 or not 0.0 <= self.vignetting_min_strength < 1.0:
            raise ConfigError("frontend: vignetting_fit_pairs must be >= 0 and vignetting_min_strength in [0, 1)")
        if not self.exposure_min_change >= 0.0:
            raise ConfigError(f"frontend: exposure_min_change must be >= 0, got {self.exposure_min_change}")
        if self.fb_threshold_px <= 0.0 or self.ransac_threshold_px <= 0.0 or self.min_distance_px <= 0.0:
            raise ConfigError("frontend: fb_threshold_px, ransac_threshold_px and min_distance_px must be positive")



@dataclass(frozen=True)
class StereoConfig:
    """Settings of :func:`match_stereo` (KLT from the first to the second camera of a pair)."""

    lk_window: int = 21
    lk_levels: int = 4
    fb_levels: int = 1                   # backward pass starts at the original pixel: shallow pyramid
    lk_iterations: int = 30
    lk_epsilon: float = 0.01
    fb_threshold_px: float = 1.0
    exposure_compensation: bool = True   # the two cameras' exposures differ: as TrackerConfig
    exposure_min_change: float = 0.01
    border_px: float = 0.0               # matches closer than this to the second image's border are dropped
    epipolar_threshold_px: float = 0.7   # Sampson GEC error of the known pair, pixels (rectified: row error / sqrt 2)
    min_depth_m: float = 1.0             # points closer than this (or behind) are rejected
    max_depth_m: float = 200.0




def _config_from_dict(kind: type, raw: dict[str, Any] | None, source: str) -> Any:
    """A frozen config dataclass from a YAML mapping; unknown keys and bad values raise ConfigError."""
    if raw is None:
        return kind()
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: expected a mapping of {kind.__name__} settings, got {type(raw).__name__}")
    fields = {item.name: item for item in dataclasses.fields(kind)}
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        raise ConfigError(f"{source}: unknown setting(s) {unknown}; known: {sorted(fields)}")
    values = {}
    for name, value in raw.items():
        cast = int if isinstance(getattr(kind(), name), int) else float
        try:
            values[name] = cast(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{source}: {name}: expected a number, got {value!r}") from None
    try:
        return kind(**values)
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None


def tracker_config_from_dict(raw: dict[str, Any] | None, source: str = "frontend") -> "TrackerConfig":
    """:class:`TrackerConfig` from a config mapping (e.g. the ``frontend`` section of a VO config)."""
    return _config_from_dict(TrackerConfig, raw, source)


def stereo_config_from_dict(raw: dict[str, Any] | None, source: str = "stereo") -> "StereoConfig":
    """:class:`StereoConfig` from a config mapping."""
    return _config_from_dict(StereoConfig, raw, source)


MODES = ("full", "tractor_only", "no_trailer_constraint", "separate")
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
PUBLISH_POLICIES = ("latest", "lagged")
# where the frames' observations come from (issue 7): images through the frontend when the dataset
# has them, else the simulator's bearing measurements (``auto``); or forced
SOURCES = ("auto", "images", "bearings")
# where an image source produces the next frame while the backend works (ampc_vo.frontend.sources)
FRONTEND_WORKERS = ("process", "thread", "none")


@dataclass(frozen=True)
class KeyframeConfig:
    """When a frame becomes a keyframe: moved ``min_distance_m`` (estimated chord of the hitch) or
    turned ``min_rotation_deg`` since the last keyframe, or ``max_interval_s`` elapsed (standstill
    keyframes keep the graph alive). DESIGN 2.3: keyframes 1-3 m apart keep θ accurate."""

    min_distance_m: float = 1.5
    min_rotation_deg: float = 5.0
    max_interval_s: float = 1.0
    min_tracks: int = 10
    standstill_distance_m: float = 0.05
    # frames whose constant-velocity prediction is below this fraction of both thresholds are not
    # keyframe candidates: the per-frame tractor RANSAC is skipped for them (speed); 0 disables
    prediction_gate: float = 0.6

    def validate(self, where: str) -> None:
        _positive(self.min_distance_m, where + "min_distance_m")
        if not 0.0 <= self.prediction_gate < 1.0:
            raise _error(where + "prediction_gate", f"must be in [0, 1), got {self.prediction_gate}")
        _positive(self.min_rotation_deg, where + "min_rotation_deg")
        _positive(self.max_interval_s, where + "max_interval_s")
        _at_least(self.min_tracks, 2, where + "min_tracks")
        _at_least(self.standstill_distance_m, 0.0, where + "standstill_distance_m")


@dataclass(frozen=True)
class RansacConfig:
    """RANSAC of the tractor 2-point and trailer 1-point solvers (DESIGN 2.1, 2.2). The Sampson
    threshold is given in pixels and divided by each camera's focal length (it is ~radians)."""

    threshold_px: float = 2.0
    confidence: float = 0.999
    max_iterations: int = 200
    min_inliers: int = 8
    seed: int = 0
    # median parallax (pixels, divided by the focal length) below which a frame pair is a standstill;
    # null: the median parallax of still points under smoother.pixel_sigma (1.665 sigma: the difference
    # of two noisy observations is Rayleigh). Forward motion with mostly far points (KITTI) needs less
    standstill_parallax_px: float | None = None
    # the hardest braking a truck can do (full braking of loaded trucks is about 5-7 m/s^2; UN ECE
    # R13 asks N3 vehicles for at least 5 m/s^2): a frame pair is a standstill only when the speed
    # before it could have dropped to zero within it (DESIGN 2.1); tracks that stay still while
    # the truck turns (the trailer's box in a mirror) cannot then stop the truck
    max_deceleration_mps2: float = 8.0
    # error of the Ackermann chord direction (curvature transitions, tyre slip; DESIGN 2): at small
    # yaw changes the 2-point chord hinges on it; 0 trusts the model exactly
    model_direction_sigma_deg: float = 0.05
    # a tractor motion must explain at least this share of the shared tracks: a planar motion
    # that fits a few (a speed bump's pitch, traffic, the trailer's box) is no measurement
    min_inlier_fraction: float = 0.25
    # where a planar motion explains less than attitude_fraction of the shared tracks, a change of
    # the body's pitch and roll up to max_attitude_change_deg is searched (bumps, braking, vertical
    # curves: a 0.5 deg pitch within a pair moves every bearing beyond the threshold); 0: planar only
    max_attitude_change_deg: float = 2.0
    attitude_fraction: float = 0.6

    def validate(self, where: str) -> None:
        _positive(self.threshold_px, where + "threshold_px")
        _at_least(self.max_attitude_change_deg, 0.0, where + "max_attitude_change_deg")
        if not 0.0 <= self.attitude_fraction <= 1.0:
            raise _error(where + "attitude_fraction", f"must be in [0, 1], got {self.attitude_fraction}")
        if not 0.0 <= self.min_inlier_fraction < 1.0:
            raise _error(where + "min_inlier_fraction", f"must be in [0, 1), got {self.min_inlier_fraction}")
        _at_least(self.model_direction_sigma_deg, 0.0, where + "model_direction_sigma_deg")
        _positive(self.max_deceleration_mps2, where + "max_deceleration_mps2")
        if not 0.0 < self.confidence < 1.0:
            raise _error(where + "confidence", f"must be in (0, 1), got {self.confidence}")
        _at_least(self.max_iterations, 1, where + "max_iterations")
        _at_least(self.min_inliers, 2, where + "min_inliers")
        if self.standstill_parallax_px is not None:
            _positive(self.standstill_parallax_px, where + "standstill_parallax_px")


@dataclass(frozen=True)
class SmootherConfig:
    """Fixed-lag smoother and factor noise (DESIGN section 3)."""

    lag_s: float = 3.0
    pixel_sigma: float = 1.0
    huber_k: float = 1.5
    nonholonomic_sigma_m: float = 0.005          # floor of the non-holonomic residual sigma (m)
    nonholonomic_slip_deg: float = 0.2           # tractor axle: slip angle the arc model misses when not cornering
    trailer_nonholonomic_slip_deg: float = 0.2   # trailer axle group: the same
    nonholonomic_slip_deg_per_mps2: float = 0.7  # both: tyre slip angle per m/s^2 of lateral acceleration (cornering coefficient ~0.15/deg)
    # the slip the arc misses stays for about this long (it follows the steering and the load): keyframe
    # pairs shorter than it share one slip, so each pair's slip sigma grows by sqrt(time / dt) and the
    # model's information per second does not grow with the keyframe rate (0: independent per pair)
    nonholonomic_slip_correlation_s: float = 1.0
    # the trailer's crab angle (steady drift down a cross-slope, an axle group off the centre line, a
    # dog-tracking trailer), a variable of the trailer's non-holonomic factor with this prior (None: not
    # estimated, zero; opt-in: on the realistic suite it cost more than it gave, DESIGN 11)
    trailer_crab_sigma_deg: float | None = None
    trailer_crab_random_walk_deg_per_sqrt_100m: float = 0.1  # it changes with the road's cross-slope and the load
    planar_rotation_sigma_deg: float = 0.2
    planar_height_sigma_m: float = 0.02
    # suspension: body roll and pitch per m/s^2 of lateral and longitudinal acceleration (quasi-static;
    # trucks: roll 0.4-0.9, pitch 0.1-0.35 deg per m/s^2, Gillespie ch. 5); widen the planar factor
    suspension_roll_deg_per_mps2: float = 0.9
    suspension_pitch_deg_per_mps2: float = 0.35
    joint_loop_rotation_sigma_deg: float = 0.1
    joint_loop_translation_sigma_m: float = 0.01
    joint_loop_pitch_sigma_deg: float = 10.0   # the fifth wheel's plate pitches freely (about +-15 deg of travel)
    prior_rotation_sigma_deg: float = 0.01
    prior_translation_sigma_m: float = 0.001
    hitch_prior_sigma_deg: float = 30.0
    hitch_limit_deg: float = 90.0   # the hitch's mechanical range (jack-knife stop), factors.hitch_limit
    hitch_random_walk_deg_per_m: float = 5.0
    hitch_hold_sigma_growth_deg_per_s: float = 1.0
    standstill_rotation_sigma_deg: float = 0.01
    standstill_translation_sigma_m: float = 0.002
    weak_motion_rotation_sigma_deg: float = 5.0
    weak_motion_translation_sigma_m: float = 1.0
    max_pair_gap: int = 1
    gate_px: float = 3.0
    # each camera's rotation relative to its body between two keyframes (bracket and mirror-arm
    # vibration), marginalised per camera and keyframe pair in the GEC (DESIGN 11, "Camera mounts"):
    # sigma = hypot(floor, per_mps * speed); both 0: rigid mounts, the body's rotation is each camera's
    camera_mount_sigma_deg: float = 0.02
    camera_mount_sigma_deg_per_mps: float = 0.004
    max_window_tracks_per_camera: int = 150
    # rolling-shutter rows in the epipolar factors: each observation with its row's exposure time
    # (DESIGN 11, "Rolling shutter"); off: one capture time per image (the readout's measured cost is small,
    # and the rows' extrapolation with the twist frozen at graph construction biased the hilly route's hitch)
    rolling_shutter_rows: bool = False
    lm_max_iterations: int | None = None  # None: 10 (VoConfig.lm_iterations); LM stops earlier at lm_relative_error_tol
    lm_lambda_initial: float = 1.0
    lm_relative_error_tol: float = 1e-4
    # an epipolar factor whose keyframe pairs' relative motions moved less than this (rad; translation per
    # metre of chord) since its last full evaluation gives its Gauss-Newton model there (iSAM2's fluid
    # relinearisation; 1e-3 moves a row by ~0.5 px at 500 px focal length, the model's own error is
    # second order, ~1e-3 px; 0: every evaluation in full; DESIGN 11)
    relinearize_threshold: float = 1e-3
    marginals: bool = True

    def validate(self, where: str) -> None:
        for name in (
            "lag_s", "pixel_sigma", "huber_k", "nonholonomic_sigma_m", "nonholonomic_slip_deg", "trailer_nonholonomic_slip_deg", "nonholonomic_slip_deg_per_mps2", "planar_rotation_sigma_deg",
            "suspension_roll_deg_per_mps2", "suspension_pitch_deg_per_mps2",
            "planar_height_sigma_m", "joint_loop_rotation_sigma_deg", "joint_loop_translation_sigma_m", "joint_loop_pitch_sigma_deg",
            "prior_rotation_sigma_deg", "prior_translation_sigma_m", "hitch_prior_sigma_deg", "hitch_limit_deg",
            "hitch_random_walk_deg_per_m", "hitch_hold_sigma_growth_deg_per_s", "lm_lambda_initial",
            "standstill_rotation_sigma_deg", "standstill_translation_sigma_m", "weak_motion_rotation_sigma_deg",
            "weak_motion_translation_sigma_m", "gate_px",
            "lm_relative_error_tol",
        ):
            _positive(getattr(self, name), where + name)
        _at_least(self.nonholonomic_slip_correlation_s, 0.0, where + "nonholonomic_slip_correlation_s")
        if self.lm_max_iterations is not None:
            _at_least(self.lm_max_iterations, 1, where + "lm_max_iterations")
        if self.trailer_crab_sigma_deg is not None:
            _positive(self.trailer_crab_sigma_deg, where + "trailer_crab_sigma_deg")
            _positive(self.trailer_crab_random_walk_deg_per_sqrt_100m, where + "trailer_crab_random_walk_deg_per_sqrt_100m")
        if not self.hitch_limit_deg < 180.0:
            raise _error(where + "hitch_limit_deg", f"must be below 180, got {self.hitch_limit_deg}")
        _at_least(self.max_window_tracks_per_camera, 2, where + "max_window_tracks_per_camera")
        _at_least(self.max_pair_gap, 1, where + "max_pair_gap")
        _at_least(self.camera_mount_sigma_deg, 0.0, where + "camera_mount_sigma_deg")
        _at_least(self.camera_mount_sigma_deg_per_mps, 0.0, where + "camera_mount_sigma_deg_per_mps")
        _at_least(self.relinearize_threshold, 0.0, where + "relinearize_threshold")


@dataclass(frozen=True)
class ScaleConfig:
    """Aids for metric scale (DESIGN 2.3): a smooth-speed prior between consecutive keyframes
    (``null`` disables it) and the optional wheel-speed factor (off by default; ``wheel_speed_source``:
    a log topic or CSV of the rear-axle speed, ``ampc_vo.io.wheel_speed``).

    ``ground_plane``: measure the tractor axle chord from road points seen by the tractor cameras
    and their known height above the road (``ampc_vo.scale.ground``; needs the cameras' pitch
    relative to the road calibrated in the rig; the road plane is z = -``hitch_height`` of rig.yaml in
    the body frame); ``ground_height_sigma_m``: uncertainty of
    the cameras' height above the road (suspension, camber); ``ground_normal_sigma_deg``: of their
    pitch and roll relative to the road (calibration, load, braking) when the calibrated plane is used;
    ``ground_plane_fit``: estimate the road plane's normal from the road points instead (grades,
    crown, suspension pitch; DESIGN 11), the calibrated normal a prior of
    ``ground_normal_prior_sigma_deg`` per axis. ``ground_lane_half_width_m``, ``ground_lane_length_m``:
    road points from the truck's own lane only (within that distance of its path and along it from
    the axle; the crown, shoulders and verges beyond slope otherwise; null: the whole view) when
    there are enough there, else the whole view, or twice the lane's width where that measures another
    chord (``ampc_vo.scale.ground``, "Own lane"). ``cross_camera``: epipolar
    correspondences between two cameras of one body at different keyframes, associated by
    ``CameraObservations.landmark_ids`` (two-camera GEC: metric scale observable in straight driving),
    up to ``cross_camera_max_gap`` keyframes apart (``max_pair_gap`` in the single-body modes), gated at ``cross_camera_gate_px`` under the
    initial poses (looser than ``smoother.gate_px``: the initial chord may be off in scale)."""

    smooth_speed_sigma_mps2: float | None = 1.0
    wheel_speed: bool = False
    wheel_speed_sigma_m: float = 0.05
    # the wheel odometry's scale (tyre radius, wear, load and pressure: a per cent or two) as a variable
    # calibrated online by the other metric sources (issue 15): its prior sigma at the first keyframe and
    # its random walk per sqrt(km) driven. None (the default): the wheel is taken as calibrated, as the
    # cameras' height is. Online, the wheel's scale follows the cameras' where their scale is biased
    # (realistic motorway on images: ground chords 4 % short, calibrated 1.047 for a truth of 1.01 at any
    # prior sigma, 1.10 % ATE; taken as calibrated 0.36 %), and making the cameras' scale error a variable
    # of its own instead lets the metric priors (smooth speed, planar, non-holonomic residuals in metres,
    # all smaller on a smaller trajectory) shrink the scale unchecked (ground scale 1.4-2.3, ATE 6-8 %)
    wheel_scale_sigma: float | None = None
    wheel_scale_random_walk_per_sqrt_km: float = 0.005
    # where the wheel speed comes from (issue 15): a topic of the log (TwistStamped, Odometry) or a
    # CSV file ``timestamp,speed``; None: the dataset folder's wheel_speed.csv when there is one
    wheel_speed_source: str | None = None
    ground_plane: bool = True
    ground_height_sigma_m: float = 0.02
    ground_normal_sigma_deg: float = 0.0
    ground_plane_fit: bool = True
    ground_normal_prior_sigma_deg: float = 2.0
    ground_lane_half_width_m: float | None = 2.0
    ground_lane_length_m: float = 40.0
    # the measured chords are those of the path between the times their road points were seen
    # (camera offsets, rolling-shutter rows), not between the keyframe times: a speed change
    # within the delay makes them differ (a braking truck's ground chords read short; DESIGN 11)
    capture_time_chords: bool = True
    cross_camera: bool = True
    cross_camera_max_gap: int = 1
    cross_camera_gate_px: float = 10.0
    # chord of the tractor axle from points triangulated by two cameras of the tractor in the same
    # frame (equal landmark_ids; KITTI's stereo pair): initial chord and a robust chord factor
    # (ampc_vo.scale.stereo); points up to stereo_max_depth_m are used
    stereo_chord: bool = False
    stereo_max_depth_m: float = 40.0
    bootstrap_pairs: int = 3
    bootstrap_interval_s: float = 0.5
    bootstrap_max_s: float = 30.0

    def validate(self, where: str) -> None:
        _at_least(self.bootstrap_pairs, 1, where + "bootstrap_pairs")
        _positive(self.bootstrap_interval_s, where + "bootstrap_interval_s")
        _positive(self.bootstrap_max_s, where + "bootstrap_max_s")
        if self.smooth_speed_sigma_mps2 is not None:
            _positive(self.smooth_speed_sigma_mps2, where + "smooth_speed_sigma_mps2")
        _positive(self.wheel_speed_sigma_m, where + "wheel_speed_sigma_m")
        if self.wheel_scale_sigma is not None:
            _positive(self.wheel_scale_sigma, where + "wheel_scale_sigma")
        _positive(self.wheel_scale_random_walk_per_sqrt_km, where + "wheel_scale_random_walk_per_sqrt_km")
        _positive(self.ground_height_sigma_m, where + "ground_height_sigma_m")
        _at_least(self.ground_normal_sigma_deg, 0.0, where + "ground_normal_sigma_deg")
        _positive(self.ground_normal_prior_sigma_deg, where + "ground_normal_prior_sigma_deg")
        if self.ground_lane_half_width_m is not None:
            _positive(self.ground_lane_half_width_m, where + "ground_lane_half_width_m")
        _positive(self.ground_lane_length_m, where + "ground_lane_length_m")
        _at_least(self.cross_camera_max_gap, 1, where + "cross_camera_max_gap")
        _positive(self.cross_camera_gate_px, where + "cross_camera_gate_px")
        _positive(self.stereo_max_depth_m, where + "stereo_max_depth_m")


@dataclass(frozen=True)
class RecordingConfig:
    """What a Rerun recording (``run_odometry.py --rerun``) holds: about 70 kB per 640x480 image at
    quality 85, so a long run with 4 cameras wants ``image_every`` > 1 or a lower quality."""

    image_every: int = 1          # log camera images every N-th frame (0: never; features are logged every frame)
    jpeg_quality: int = 85        # JPEG quality of the logged images (1-100)
    trajectory_every: int = 10    # re-log the trajectory line strips every N-th frame

    def validate(self, where: str) -> None:
        _at_least(self.image_every, 0, where + "image_every")
        _at_least(self.trajectory_every, 0, where + "trajectory_every")
        if not 1 <= self.jpeg_quality <= 100:
            raise _error(where + "jpeg_quality", f"must be in [1, 100], got {self.jpeg_quality}")


@dataclass(frozen=True)
class OutputConfig:
    """What the pipeline writes and logs."""

    log_level: str = "INFO"
    progress: bool = True
    write_timing: bool = True
    publish: str = "lagged"
    # latest: the keyframes of the start (the scale bootstrap's) are published once the newest
    # keyframe's hitch sigma is at most this, or smoother.lag_s after the bootstrap; null: at its end
    latest_start_hitch_sigma_deg: float | None = 1.0

    def validate(self, where: str) -> None:
        if self.publish not in PUBLISH_POLICIES:
            raise _error(where + "publish", f"must be one of {PUBLISH_POLICIES}, got {self.publish!r}")
        if self.latest_start_hitch_sigma_deg is not None and not self.latest_start_hitch_sigma_deg > 0:
            raise _error(where + "latest_start_hitch_sigma_deg", f"must be > 0 or null, got {self.latest_start_hitch_sigma_deg}")
        if self.log_level.upper() not in LOG_LEVELS:
            raise _error(where + "log_level", f"must be one of {LOG_LEVELS}, got {self.log_level!r}")


@dataclass(frozen=True)
class VoConfig:
    """The whole odometry configuration. ``mode``: one of :data:`MODES` (issue 5)."""

    mode: str = "full"
    source: str = "auto"
    threads: int = 2   # image sources: cameras tracked in parallel threads (OpenCV releases the GIL)
    # image sources: where the next frame is decoded and tracked while the backend works on this one:
    # process (its own process: no GIL shared with the backend), thread (a worker thread), none (in turn)
    frontend_worker: str = "process"
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    ransac: RansacConfig = field(default_factory=RansacConfig)
    smoother: SmootherConfig = field(default_factory=SmootherConfig)
    scale: ScaleConfig = field(default_factory=ScaleConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    rerun: RecordingConfig = field(default_factory=RecordingConfig)
    frontend: TrackerConfig = field(default_factory=TrackerConfig)   # validated on construction
    stereo: StereoConfig = field(default_factory=StereoConfig)        # overlapping pairs (KITTI)

    def validate(self, where: str = "") -> None:
        if self.mode not in MODES:
            raise _error(where + "mode", f"unknown mode {self.mode!r} (expected one of {MODES})")
        _at_least(self.threads, 1, where + "threads")
        if self.frontend_worker not in FRONTEND_WORKERS:
            raise _error(where + "frontend_worker", f"unknown frontend_worker {self.frontend_worker!r} (expected one of {FRONTEND_WORKERS})")
        if self.source not in SOURCES:
            raise _error(where + "source", f"unknown source {self.source!r} (expected one of {SOURCES})")
        for section in ("keyframes", "ransac", "smoother", "scale", "output", "rerun"):
            getattr(self, section).validate(f"{where}{section}.")

    @property
    def lm_iterations(self) -> int:
        """LM iterations per smoother update at most: ``smoother.lm_max_iterations``, by default 10
        in both publish modes (LM stops at ``lm_relative_error_tol``, so a converged window costs
        one or two steps). One step per update is not enough after a standing start: the first
        moving keyframes linearise the hitch far from the truth and a single damped step leaves it
        there with a confident marginal (DESIGN 11)."""
        if self.smoother.lm_max_iterations is not None:
            return self.smoother.lm_max_iterations
        return 10

    def with_mode(self, mode: str) -> "VoConfig":
        """A copy with another mode (validated)."""
        changed = dataclasses.replace(self, mode=mode)
        try:
            changed.validate()
        except _FieldError as error:
            raise ConfigError(str(error)) from None
        return changed


# ---------------------------------------------------------------------- validation helpers
class _FieldError(Exception):
    """A problem with one field; turned into a ConfigError with the file name by the loader."""

    def __init__(self, where: str, problem: str) -> None:
        super().__init__(f"{where}: {problem}")
        self.where = where
        self.problem = problem


def _error(where: str, problem: str) -> _FieldError:
    return _FieldError(where, problem)


def _positive(value: float, where: str) -> None:
    if not value > 0:
        raise _error(where, f"must be > 0, got {value}")


def _at_least(value: float, minimum: float, where: str) -> None:
    if not value >= minimum:
        raise _error(where, f"must be >= {minimum}, got {value}")


def _convert(value: Any, annotation: Any, where: str) -> Any:
    """Check and convert one scalar against its field type (float, int, bool, str, Optional)."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        arguments = [argument for argument in typing.get_args(annotation) if argument is not type(None)]
        if value is None:
            return None
        return _convert(value, arguments[0], where)
    if annotation is bool:
        if not isinstance(value, bool):
            raise _error(where, f"expected true or false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _error(where, f"expected an integer, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _error(where, f"expected a number, got {value!r}")
        if not math.isfinite(value):  # YAML .inf / .nan: no setting of ours means "without limit"
            raise _error(where, f"must be a finite number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise _error(where, f"expected a string, got {value!r}")
        return value
    raise _error(where, f"unsupported field type {annotation!r}")  # pragma: no cover


# keys that moved: a config that still sets one is told where it went
_MOVED_KEYS = {"scale.ground_z_m": "replaced by hitch_height in rig.yaml (the road plane is z = -hitch_height)"}


def _section_from_dict(cls: type, raw: Any, where: str) -> Any:
    if raw is None:
        return cls()
    if not isinstance(raw, dict):
        raise _error(where.rstrip("."), f"expected a mapping, got {raw!r}")
    hints = typing.get_type_hints(cls)
    names = [item.name for item in dataclasses.fields(cls)]
    unknown = sorted(set(raw) - set(names))
    for key in unknown:
        if where + str(key) in _MOVED_KEYS:
            raise _error(where + str(key), _MOVED_KEYS[where + str(key)])
    if unknown:
        raise _error(where + str(unknown[0]), f"unknown key (known keys: {', '.join(names)})")
    values = {}
    for name, value in raw.items():
        annotation = hints[name]
        if dataclasses.is_dataclass(annotation):
            values[name] = _section_from_dict(annotation, value, f"{where}{name}.")
        else:
            values[name] = _convert(value, annotation, where + name)
    try:
        return cls(**values)
    except ConfigError as error:  # sections that validate themselves on construction (frontend)
        section = where.rstrip(".") or cls.__name__
        raise _error(section, str(error).removeprefix(section + ": ")) from None


def config_from_dict(raw: Any, source: str = "config") -> VoConfig:
    """Build and validate a :class:`VoConfig` from a parsed YAML mapping (``None`` = defaults)."""
    try:
        config = _section_from_dict(VoConfig, raw if raw is not None else {}, "")
        config.validate()
    except _FieldError as error:
        raise ConfigError(f"{source}: {error.where or 'top level'}: {error.problem}") from None
    return config


def load_config(path: str | Path | None = None) -> VoConfig:
    """Read and validate a VO config file; ``None`` gives the defaults."""
    if path is None:
        return VoConfig()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as error:  # a binary or non-UTF-8 file too
        raise ConfigError(f"{path}: not valid YAML: {error}") from None
    return config_from_dict(raw, source=str(path))


def config_to_dict(config: VoConfig) -> dict:
    """The YAML mapping of a config (inverse of :func:`config_from_dict`)."""
    return dataclasses.asdict(config)


def config_yaml(config: VoConfig) -> str:
    """A config as YAML text (what :func:`save_config` writes)."""
    return yaml.safe_dump(config_to_dict(config), sort_keys=False)


def save_config(config: VoConfig, path: str | Path) -> None:
    """Write a config as YAML (e.g. beside the outputs of a run, for reproducibility)."""
    Path(path).write_text(config_yaml(config), encoding="utf-8")
