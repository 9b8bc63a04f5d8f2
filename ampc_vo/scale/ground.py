"""Metric scale from the ground plane: the tractor axle chord between two keyframes, measured from
road points seen by a tractor camera whose height above the road is known from the rig.

Why: with intra-camera correspondences, metric scale is unobservable in straight driving (DESIGN
2.3). The camera's height above the road is a metric length the images can compare against: the
classic monocular-VO scale source (e.g. Kitt et al., IV 2011; Song and Chandraker, CVPR 2014).

**Derivation** (body frame i, DESIGN 1 conventions). Camera centre ``c`` (``T_body_camera``),
rigid axle midpoint ``m = (axle_x, 0, 0)``, body motion ``T_i_j = (R, t)`` with the rotation
known and the scale unknown. Body-frame bearings ``f = R_body_camera f_i`` (view i) and
``g = R R_body_camera f_j`` (view j, rotated into frame i). The unknown scale is the length ``rho``
of the axle chord, whose direction ``d`` is known from the given motion (the (NH) family of DESIGN
2: ``d ∝ R m + t - m``):

    t(rho) = rho d + m - R m,     b(rho) = R c + t(rho) - c = b0 + rho d,     b0 = (R - I)(c - m)

(``b`` is the camera baseline; for a pure translation ``b0 = 0`` and ``rho`` is a plain scale).
Midpoint triangulation of the rays ``c + lambda f`` and ``c + b + mu g`` (``k = f.g``):

    lambda = (f.b - k g.b) / (1 - k²),     mu = (k f.b - g.b) / (1 - k²),
    X = c + (lambda f + b + mu g) / 2,

is linear in ``b``, so the point's height is ``X_z = c_z + w.b`` with

    w = (e_z + f_z (f - k g) / (1 - k²) + g_z (k f - g) / (1 - k²)) / 2.

A road point has ``X_z = z_g`` (road height in the body frame, camera height ``h = c_z - z_g``):

    rho_k = -(h + w.b0) / (w.d)                                                       (G)

For a pure translation ``rho_k = h / h_unit,k`` with ``h_unit,k = -w.d`` the camera height above
the point triangulated at unit scale: the textbook ratio "known height over unit-scale height".

**Selecting the road.** Every road point gives the same ``rho_k``; a point at height ``z_p``
between the road and the camera gives ``rho_k ≈ rho h / (c_z - z_p) > rho`` (it is read as a
farther road point), points above the camera give no admissible value. Candidates are points below
the horizon in both views (body frame) with enough parallax and positive depths. Their per-point
sigmas come from propagating the bearing noise (``pixel_sigma / focal``) through (G) (numerical
derivatives along the bearings' tangent planes). The road is the consensus set of a 1-D MSAC over
the candidates' ``rho_k`` (every candidate is a hypothesis; residuals normalised by the per-point
sigmas) -- equivalently the dominant horizontal plane below the camera at unit scale. The
consensus set must span an area on the road (a row of wall points at one height is a horizontal
line, consistent with a plane at another scale). The chord is the inverse-variance mean of the
consensus set (re-selected a few times); its sigma is the formal one inflated by the Birge ratio
(spread of the per-point values vs. their sigmas) and combined with the camera-height uncertainty
(``height_sigma_m``: suspension, road camber), ``sigma_rho / rho = sigma_h / h``, and with the
road-normal uncertainty (``normal_sigma``), propagated through (G) with the normal n in place of
``e_z`` (``w = (n + (f.n) (f - k g) / (1 - k²) + (g.n) (k f - g) / (1 - k²)) / 2``).

**Road plane** (issue 16; ``fit_plane``, the default). The plane (G) measures from is estimated
from the road points instead of trusted: a body pitch of 0.3-3° (braking, a grade change under the
axles) or a crown tilts the road seen from the cameras, and (G) with the calibrated normal is off
by ``D δ / h`` (below). The normal is ``n(a, b) ∝ (tan a, tan b, 1)`` (tilts about body y and x);
the camera's distance to the plane stays the calibrated height (the metric reference). In
inverse chords ``q_k(n) = 1 / rho_k(n)`` (the unit-scale point's distance to the plane over the
camera's: nearly linear in the bearings, ``rho_k`` is skewed for far points) every road point
says ``q_k(n) = q``; the fit minimises ``sum ((q - q_k(n)) / sigma_q,k)² + |(a, b)|² / sigma_n²``
(the calibrated normal a prior, ``normal_prior_sigma`` 2°) by Gauss-Newton, starting from the best
of a few pitch hypotheses (1-D MSAC per hypothesis) and re-selecting the inliers at each plane.
The chord's sigma is its marginal (the tilt's uncertainty included), Birge-inflated, with the
height term. ``fit_plane=False``: the calibrated plane, ``normal_sigma`` widening its sigma.

**Own lane** (issue 16; ``lane_half_width_m``, ``lane_length_m``). The road is a plane only
locally: a crown turns the cross-slope over at the centre line (2-3 % each way), shoulders and
verges slope otherwise, and a vertical curve bends the road away from the plane under the axles
(by ``x² / 2K``, 10 cm at 20 m on a K = 2000 m curve). Seen from a camera 2-3 m high, road points
5-30 cm off the plane bias their chord by that over the height: on a crowned road the whole view
gave chords 3 % short (the other lane lies below the own lane's plane extended). The road points
are therefore taken from the truck's own lane, where its axles stand on the plane (G) assumes:
the bearings meeting the calibrated road plane within ``lane_half_width_m`` (2 m: half a 3.5-3.75
m lane plus its markings) of the axle's path and within ``lane_length_m`` (40 m) of the axle along
it. Ahead the path is a circular arc of the motion's curvature; behind it is the road driven
(``driven``: the last keyframes' motions chained backwards, the oldest piece extended straight to
``lane_length_m``), as the arc extrapolated backwards leaves the road where the curvature changes:
entering a 20 m radius turn it lies 10 m to the side 20 m behind, where the mirror cameras look at
the straight road the truck came on (realistic stop_and_go, images). The lane is used when at least
``min_lane_points`` (8, as ``min_points``: the plane's tilt and chord with some redundancy)
candidates lie there; else the whole view, unless the candidates within twice the half width
(the neighbouring lanes' halves: the far side of a crown lies at most a few cm off the lane's plane
there) measure a chord that differs from the whole view's by more than ``lane_consistency_sigmas``
(2) times the spread of the difference of two nested estimates, ``sqrt(sigma_band^2 -
sigma_whole^2)`` (Hausman's test: under one road plane the band and the whole view agree, and the
whole view, with more points, is kept; a standing start's few metres of chord, where the band's
points are too few to tell, keep the whole view too). Points beyond the lane (the whole view or
the band) see the road's shape there: a cross-slope change ``c`` at the lane's edge (a crown's
2 x 2.5 %, shoulders, the crossing roads of an intersection) puts a point ``d`` beyond it ``c d``
below the lane's plane, and (G) reads it ``1 + c d / h`` too far, in the same direction for the
points on that side, so their number does not shrink the error. The fitted plane therefore
estimates that fall on either side with the plane (``off_lane_slope_sigma``, 5 %, its prior):
each point's inverse chord modelled as ``q_k / (1 + c_side d_k / h)``, ``d_k`` its distance beyond
the edge where its ray meets the calibrated plane; the fall's uncertainty is in the chord's
marginal. The chord's sigma is widened as well (with the calibrated plane, ``fit_plane`` off, it is
all there is): the mean of ``d / h`` over the road points times that sigma, added in quadrature,
since beyond the lane the road is a hinge only along a carriageway (crossing roads at an
intersection, kerbs and verges are not; without the widening the fitted chords of stop_and_go's
turn carried the hitch 0.7° off at a sigma of 0.17°). In the
realistic stop_and_go's 90° turn on images the whole view read the chords 5-7 % short with sigmas
of 1 % (-5 to -8 sigma), the hitch angle that follows them 0.66° off at 2σ = 0.4°; with the
off-lane sigma the turn leans on its other metric sources. Rendered images of plain asphalt hold few
points in the own lane (a median of 3 on the motorway's cab and mirror cameras): the whole view,
which 93 % of its keyframes fell back to, read their chords 4 % short (0.959 of the truth with the
true motion, the lane's 0.998; ``tests/scale``: the band's error a fifth of the whole view's). The lane's
texture is sparse (lane markings and worn patches on plain asphalt): with 15 points and 25 m the
own lane fell back to the crowned whole view on most keyframes of the simulated motorway and its
chord read 3 % short (ground chords with the true motion, median over its frames 100-1000: 0.967
of the truth; with 8 points and 40 m 1.000, the hilly road 0.994 -> 1.002, the city 0.990 ->
1.003). A vertical curve bends the road by up to 40 cm at 40 m (K = 2000 m), but points that far
ahead carry little weight in the inverse-variance chord, and the plane's pitch is fitted.
The lane is also where the traffic ahead drives: a vehicle moving along the truck's path, and its
shadow on the road, are consistent with the ego-motion's epipolar geometry at
another depth and read as chords tens of % short. So the lane's points are those within
``lane_consensus_tolerance`` (15 %) of the whole view's road (1-D consensus over every
candidate, where the static road is the majority). The lane's points may lie on one line (a lane
marking, the rest of the lane hidden by the vehicle ahead in stop-and-go traffic): outside the
lane a row of points at one height is rejected (a wall's row fits a horizontal plane), in the lane
it lies on the road, and with the fitted plane its chord stands, the tilt across the line taken
from the prior and its uncertainty in the chord's marginal (a marking 1.8 m to the side with the
prior's 2° of roll: about 2.5 % at a camera 2.5 m high). The pair where stop_and_go's hard braking
begins had only its right marking in view and no chord, and the smoother's made-up chord read
0.17 m short there.

**Capture times** (rolling shutter, unsynchronised cameras) and the chord's time: the chord is of
the path between the points' capture times (mean delay ``MotionInit.scale_chord_delay_s``, used by
the smoother, DESIGN 11 "Capture-time chords").

A point is seen at its own times:
its camera's image time plus its row's readout (``Camera.row_times``), in both keyframes. Over a
constant-velocity arc the body moves by the keyframes' motion times ``s_k = (tau_j - tau_i) /
(t_j - t_i)`` between the point's two observations, so (G) measures ``s_k rho``: each point's
chord is divided by its ``s_k``. With a 30 ms readout a road point that moves 100 rows between
keyframes 0.1 s apart is seen over 106 ms: forward cameras (road points move down the image)
read chords ~4 % long at 25 m/s, cameras looking back ~6 % short (bearings of the realistic
motorway), where the keyframes' own rotation is kept (its share is second order).

**Sensitivities** (what the measurement trusts). A road normal off by δ (e.g. an uncalibrated
camera pitch) biases the chord by about ``D δ / h`` for road points at distance D: 1° at 10 m and
1.65 m height is ~10 %, so the cameras' pitch relative to the road must be calibrated in the rig
(KITTI: the cameras look ~1.2° below the direction of travel). A yaw error of the given motion
hardly moves a forward camera's chord but biases a side camera's (~6 % per degree on the default
rig's left camera): with ``yaw_sigma`` the cameras' chords are combined by generalised least
squares with that common error (:func:`_combine_cameras`). The camera height enters linearly.
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ampc_vo.geometry import check_bearings, rot_z, yaw_of
from ampc_vo.rig import Camera

logger = logging.getLogger(__name__)

_E_Z = np.array([0.0, 0.0, 1.0])
_DIFFERENCE_STEP = 1e-6  # radians, bearing perturbation of the numerical sigma propagation


class GroundScaleStatus(str, Enum):
    """Outcome of a ground-plane chord measurement (``OK`` or why there is none)."""

    OK = "ok"
    NO_MOTION_DIRECTION = "no_motion_direction"    # the given motion has no axle displacement
    SMALL_BASELINE = "small_baseline"              # too little parallax (standstill)
    TOO_FEW_GROUND_POINTS = "too_few_ground_points"
    GROUND_ON_A_LINE = "ground_on_a_line"          # the consensus points do not span an area (a wall's row)
    CAMERA_NOT_ABOVE_ROAD = "camera_not_above_road"


@dataclass(frozen=True)
class GroundScaleOptions:
    """Options of :func:`ground_plane_chord` (radians, metres).

    ``ground_z``: z of the road surface in the body frame (the simulator puts the body origin on the
    road, DESIGN 6; a real truck's hitch is ~1.2 m above it). ``pixel_sigma``: bearing noise in
    pixels, divided by each camera's focal length. ``height_sigma_m``: uncertainty of the camera
    height above the road. ``min_depression``: both bearings at least this far below the body's
    horizontal plane. ``min_parallax``: median parallax below this is a standstill; single points
    need ``2 * bearing sigma``. ``consensus_sigmas``: inlier threshold in per-point sigmas.
    ``max_relative_point_sigma``: points whose chord is more uncertain than this (relative to the
    consensus) are ignored. ``min_points``: fewer road inliers give no measurement.
    ``min_ground_spread_m``: the road inliers must span an area: the smaller standard deviation of
    their horizontal positions (body frame) at least this (a row of wall points at one height is
    consistent with a horizontal plane too). ``lowest_plane_support``: hypotheses with at least this
    fraction of the best support compete, and the lowest plane (smallest chord) among them wins.
    ``refine_rounds``: inlier re-selections around the weighted mean. ``normal_sigma``: uncertainty (radians) of the road normal about the body z axis (pitch and roll
    of the cameras relative to the road: calibration, load, braking), propagated into the sigma of
    the calibrated-plane chord (``fit_plane`` off; the fitted plane's sigma carries its own).
    ``fit_plane``: estimate the road plane's normal from the road points (module docstring, "Road
    plane"), the calibrated normal (body z) a prior of ``normal_prior_sigma`` (radians) per axis;
    ``normal_search``: the tilt hypotheses (radians, about the body y and x axes) the consensus
    starts from (default: the calibrated plane only; a grid lets wall points below the horizon
    buy a tilted "road" with their support); ``plane_rounds``: Gauss-Newton steps and inlier
    re-selections of the plane fit. ``lane_half_width_m``, ``lane_length_m``: the road points are
    taken from the truck's own lane (module docstring, "Own lane"): within this lateral distance of
    its path and this distance along it from the axle, when at least ``min_lane_points`` candidates
    lie there (enough for the plane's three parameters with some redundancy; ``None``: the whole view)
    and agree within ``lane_consensus_tolerance`` (relative) with the whole view's road.
    ``off_lane_slope_sigma``: prior sigma of the road's cross-slope change at the own lane's edges
    (module docstring, "Own lane"): the fitted plane estimates it per side, the calibrated plane
    widens the chord's sigma by it. ``short_chord_relative_point_sigma``: where
    ``max_relative_point_sigma`` leaves too few road points (a short chord: a point's relative sigma
    is its bearing sigma over its parallax, so at a stop or a drive-off few points pass), the chord
    is measured again with this looser test, its sigma times ``short_chord_sigma_factor`` (such
    points read the chord long by 1-3 of their sigmas; None: no second attempt). A truck braking to
    rest or driving off changes its speed most where the smooth-speed prior cannot follow.
    """

    ground_z: float = 0.0
    pixel_sigma: float = 1.0
    height_sigma_m: float = 0.02
    min_depression: float = np.deg2rad(2.0)
    min_parallax: float = 0.003
    consensus_sigmas: float = 3.0
    lane_consistency_sigmas: float = 2.0  # own lane too sparse: the points near the path replace the whole view
                                          # when their chords differ by more than this (Hausman's test)
    max_relative_point_sigma: float = 0.3
    min_points: int = 8
    min_ground_spread_m: float = 0.3
    lowest_plane_support: float = 0.5
    refine_rounds: int = 3
    normal_sigma: float = 0.0
    fit_plane: bool = True
    normal_prior_sigma: float = np.deg2rad(2.0)
    normal_search: tuple[tuple[float, ...], tuple[float, ...]] = (tuple(np.deg2rad([-3.0, -1.5, 0.0, 1.5, 3.0])), (0.0,))
    plane_rounds: int = 6
    lane_half_width_m: float | None = 2.0
    lane_length_m: float = 40.0
    min_lane_points: int = 8
    lane_consensus_tolerance: float = 0.15
    short_chord_relative_point_sigma: float | None = 1.0
    short_chord_sigma_factor: float = 3.0
    off_lane_slope_sigma: float = 0.05  # change of cross-slope beyond the own lane (a crown's 2 x 2.5 %, shoulders,
                                        # crossing roads): the sigma of a chord from points beyond it (module docstring)


def tilted_normal(tilt: np.ndarray) -> np.ndarray:
    """Unit road normal (body frame) ``(tan a, tan b, 1) / norm`` of a tilt ``(a, b)`` (radians): the
    road rising by ``tan a`` per metre along body x and ``tan b`` along body y (body pitched down /
    rolled relative to the road; ``(0, 0)``: the calibrated normal e_z)."""
    normal = np.array([np.tan(tilt[0]), np.tan(tilt[1]), 1.0])
    return normal / np.linalg.norm(normal)


@dataclass(frozen=True)
class PointChords:
    """Per-correspondence chord values (G) of one camera: ``chord`` (N,), ``sigma`` (N,), the
    ``candidate`` mask (N,) (below the horizon, parallax, positive depths, finite), the parallax
    angle (N,) and ``ground_xy`` (N, 2): body-frame x, y of the point triangulated at its chord."""

    chord: np.ndarray
    sigma: np.ndarray
    candidate: np.ndarray
    parallax: np.ndarray
    ground_xy: np.ndarray
    rays: _Rays | None = None  # what (G) needs to re-evaluate with another normal or yaw
    off_lane: np.ndarray | None = None  # (N,) signed metres beyond the own lane's edge (+ left, - right, 0 inside; None: no lane)

    def off_lane_ratios(self) -> np.ndarray:
        """(N, 2): metres beyond the lane's left and right edges over the camera's height (the
        sensitivity of (G) to the road's fall there, module docstring "Own lane"); zeros without a lane."""
        if self.off_lane is None or self.rays is None:
            return np.zeros((self.chord.shape[0], 2))
        return np.column_stack([np.maximum(self.off_lane, 0.0), np.maximum(-self.off_lane, 0.0)]) / self.rays.height

    def chords_for_normal(self, normal: np.ndarray) -> np.ndarray:
        """(G) of every correspondence for a tilted road normal (body frame, unit)."""
        return self.chord if self.rays is None else self.rays.chords(normal=normal)

    def chords_for_yaw(self, yaw_error: float) -> np.ndarray:
        """(G) of every correspondence if the motion's yaw change were ``yaw_error`` larger."""
        return self.chord if self.rays is None else self.rays.chords(normal=self.rays.normal, yaw_error=yaw_error)

    def with_normal(self, normal: np.ndarray) -> PointChords:
        """The same correspondences measured from a road plane with ``normal`` (body frame, unit):
        ``chord`` and later yaw re-evaluations use it."""
        if self.rays is None:
            return self
        rays = dataclasses.replace(self.rays, normal=np.asarray(normal, dtype=float))
        return dataclasses.replace(self, chord=rays.chords(normal=rays.normal), rays=rays)


@dataclass(frozen=True)
class _Rays:
    """What (G) needs of one camera: body-frame rays f (N, 3) and g (N, 3, rotated into frame i),
    camera height h, ``baseline0``, the chord ``direction`` and the camera's ``offset`` c - m."""

    f: np.ndarray
    g: np.ndarray
    height: float
    baseline0: np.ndarray
    direction: np.ndarray
    offset: np.ndarray
    normal: np.ndarray = dataclasses.field(default_factory=lambda: _E_Z.copy())  # the road normal ``chord`` was evaluated with
    time_scale: np.ndarray | float = 1.0  # each point's observation interval over the keyframes' (module docstring, "Capture times")

    def chords(self, normal: np.ndarray | None = None, yaw_error: float = 0.0) -> np.ndarray:
        """(G) with a road ``normal`` (default body z) and the motion's yaw change increased by
        ``yaw_error`` (R -> Rz(e) R, chord direction turned by e / 2: the Ackermann family)."""
        normal = _E_Z if normal is None else normal
        if yaw_error == 0.0:
            return _chord_of_rays(self.f, self.g, self.height, self.baseline0, self.direction, normal) / self.time_scale
        turn = rot_z(yaw_error)
        baseline0 = turn @ self.baseline0 + (turn - np.eye(3)) @ self.offset
        return _chord_of_rays(self.f, self.g @ turn.T, self.height, baseline0, rot_z(0.5 * yaw_error) @ self.direction, normal) / self.time_scale


@dataclass(frozen=True)
class GroundChord:
    """Result of :func:`ground_plane_chord`: the metric chord of the tractor axle midpoint and its
    1-sigma (metres), or ``None`` with the ``status`` saying why. ``inliers``: per camera, the mask
    of the correspondences taken as road points; ``candidates``: candidate count."""

    status: GroundScaleStatus
    chord: float | None = None
    sigma: float | None = None
    inliers: tuple[np.ndarray, ...] = ()
    candidates: int = 0

    @property
    def ok(self) -> bool:
        return self.status is GroundScaleStatus.OK

    @property
    def inlier_count(self) -> int:
        return int(sum(int(np.count_nonzero(mask)) for mask in self.inliers))

    def as_scale_chord(self) -> tuple[float, float] | None:
        """``(chord, sigma)`` for :class:`ampc_vo.backend.smoother.MotionInit.scale_chord`, or ``None``."""
        return (float(self.chord), float(self.sigma)) if self.ok else None


def axle_displacement(T_i_j: np.ndarray, axle_x: float) -> np.ndarray:
    """The axle midpoint's displacement ``R m + t - m`` (3,) of a motion ``T_i_j``, body frame i,
    ``m = (axle_x, 0, 0)`` (DESIGN 2 (NH))."""
    axle = np.array([axle_x, 0.0, 0.0])
    return T_i_j[:3, :3] @ axle + T_i_j[:3, 3] - axle


def axle_chord_direction(T_i_j: np.ndarray, axle_x: float) -> np.ndarray | None:
    """Unit direction ``d`` of the axle displacement ``R m + t - m`` of a motion (DESIGN 2 (NH)),
    or ``None`` when the motion does not move the axle."""
    displacement = axle_displacement(T_i_j, axle_x)
    norm = float(np.linalg.norm(displacement))
    return displacement / norm if norm > 1e-9 and np.isfinite(norm) else None


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _chord_of_rays(f: np.ndarray, g: np.ndarray, height: float, baseline0: np.ndarray, direction: np.ndarray, normal: np.ndarray = _E_Z) -> np.ndarray:
    """Equation (G) for body-frame rays ``f`` (view i) and ``g`` (view j in frame i), shapes (N, 3):
    the chord ``rho`` (N,), NaN where the rays are parallel or the height does not change with it.
    With a tilted road ``normal`` n, ``e_z``, ``f_z``, ``g_z`` in ``w`` become n, f.n, g.n."""
    k = _rowdot(f, g)
    denominator = 1.0 - k * k
    safe = np.where(denominator > 1e-15, denominator, np.nan)
    f_n, g_n = f @ normal, g @ normal
    w = 0.5 * (normal + (f_n / safe)[:, None] * (f - k[:, None] * g) + (g_n / safe)[:, None] * (k[:, None] * f - g))
    with np.errstate(divide="ignore", invalid="ignore"):
        return -(height + w @ baseline0) / (w @ direction)


def _tangent_basis(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) orthogonal to each unit vector (N, 3) and to each other."""
    x, y, z = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    use_x = np.abs(x) < 0.9  # helper axis e_x, else e_y: first = v x helper
    first = np.where(use_x[:, None], np.column_stack([np.zeros_like(x), z, -y]), np.column_stack([-z, np.zeros_like(x), x]))
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    second = np.column_stack([y * first[:, 2] - z * first[:, 1], z * first[:, 0] - x * first[:, 2], x * first[:, 1] - y * first[:, 0]])
    return first, second


def point_chords(camera: Camera, bearings_i: np.ndarray, bearings_j: np.ndarray, T_i_j: np.ndarray, axle_x: float,
                 options: GroundScaleOptions = GroundScaleOptions(), time_scale: np.ndarray | None = None) -> PointChords:
    """Equation (G) and its propagated sigma for every correspondence of one camera (module docstring).

    ``bearings_i``, ``bearings_j``: (N, 3) camera-frame bearings of the same points in keyframes i
    and j; ``T_i_j``: body motion (rotation trusted, translation only for the chord direction).
    ``time_scale`` (N,): each point's time between its two observations over the keyframes'
    interval (rolling shutter, unsynchronised cameras; module docstring, "Capture times"); None: 1.
    Raises :class:`ampc_vo.errors.BearingError` for malformed bearings.
    """
    bearings_i = check_bearings(bearings_i, "bearings_i")
    bearings_j = check_bearings(bearings_j, "bearings_j", count=bearings_i.shape[0])
    count = bearings_i.shape[0]
    direction = axle_chord_direction(T_i_j, axle_x)
    if direction is None or count == 0:
        return _no_point_chords(count)
    rotation, R_body_camera = T_i_j[:3, :3], camera.R_body_camera
    center = camera.center
    height = float(center[2] - options.ground_z)
    if height <= 0.0:  # a camera at or below the road sees no road from above
        return _no_point_chords(count)
    baseline0 = (rotation - np.eye(3)) @ (center - np.array([axle_x, 0.0, 0.0]))
    f = bearings_i @ R_body_camera.T
    g = bearings_j @ (rotation @ R_body_camera).T
    # (G) and its values with each bearing moved along both tangent directions (one stacked call):
    # the numerical gradient propagates the bearing noise into the sigma of rho
    f_moved = [f + _DIFFERENCE_STEP * tangent for tangent in _tangent_basis(f)]
    g_moved = [g + _DIFFERENCE_STEP * tangent for tangent in _tangent_basis(g)]
    stacked_f = np.concatenate([f, *f_moved, f, f])
    stacked_g = np.concatenate([g, g, g, *g_moved])
    stacked_f /= np.linalg.norm(stacked_f, axis=1, keepdims=True)
    stacked_g /= np.linalg.norm(stacked_g, axis=1, keepdims=True)
    scale = np.ones(count) if time_scale is None else np.asarray(time_scale, dtype=float).reshape(count)
    scale = np.where(np.isfinite(scale) & (scale > 0.0), scale, np.nan)
    values = _chord_of_rays(stacked_f, stacked_g, height, baseline0, direction).reshape(5, count) / scale
    rho = values[0]
    variance = np.sum(((values[1:] - rho) / _DIFFERENCE_STEP) ** 2, axis=0)
    parallax = np.arccos(np.clip(_rowdot(f, g), -1.0, 1.0))
    bearing_sigma = options.pixel_sigma / (0.5 * (camera.fx + camera.fy))
    sigma = bearing_sigma * np.sqrt(variance)
    # positive depths on both rays at the point's own chord (over its own observation interval)
    baseline = baseline0 + (rho * scale)[:, None] * direction
    k = _rowdot(f, g)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_i = (_rowdot(f, baseline) - k * _rowdot(g, baseline)) / (1.0 - k * k)
        depth_j = (k * _rowdot(f, baseline) - _rowdot(g, baseline)) / (1.0 - k * k)
    below = np.sin(options.min_depression)
    candidate = (
        (f[:, 2] < -below) & (g[:, 2] < -below) & (parallax > 2.0 * bearing_sigma)
        & np.isfinite(rho) & (rho > 0.0) & np.isfinite(sigma) & (depth_i > 0.0) & (depth_j > 0.0)
    )
    midpoint = center + 0.5 * (depth_i[:, None] * f + baseline + depth_j[:, None] * g)
    offset = center - np.array([axle_x, 0.0, 0.0])
    return PointChords(rho, sigma, candidate, parallax, midpoint[:, :2], _Rays(f, g, height, baseline0, direction, offset, time_scale=scale))


def path_distance(f: np.ndarray, offset: np.ndarray, height: float, curvature: float, driven: np.ndarray | None = None,
                  direction: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where body-frame bearings ``f`` (N, 3) from a camera at ``offset`` from the axle midpoint,
    ``height`` above the road, meet the calibrated road plane, relative to the axle's path:
    ``(along, lateral, downward)`` (N,) each: metres along the body from the axle, signed metres
    from the path (positive towards the body's +y, the left), and the mask of rays that meet the
    plane. The path is the arc ``y = curvature x² / 2`` (x along the body from the axle), ahead and
    behind; with ``driven`` ((M, 2) axle positions of the path driven before, relative to the axle,
    newest first), behind the axle (against ``direction``, +1 forward, -1 reversing) it is that
    polyline instead: the mirror cameras look back along the road the truck came on, which in a
    turn's entry is straight, not the turn's arc."""
    downward = f[:, 2] < 0.0
    reach = height / np.where(downward, -f[:, 2], 1.0)
    along = offset[0] + reach * f[:, 0]
    beside = offset[1] + reach * f[:, 1]
    lateral = beside - 0.5 * curvature * along**2
    if driven is not None and driven.shape[0] >= 2:
        behind = direction * along < 0.0
        distance, side = _polyline_offset(np.column_stack([along, beside]), driven)
        # the polyline runs from the axle against the direction of travel: its left is the body's right forward
        lateral = np.where(behind, -direction * side * distance, lateral)
    return along, lateral, downward


def in_own_lane(f: np.ndarray, offset: np.ndarray, height: float, curvature: float, options: GroundScaleOptions,
                driven: np.ndarray | None = None, direction: float = 1.0) -> np.ndarray:
    """Mask of body-frame bearings ``f`` (N, 3) that meet the calibrated road plane in the truck's
    own lane (module docstring, "Own lane"): within ``lane_half_width_m`` of the axle's path
    (:func:`path_distance`) and within ``lane_length_m`` of the axle along it. All True without a lane."""
    if options.lane_half_width_m is None:
        return np.ones(f.shape[0], bool)
    along, lateral, downward = path_distance(f, offset, height, curvature, driven, direction)
    return downward & (np.abs(lateral) <= options.lane_half_width_m) & (np.abs(along) <= options.lane_length_m)


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance (N,) of 2-D ``points`` (N, 2) to the polyline through ``polyline`` (M, 2), M >= 2."""
    return _polyline_offset(points, polyline)[0]


def _polyline_offset(points: np.ndarray, polyline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (N,) of 2-D ``points`` (N, 2) to the polyline through ``polyline`` (M, 2), M >= 2,
    and the side (N,): +1 left of its nearest segment (in the polyline's order), -1 right."""
    start, end = polyline[:-1], polyline[1:]
    segment = end - start
    length_squared = np.maximum(np.sum(segment**2, axis=1), 1e-12)
    relative = points[:, None, :] - start[None, :, :]
    fraction = np.clip(np.einsum("nmk,mk->nm", relative, segment) / length_squared, 0.0, 1.0)
    nearest = start[None, :, :] + fraction[:, :, None] * segment[None, :, :]
    distances = np.linalg.norm(points[:, None, :] - nearest, axis=2)
    closest = np.argmin(distances, axis=1)
    rows = np.arange(points.shape[0])
    along_segment, to_point = segment[closest], relative[rows, closest]
    side = np.where(along_segment[:, 0] * to_point[:, 1] - along_segment[:, 1] * to_point[:, 0] >= 0.0, 1.0, -1.0)
    return distances[rows, closest], side


def _consensus_road_chord(per_camera: Sequence[PointChords], options: GroundScaleOptions) -> float | None:
    """The whole view's road chord: the 1-D consensus of :func:`robust_chord` over every candidate
    (None without one): what the own lane's points must agree with (:func:`_within_lane`)."""
    chords = np.concatenate([points.chord[points.candidate] for points in per_camera])
    sigmas = np.concatenate([points.sigma[points.candidate] for points in per_camera])
    whole = robust_chord(chords, sigmas, options) if chords.size else None
    return None if whole is None else whole[0]


def _within_lane(per_camera: Sequence[PointChords], road_chord: float, curvature: float, options: GroundScaleOptions,
                 widening: float = 1.0, driven: np.ndarray | None = None, direction: float = 1.0) -> list[PointChords] | None:
    """``per_camera`` with the candidates restricted to the own lane (:func:`in_own_lane`, its half
    width ``lane_half_width_m`` times ``widening``): those that agree within
    ``lane_consensus_tolerance`` with the whole view's ``road_chord``
    (:func:`_consensus_road_chord`: moving traffic in the lane ahead and its shadow on the road,
    which the ego-motion's epipolar geometry cannot tell from the static road, read as chords tens
    of % off, the road's shape beyond the lane a few %), when at least ``min_lane_points`` remain;
    ``None`` otherwise. ``curvature``, ``driven``, ``direction``: the path ahead, the path driven
    before and the direction of travel (:func:`in_own_lane`)."""
    band = dataclasses.replace(options, lane_half_width_m=widening * options.lane_half_width_m)
    in_lane = []
    for points in per_camera:
        agrees = np.abs(points.chord - road_chord) < np.maximum(options.lane_consensus_tolerance * road_chord, options.consensus_sigmas * points.sigma)
        lane = in_own_lane(points.rays.f, points.rays.offset, points.rays.height, curvature, band, driven, direction) if points.rays is not None else False
        in_lane.append(points.candidate & agrees & lane)
    if sum(int(np.count_nonzero(mask)) for mask in in_lane) < max(options.min_lane_points, options.min_points):
        return None
    return [dataclasses.replace(points, candidate=mask) for points, mask in zip(per_camera, in_lane)]


def _no_point_chords(count: int) -> PointChords:
    return PointChords(np.full(count, np.nan), np.full(count, np.inf), np.zeros(count, bool), np.zeros(count), np.full((count, 2), np.nan))


def robust_chord(chords: np.ndarray, sigmas: np.ndarray, options: GroundScaleOptions = GroundScaleOptions()) -> tuple[float, float, np.ndarray] | None:
    """1-D MSAC consensus over per-point chords (N,) with sigmas (N,) (module docstring):
    ``(chord, statistical sigma, inlier mask)`` or ``None`` with fewer than ``min_points`` inliers.
    Every point is a hypothesis; the cost of hypothesis h is ``sum min((rho_k - rho_h)^2 /
    sigma_k^2, T^2)`` with ``T = consensus_sigmas`` (vectorised, N x N)."""
    count = chords.shape[0]
    if count < options.min_points:
        return None
    threshold = options.consensus_sigmas
    normalized = (chords[None, :] - chords[:, None]) / sigmas[None, :]
    cost = np.minimum(normalized**2, threshold**2).sum(axis=1)
    support = (np.abs(normalized) < threshold).sum(axis=1)
    # the road is the lowest horizontal plane: among well-supported hypotheses (box tops, kerbs,
    # rows of wall points can form smaller clusters at larger chords) keep the lowest cluster
    eligible = support >= max(options.min_points, options.lowest_plane_support * support.max())
    if not np.any(eligible):
        return None
    lowest = int(np.flatnonzero(eligible)[np.argmin(chords[eligible])])
    in_lowest = eligible & (np.abs(chords - chords[lowest]) < threshold * np.hypot(sigmas, sigmas[lowest]))
    estimate = float(chords[np.flatnonzero(in_lowest)[np.argmin(cost[in_lowest])]])
    inliers = np.zeros(count, bool)
    for _ in range(options.refine_rounds):
        inliers = (np.abs(chords - estimate) < threshold * sigmas) & (sigmas < options.max_relative_point_sigma * estimate)
        if np.count_nonzero(inliers) < options.min_points:
            return None
        weights = 1.0 / sigmas[inliers] ** 2
        estimate = float(np.sum(weights * chords[inliers]) / np.sum(weights))
    inliers = (np.abs(chords - estimate) < threshold * sigmas) & (sigmas < options.max_relative_point_sigma * estimate)
    used = int(np.count_nonzero(inliers))
    if used < options.min_points:
        return None
    weights = 1.0 / sigmas[inliers] ** 2
    formal = 1.0 / np.sqrt(np.sum(weights))
    birge = np.sqrt(np.sum(weights * (chords[inliers] - estimate) ** 2) / max(used - 1, 1))
    return estimate, float(formal * max(1.0, birge)), inliers


def _normal_variance(per_camera: Sequence[PointChords], inliers: np.ndarray, sigmas: np.ndarray, chord: float, options: GroundScaleOptions) -> float:
    """Variance of the chord from an uncertain road normal (``normal_sigma`` about the body x and
    y axes, common to all points): numerical derivative of the inliers' weighted mean of (G)."""
    if options.normal_sigma <= 0.0:
        return 0.0
    weights = 1.0 / sigmas[inliers] ** 2
    variance, step = 0.0, 1e-4
    for tilt in ((step, 0.0), (0.0, step)):
        normal = np.array([tilt[0], tilt[1], 1.0]) / np.hypot(1.0, step)
        tilted = np.concatenate([points.chords_for_normal(normal)[points.candidate] for points in per_camera])[inliers]
        derivative = (float(np.sum(weights * tilted) / np.sum(weights)) - chord) / step
        variance += (derivative * options.normal_sigma) ** 2 if np.isfinite(derivative) else 0.0
    return variance


@dataclass(frozen=True)
class PlaneFit:
    """The road plane fitted to the road points (module docstring, "Road plane"): ``tilt`` (2,)
    radians (:func:`tilted_normal`), the ``chord`` (m) measured from it, its marginal
    ``chord_variance`` (bearing noise and the tilt's uncertainty under its prior, Birge-inflated),
    ``tilt_variance``: the part of it the tilt's uncertainty adds, ``birge``: the Birge ratio, and
    the ``inliers`` mask over the candidates."""

    tilt: np.ndarray
    chord: float
    chord_variance: float
    tilt_variance: float
    birge: float
    inliers: np.ndarray
    off_lane_slope: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))


def _candidate_chords(per_camera: Sequence[PointChords], tilt: np.ndarray) -> np.ndarray:
    """(G) of every candidate of every camera for the road tilted by ``tilt``; values that are
    not a chord (parallel rays, a plane above the ray) become a huge chord no consensus takes."""
    normal = tilted_normal(tilt)
    chords = np.concatenate([points.chords_for_normal(normal)[points.candidate] for points in per_camera])
    return np.where(np.isfinite(chords) & (chords > 0.0), chords, 1e12)


def _search_plane(per_camera: Sequence[PointChords], sigmas: np.ndarray, options: GroundScaleOptions) -> tuple[np.ndarray, float, np.ndarray] | None:
    """The best tilt hypothesis of ``options.normal_search``: 1-D MSAC (:func:`robust_chord`) per
    tilt, scored by its MSAC cost over all candidates plus the tilt prior ``|tilt|² / sigma²``;
    ``(tilt, chord, inliers)`` or ``None`` when no hypothesis finds a road."""
    best: tuple[float, np.ndarray, float, np.ndarray] | None = None
    threshold = options.consensus_sigmas
    for pitch in options.normal_search[0]:
        for roll in options.normal_search[1]:
            tilt = np.array([pitch, roll])
            chords = _candidate_chords(per_camera, tilt)
            consensus = robust_chord(chords, sigmas, options)
            if consensus is None:
                continue
            chord = consensus[0]
            cost = float(np.sum(np.minimum(((chords - chord) / sigmas) ** 2, threshold**2)) + np.sum((tilt / options.normal_prior_sigma) ** 2))
            if best is None or cost < best[0]:
                best = (cost, tilt, chord, consensus[2])
    return None if best is None else (best[1], best[2], best[3])


def _inverse_chords(per_camera: Sequence[PointChords], tilt: np.ndarray) -> np.ndarray:
    """``1 / rho_k`` of every candidate for the road tilted by ``tilt`` (0 where there is no chord):
    the unit-scale point's distance to the plane over the camera's, nearly linear in the bearings
    (``rho_k`` itself, its inverse, is skewed for far points)."""
    chords = _candidate_chords(per_camera, tilt)
    return np.where(chords < 1e12, 1.0 / chords, 0.0)


def _modelled_inverse(inverse: np.ndarray, ratios: np.ndarray, slope: np.ndarray) -> np.ndarray:
    """The inverse chords of the candidates corrected for the road's fall beyond the own lane: a
    point ``e`` beyond the edge on a side falling by ``slope`` lies ``slope e`` below the lane's
    plane, so (G) read it ``1 + slope e / h`` too far (``ratios``: ``e / h`` per side, (N, 2))."""
    return inverse / (1.0 + ratios @ slope)


def _plane_step(per_camera: Sequence[PointChords], inverse_sigmas: np.ndarray, tilt: np.ndarray, slope: np.ndarray, inverse: np.ndarray,
                ratios: np.ndarray, inliers: np.ndarray, options: GroundScaleOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One Gauss-Newton step of the plane fit on the ``inliers`` in inverse chords: parameters
    ``x = (q, delta_tilt, delta_slope)`` with ``q = 1 / rho``, rows ``(q - m_k - J_k delta) /
    sigma_q,k`` with ``m_k = q_k(tilt) / (1 + r_k . slope)`` (:func:`_modelled_inverse`; J:
    numerical derivative in the tilt, analytic in the off-lane slopes) and the prior rows
    ``(tilt + delta) / normal_prior_sigma``, ``(slope + delta) / off_lane_slope_sigma``;
    ``inverse``: :func:`_inverse_chords` at ``tilt`` (the caller has it from the inlier selection),
    ``ratios`` (N, 2): :meth:`PointChords.off_lane_ratios` of the candidates. Returns ``(x, normal
    matrix, data residuals)``."""
    step = 1e-5
    values, lane_ratios = inverse[inliers], ratios[inliers]
    divisor = 1.0 + lane_ratios @ slope
    modelled = values / divisor
    tilt_jacobian = np.column_stack([(_inverse_chords(per_camera, tilt + step * axis)[inliers] - values) / step for axis in np.eye(2)]) / divisor[:, None]
    slope_jacobian = -(modelled / divisor)[:, None] * lane_ratios
    weights = 1.0 / inverse_sigmas[inliers]
    prior_rows = np.zeros((4, 5))
    prior_rows[:2, 1:3] = np.eye(2) / options.normal_prior_sigma
    prior_rows[2:, 3:] = np.eye(2) / options.off_lane_slope_sigma
    design = np.vstack([np.column_stack([weights, -tilt_jacobian * weights[:, None], -slope_jacobian * weights[:, None]]), prior_rows])
    target = np.concatenate([modelled * weights, -tilt / options.normal_prior_sigma, -slope / options.off_lane_slope_sigma])
    x = np.linalg.lstsq(design, target, rcond=None)[0]
    residuals = (x[0] - modelled - tilt_jacobian @ x[1:3] - slope_jacobian @ x[3:]) * weights
    return x, design.T @ design, residuals


def _plane_inliers(inverse: np.ndarray, inverse_sigmas: np.ndarray, sigmas: np.ndarray, inverse_chord: float, options: GroundScaleOptions) -> np.ndarray:
    """Road points of a plane with inverse chord ``q``: within ``consensus_sigmas`` of it, and
    precise enough (``max_relative_point_sigma``)."""
    return (np.abs(inverse - inverse_chord) < options.consensus_sigmas * inverse_sigmas) & (sigmas * inverse_chord < options.max_relative_point_sigma)


def fit_road_plane(per_camera: Sequence[PointChords], sigmas: np.ndarray, options: GroundScaleOptions) -> PlaneFit | None:
    """Road plane and chord from the candidates of ``per_camera`` (sigmas (N,) over the
    candidates): the best tilt hypothesis (:func:`_search_plane`), then ``plane_rounds`` of a
    Gauss-Newton step in inverse chords (:func:`_plane_step`, with the road's fall beyond the own
    lane on either side) and inlier re-selection at the new plane (module docstring, "Road plane").
    ``None`` when fewer than ``min_points`` road points remain."""
    found = _search_plane(per_camera, sigmas, options)
    if found is None:
        return None
    tilt, chord, inliers = found
    slope = np.zeros(2)
    ratios = np.concatenate([points.off_lane_ratios()[points.candidate] for points in per_camera])
    inverse_sigmas = sigmas / _candidate_chords(per_camera, np.zeros(2)) ** 2
    inverse = _inverse_chords(per_camera, tilt)
    for _ in range(max(options.plane_rounds, 1)):
        x, normal_matrix, residuals = _plane_step(per_camera, inverse_sigmas, tilt, slope, inverse, ratios, inliers, options)
        tilt, slope = tilt + x[1:3], slope + x[3:]
        inverse = _inverse_chords(per_camera, tilt)  # once per round: the inlier selection and the next step share it
        inliers = _plane_inliers(_modelled_inverse(inverse, ratios, slope), inverse_sigmas, sigmas, float(x[0]), options)
        if np.count_nonzero(inliers) < options.min_points:
            return None
    x, normal_matrix, residuals = _plane_step(per_camera, inverse_sigmas, tilt, slope, inverse, ratios, inliers, options)
    tilt, slope, chord = tilt + x[1:3], slope + x[3:], 1.0 / float(x[0])
    used = int(np.count_nonzero(inliers))
    birge = max(1.0, float(np.sqrt(np.sum(residuals**2) / max(used - 3, 1))))
    covariance = np.linalg.inv(normal_matrix) * birge**2
    conditional = birge**2 / normal_matrix[0, 0]  # the inverse chord's variance if the plane's shape were known
    to_chord = chord**4  # d rho / d q = -rho²
    return PlaneFit(tilt, chord, float(covariance[0, 0] * to_chord), float(max(covariance[0, 0] - conditional, 0.0) * to_chord), birge, inliers, slope)


def _formal_sigma(sigmas: np.ndarray) -> float:
    return float(1.0 / np.sqrt(np.sum(1.0 / sigmas**2)))


def _combine_cameras(per_camera: Sequence[PointChords], masks: Sequence[np.ndarray], birge: float, yaw_sigma: float) -> tuple[float, float]:
    """Generalised least squares over the cameras' chords when the motion's yaw is uncertain.

    Each camera's inlier mean ``rho_c`` (variance ``v_c``, inflated by the Birge ratio) shifts by
    ``s_c e`` for a yaw error e common to all cameras (a side camera's chord is very sensitive to
    it, a forward one's hardly: ``s_c`` numerically). Covariance ``C = diag(v_c) + yaw_sigma² s sᵀ``;
    ``rho = 1ᵀC⁻¹rho_c / 1ᵀC⁻¹1``, variance ``1 / 1ᵀC⁻¹1``."""
    means, variances, slopes = [], [], []
    step = 1e-4
    for points, mask in zip(per_camera, masks):
        if not np.any(mask):
            continue
        weights = 1.0 / points.sigma[mask] ** 2
        mean = float(np.sum(weights * points.chord[mask]) / np.sum(weights))
        turned = float(np.sum(weights * points.chords_for_yaw(step)[mask]) / np.sum(weights))
        means.append(mean)
        variances.append(birge**2 / float(np.sum(weights)))
        slopes.append((turned - mean) / step if np.isfinite(turned) else 0.0)
    means, slopes = np.array(means), np.array(slopes)
    covariance = np.diag(variances) + yaw_sigma**2 * np.outer(slopes, slopes)
    information = np.linalg.solve(covariance, np.ones(len(means)))
    total = float(np.sum(information))
    return float(information @ means / total), float(1.0 / np.sqrt(total))


def ground_plane_chord(
    correspondences: Sequence[tuple[Camera, np.ndarray, np.ndarray]],
    T_i_j: np.ndarray,
    axle_x: float,
    options: GroundScaleOptions = GroundScaleOptions(),
    yaw_sigma: float = 0.0,
    driven: np.ndarray | None = None,
) -> GroundChord:
    """Metric chord of the axle midpoint between keyframes i and j from road points
    (:func:`road_points_chord`), measured again from less precise road points with a wider sigma
    where too few precise ones remain (``options.short_chord_relative_point_sigma``)."""
    measured = road_points_chord(correspondences, T_i_j, axle_x, options, yaw_sigma, driven)
    looser = options.short_chord_relative_point_sigma
    if measured.status is not GroundScaleStatus.TOO_FEW_GROUND_POINTS or looser is None or looser <= options.max_relative_point_sigma:
        return measured
    second = road_points_chord(correspondences, T_i_j, axle_x, dataclasses.replace(options, max_relative_point_sigma=looser), yaw_sigma, driven)
    if not second.ok:
        return measured
    logger.debug("short chord from %d imprecise road points: %.4f +- %.4f m (sigma x %.1f)", second.inlier_count, second.chord, second.sigma,
                 options.short_chord_sigma_factor)
    return dataclasses.replace(second, sigma=second.sigma * options.short_chord_sigma_factor)


def road_points_chord(
    correspondences: Sequence[tuple[Camera, np.ndarray, np.ndarray]],
    T_i_j: np.ndarray,
    axle_x: float,
    options: GroundScaleOptions = GroundScaleOptions(),
    yaw_sigma: float = 0.0,
    driven: np.ndarray | None = None,
) -> GroundChord:
    """Metric chord of the axle midpoint (``axle_x``) between keyframes i and j from road points.

    ``correspondences``: per camera of the body, ``(camera, bearings_i, bearings_j)`` with (N, 3)
    camera-frame bearings of the same points in both keyframes, optionally with a fourth element,
    the points' ``time_scale`` (N,) (:func:`point_chords`; rolling shutter, unsynchronised cameras). ``T_i_j``: the body motion
    estimated up to scale (rotation, and the direction of the axle chord). All cameras' road points
    vote on the same chord. ``yaw_sigma``: uncertainty (radians) of the motion's yaw change; a
    yaw error biases each camera's chord differently (side cameras strongly), so with it the
    cameras' chords are combined by generalised least squares (:func:`_combine_cameras`). ``driven``
    ((M, 2), metres): the axle's positions on the path driven before keyframe i, relative to its
    position at i in body frame i, newest first (the own lane behind the axle follows it,
    :func:`in_own_lane`; None: the motion's arc behind as ahead). Returns a
    :class:`GroundChord` (``chord``/``sigma`` ``None`` and a status when there are too few road
    points, no motion direction, or too little parallax).
    """
    T_i_j = np.asarray(T_i_j, dtype=float)
    if axle_chord_direction(T_i_j, axle_x) is None:
        return GroundChord(GroundScaleStatus.NO_MOTION_DIRECTION)
    heights = np.array([float(correspondence[0].center[2] - options.ground_z) for correspondence in correspondences])
    if heights.size and np.all(heights <= 0.0):
        return GroundChord(GroundScaleStatus.CAMERA_NOT_ABOVE_ROAD)
    per_camera = [point_chords(*correspondence[:3], T_i_j, axle_x, options, *correspondence[3:4]) for correspondence in correspondences]
    if sum(points.chord.size for points in per_camera) == 0:
        return GroundChord(GroundScaleStatus.TOO_FEW_GROUND_POINTS)
    parallax = np.concatenate([points.parallax for points in per_camera])
    if parallax.size and float(np.median(parallax)) < options.min_parallax:
        return GroundChord(GroundScaleStatus.SMALL_BASELINE)
    # the direction of travel (-1: reversing)
    direction = 1.0 if axle_chord_direction(T_i_j, axle_x)[0] >= 0.0 else -1.0
    road_chord = _consensus_road_chord(per_camera, options) if options.lane_half_width_m is not None else None
    if road_chord is None:
        return _chord_of_points(per_camera, heights, options, yaw_sigma)
    # the path's curvature: the yaw change (its sign flipped when reversing) over the whole view's
    # road chord (the given motion's has no scale)
    curvature = direction * yaw_of(T_i_j) / road_chord
    per_camera = [_with_off_lane(points, curvature, options, driven, direction) for points in per_camera]
    lane = _within_lane(per_camera, road_chord, curvature, options, driven=driven, direction=direction)
    if lane is not None:
        return _chord_of_points(lane, heights, options, yaw_sigma, in_lane=True)
    # too few points in the own lane: the whole view, unless the points near the path (twice the
    # lane's half width) measure a different chord (the road beyond is not the lane's plane)
    whole = _chord_of_points(per_camera, heights, options, yaw_sigma)
    near = _within_lane(per_camera, road_chord, curvature, options, widening=2.0, driven=driven, direction=direction)
    band = _chord_of_points(near, heights, options, yaw_sigma) if near is not None and whole.ok else None
    # Hausman's test of nested estimates (on their statistical sigmas): the band's points are among
    # the whole view's, so under one plane the difference has the variance sigma_band^2 - sigma_whole^2
    if band is not None and band.ok and abs(band.chord - whole.chord) > options.lane_consistency_sigmas * np.sqrt(max(band.sigma**2 - whole.sigma**2, 0.0)):
        logger.debug("whole view's chord %.4f +- %.4f m differs from the %d points near the path (%.4f +- %.4f m): those taken",
                     whole.chord, whole.sigma, band.inlier_count, band.chord, band.sigma)
        return _off_lane_sigma(band, near, options)
    return _off_lane_sigma(whole, per_camera, options)


def _with_off_lane(points: PointChords, curvature: float, options: GroundScaleOptions, driven: np.ndarray | None, direction: float) -> PointChords:
    """``points`` with ``off_lane``: each ray's signed distance beyond the own lane's edge where it
    meets the calibrated road plane (:func:`path_distance`; 0 inside the lane)."""
    if points.rays is None:
        return points
    _, lateral, _ = path_distance(points.rays.f, points.rays.offset, points.rays.height, curvature, driven, direction)
    beyond = np.sign(lateral) * np.maximum(np.abs(lateral) - options.lane_half_width_m, 0.0)
    return dataclasses.replace(points, off_lane=beyond)


def _off_lane_sigma(measured: GroundChord, per_camera: Sequence[PointChords], options: GroundScaleOptions) -> GroundChord:
    """``measured`` (from road points beyond the own lane too) with its sigma widened by the road's
    shape there: a cross-slope change ``c`` (``off_lane_slope_sigma``) at the lane's edge puts a point
    ``d`` beyond it ``c d`` off the lane's plane, which reads its chord ``c d / h`` off (module docstring,
    "Own lane"), the same way for all points on that side: the mean of ``d / h`` over the road points
    times the slope sigma, added in quadrature (an error common to the points, which their number
    does not shrink)."""
    if not measured.ok or options.lane_half_width_m is None:
        return measured
    beyond = []
    for points, mask in zip(per_camera, measured.inliers):
        if points.rays is None or points.off_lane is None or not np.any(mask):
            continue
        beyond.append(np.abs(points.off_lane[mask]) / points.rays.height)  # set by _with_off_lane
    if not beyond:
        return measured
    relative = options.off_lane_slope_sigma * float(np.mean(np.concatenate(beyond)))
    return dataclasses.replace(measured, sigma=float(np.hypot(measured.sigma, measured.chord * relative)))


def _chord_of_points(per_camera: Sequence[PointChords], heights: np.ndarray, options: GroundScaleOptions, yaw_sigma: float,
                     in_lane: bool = False) -> GroundChord:
    """The chord of :func:`ground_plane_chord` from the candidate road points of ``per_camera``
    (plane fit or 1-D consensus, spread test, cameras combined, sigma with the height and normal terms).
    ``in_lane``: the candidates are the own lane's (:func:`_within_lane`), where a line of points (a
    lane marking, the rest of the lane hidden by the vehicle ahead) lies on the road: with the
    fitted plane its chord stands, the tilt the line cannot fix taken from the prior and counted
    in the sigma (module docstring, "Own lane")."""
    chords = np.concatenate([points.chord[points.candidate] for points in per_camera])
    sigmas = np.concatenate([points.sigma[points.candidate] for points in per_camera])
    plane = fit_road_plane(per_camera, sigmas, options) if options.fit_plane else None
    if options.fit_plane:
        if plane is None:
            return GroundChord(GroundScaleStatus.TOO_FEW_GROUND_POINTS, candidates=int(chords.size))
        per_camera = [points.with_normal(tilted_normal(plane.tilt)) for points in per_camera]
        chord, statistical_sigma, inliers = plane.chord, float(np.sqrt(plane.chord_variance - plane.tilt_variance)), plane.inliers
        logger.debug("road plane tilted %.2f deg (pitch), %.2f deg (roll) from the calibrated one", *np.degrees(plane.tilt))
    else:
        consensus = robust_chord(chords, sigmas, options)
        if consensus is None:
            return GroundChord(GroundScaleStatus.TOO_FEW_GROUND_POINTS, candidates=int(chords.size))
        chord, statistical_sigma, inliers = consensus
    ground_xy = np.concatenate([points.ground_xy[points.candidate] for points in per_camera])[inliers]
    spread = float(np.sqrt(max(np.linalg.eigvalsh(np.cov(ground_xy.T))[0], 0.0)))
    if spread < options.min_ground_spread_m and not (in_lane and plane is not None):
        # a row of points at one height (e.g. along a wall) also looks like a horizontal "plane"
        logger.debug("ground consensus of %d points spans %.2f m across: a line, not a road", int(np.count_nonzero(inliers)), spread)
        return GroundChord(GroundScaleStatus.GROUND_ON_A_LINE, candidates=int(chords.size))
    masks = []
    offsets = np.cumsum([0] + [int(np.count_nonzero(points.candidate)) for points in per_camera])
    for index, points in enumerate(per_camera):
        mask = np.zeros(points.chord.shape[0], bool)
        mask[np.flatnonzero(points.candidate)] = inliers[offsets[index]:offsets[index + 1]]
        masks.append(mask)
    if yaw_sigma > 0.0:
        birge = plane.birge if plane is not None else statistical_sigma / _formal_sigma(sigmas[inliers])
        chord, statistical_sigma = _combine_cameras(per_camera, masks, birge, yaw_sigma)
    height_relative = options.height_sigma_m / float(np.mean(heights[heights > 0.0]))
    # the road normal's share: estimated with the plane (its marginal), else the calibrated normal's sigma
    normal_variance = plane.tilt_variance if plane is not None else _normal_variance(per_camera, inliers, sigmas, chord, options)
    sigma = float(np.sqrt(statistical_sigma**2 + (chord * height_relative) ** 2 + normal_variance))
    return GroundChord(GroundScaleStatus.OK, chord, sigma, tuple(masks), int(chords.size))
