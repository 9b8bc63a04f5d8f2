"""The vignetting fitted to a camera's own tracks (ampc_vo.frontend.vignetting, DESIGN 4 step 1b)."""

import dataclasses

import numpy as np
import pytest

from ampc_vo.config import TrackerConfig
from ampc_vo.frontend.tracker import CameraTracker
from ampc_vo.frontend.vignetting import VignettingFit, fit_vignetting_strength, patch_means
from ampc_vo.rig import Camera
from tests.frontend.test_frontend import HEIGHT, WIDTH, make_image, match_tracks, pinhole


@pytest.mark.parametrize("strength", [0.0, 0.3, 0.6])
def test_fit_recovers_the_strength_from_grey_level_ratios(strength):
    """Log grey-level ratios made by the model (per-pair exposure changes of 5 %, 1 % noise, a
    tenth of the tracks on moving or shadowed surfaces 30 % off) give the strength back within 0.02."""
    rng = np.random.default_rng(3)
    pairs, tracks = 30, 300
    pair = np.repeat(np.arange(pairs), tracks)
    cos4_before = rng.uniform(0.3, 1.0, pairs * tracks)
    cos4_after = np.clip(cos4_before + rng.normal(0.0, 0.05, pairs * tracks), 0.2, 1.0)
    exposure = rng.normal(0.0, 0.05, pairs)[pair]
    log_ratio = exposure + np.log1p(-strength * (1 - cos4_after)) - np.log1p(-strength * (1 - cos4_before)) + rng.normal(0.0, 0.01, pairs * tracks)
    outliers = rng.random(pairs * tracks) < 0.1
    log_ratio[outliers] += rng.choice([-0.3, 0.3], outliers.sum())
    assert fit_vignetting_strength(log_ratio, cos4_before, cos4_after, pair) == pytest.approx(strength, abs=0.02)


def test_cos4_off_axis_and_patch_means():
    camera = pinhole()
    assert camera.cos4_off_axis(np.array([[319.5, 239.5], [819.5, 239.5]])) == pytest.approx([1.0, 0.25])
    image = np.zeros((HEIGHT, WIDTH), np.uint8)
    image[:, 320:] = 100
    # a 47 px box: 24 of its columns lie right of the step at x = 320 (320 to 343)
    assert patch_means(image, np.array([[100.0, 50.0], [400.0, 50.0], [320.0, 50.0]])) == pytest.approx([0.0, 100.0, 2400.0 / 47.0])


def _drive(tracker: CameraTracker, shading: np.ndarray, frames: int) -> list:
    """Track ``frames`` images of a texture moving 10-14 px per frame in changing directions,
    under ``shading`` and an exposure that changes by up to 1 % from frame to frame (KLT itself
    is not invariant to gain: 4 % moves its tracks by 0.1-0.4 px here)."""
    rng = np.random.default_rng(5)
    offset, observations = np.zeros(2), []
    for frame in range(frames):
        exposure = 1.2 * (1.0 + 0.005 * np.sin(frame))
        image = np.clip(make_image(*offset).astype(float) * exposure * shading, 0, 255).round().astype(np.uint8)
        observations.append((offset.copy(), tracker.track(image)))
        angle = rng.uniform(0, 2 * np.pi)
        offset = offset + rng.uniform(10, 14) * np.array([np.cos(angle), np.sin(angle)])
    return observations


def _shift_errors(observations: list) -> np.ndarray:
    """Per frame pair, the median distance (px) of the tracks' image motion from the texture's shift."""
    errors = []
    for (offset_first, first), (offset_second, second) in zip(observations[:-1], observations[1:]):
        index_first, index_second = match_tracks(first, second)
        assert len(index_first) > 0.8 * len(first)
        errors.append(np.median(np.linalg.norm(second.pixels[index_second] - first.pixels[index_first] - (offset_second - offset_first), axis=1)))
    return np.array(errors)


def test_tracker_fits_an_uncalibrated_vignetting_and_divides_it_out():
    """A camera whose rig.yaml gives no vignetting, under a fall-off of strength 0.6: the tracker
    fits it to its first 8 image pairs' tracks (within 0.05) and divides it out from then on, so KLT
    reads the texture's shift as well as with the calibrated camera (within 0.005 px) and at most
    two thirds as wrong as with the fall-off left in. Without a fall-off the fit leaves the images alone."""
    config = dataclasses.replace(TrackerConfig(), vignetting_fit_pairs=8)
    calibrated = Camera("front", "tractor", "pinhole", WIDTH, HEIGHT, 500.0, 500.0, 319.5, 239.5, vignetting=0.6)
    shading = calibrated.relative_illumination()
    fitted = CameraTracker(pinhole(), config)
    errors = {
        "calibrated": _shift_errors(_drive(CameraTracker(calibrated, config), shading, 14)),
        "fitted": _shift_errors(_drive(fitted, shading, 14)),
        "left in": _shift_errors(_drive(CameraTracker(pinhole(), dataclasses.replace(config, vignetting_fit_pairs=0)), shading, 14)),
    }
    assert fitted.vignetting == pytest.approx(0.6, abs=0.05)
    after_fit = slice(9, None)  # the pairs tracked once the flat field is on
    assert np.all(errors["fitted"][after_fit] <= errors["calibrated"][after_fit] + 0.005)
    assert np.all(errors["left in"][after_fit] >= 1.5 * errors["fitted"][after_fit])

    flat = CameraTracker(pinhole(), config)
    _drive(flat, np.ones((HEIGHT, WIDTH), np.float32), 10)
    assert flat._vignetting_fit.strength is not None and flat._vignetting_fit.strength < 0.05
    assert flat.vignetting == 0.0


def test_pairs_at_rest_are_not_fitted():
    """A camera at rest (tracks within a pixel of where they were) sees no fall-off: however long
    the standstill, nothing is fitted from it (it would fit the exposure noise)."""
    rng = np.random.default_rng(1)
    fit = VignettingFit(pinhole(), pairs=3)
    image = make_image()
    pixels = rng.uniform([60, 60], [580, 420], (200, 2))
    for _ in range(20):
        assert fit.add(image, pixels, image, pixels + rng.normal(0.0, 0.3, pixels.shape)) is None
    assert fit.tracks == 0
