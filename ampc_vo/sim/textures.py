"""Grey surface textures for the renderer (issue 6, DESIGN section 6).

Textures are square, seamlessly tileable ``uint8`` images built from the real photographs that
scikit-image ships inside its wheel (``brick``, ``grass``, ``gravel``, ``moon``: no network access)
plus procedural variation (random crops, contrast, stains, multi-scale noise), or fully procedural
(``wood``, ``metal``, ``marker``). :class:`TextureAtlas` packs every texture and its mipmap pyramid
into one image that ``cv2.remap`` samples (bilinear per level, trilinear across levels).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from ampc_vo.errors import ConfigError

logger = logging.getLogger(__name__)

TEXTURE_SIZE = 512
ATLAS_PAD = 2  # wrapped border texels around every mip level, so bilinear taps never leave a texture
_MAX_ATLAS_SIDE = 32766  # cv2.remap needs maps smaller than 32767 per side (DESIGN section 7)


# ---------------------------------------------------------------------- building blocks
def _photo(name: str) -> np.ndarray:
    """A grey float32 photograph in [0, 1] from ``skimage.data`` (shipped files only, no download)."""
    import skimage.data

    image = getattr(skimage.data, name)()
    if image.ndim == 3:
        image = cv2.cvtColor(image[..., :3], cv2.COLOR_RGB2GRAY)
    return image.astype(np.float32) / 255.0


def make_tileable(image: np.ndarray) -> np.ndarray:
    """Seamlessly tileable version of a square image: blend it with its three half-period shifts.

    The copy rolled by ``(dy, dx)`` has its seams on the lines ``x = dx`` and ``y = dy``; it is
    weighted by ``r(x - dx) r(y - dy)`` with ``r(s) = sin^2(pi s / S)``, which vanishes on its
    seams, and the four weights sum to one (``sin^2 + cos^2``), so no seam survives.
    """
    size = image.shape[0]
    half = size // 2
    coordinate = np.arange(size) + 0.5
    ramps = {shift: (np.sin(np.pi * (coordinate - shift) / size) ** 2).astype(np.float32) for shift in (0, half)}
    blended = np.zeros_like(image, dtype=np.float32)
    weight_sq = np.zeros_like(blended)
    for dy in (0, half):
        for dx in (0, half):
            weight = np.outer(ramps[dy], ramps[dx])
            blended += weight * np.roll(image, (dy, dx), axis=(0, 1))
            weight_sq += weight**2
    # Averaging independent patches lowers contrast where several weigh in: restore it locally.
    mean = float(blended.mean())
    return (mean + (blended - mean) / np.sqrt(weight_sq)).astype(np.float32)


def periodic_noise(size: int, rng: np.random.Generator, scales: tuple[int, ...] = (4, 8, 16, 32, 64),
                   weights: tuple[float, ...] | None = None) -> np.ndarray:
    """Multi-scale tileable value noise in about [-1, 1]: sum of bicubically upsampled random grids
    with ``scale`` cells per tile (periodic because the coarse grids are wrapped before resizing)."""
    weights = weights or tuple(1.0 / np.sqrt(s) for s in scales)
    total = np.zeros((size, size), np.float32)
    for cells, weight in zip(scales, weights):
        grid = rng.standard_normal((cells, cells)).astype(np.float32)
        padded = np.pad(grid, 2, mode="wrap")
        step = size / cells
        big = cv2.resize(padded, (int(round(step * (cells + 4))),) * 2, interpolation=cv2.INTER_CUBIC)
        start = int(round(2 * step))
        total += weight * big[start:start + size, start:start + size]
    return total / (np.abs(total).max() + 1e-6)


def _crop_resize(image: np.ndarray, rng: np.random.Generator, min_fraction: float = 0.6) -> np.ndarray:
    """A random square crop (at least ``min_fraction`` of the side) resized to ``TEXTURE_SIZE``."""
    side = min(image.shape[:2])
    crop = int(rng.uniform(min_fraction, 1.0) * side)
    y0 = int(rng.integers(0, image.shape[0] - crop + 1))
    x0 = int(rng.integers(0, image.shape[1] - crop + 1))
    patch = image[y0:y0 + crop, x0:x0 + crop]
    if rng.random() < 0.5:
        patch = patch[:, ::-1]
    return cv2.resize(np.ascontiguousarray(patch), (TEXTURE_SIZE, TEXTURE_SIZE), interpolation=cv2.INTER_AREA)


def _normalise(image: np.ndarray, mean: float, std: float) -> np.ndarray:
    image = (image - image.mean()) / (image.std() + 1e-6)
    return np.clip(mean + std * image, 0.0, 1.0).astype(np.float32)


def _stains(size: int, rng: np.random.Generator, strength: float) -> np.ndarray:
    """Multiplicative low-frequency stains and patches (1 + strength * noise, noise std ~0.35).

    Real surfaces vary at every scale; the coarse variation is what lets pyramidal KLT lock on under
    large image motion (fine gravel alone gives no signal at the coarse pyramid levels)."""
    noise = periodic_noise(size, rng, scales=(2, 4, 8, 16), weights=(1.0, 0.8, 0.6, 0.4))
    noise = noise / (3.0 * noise.std() + 1e-6)
    return np.clip(1.0 + strength * noise, 0.2, 2.0).astype(np.float32)


def _to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------------- the textures
def _asphalt(rng: np.random.Generator) -> np.ndarray:
    base = make_tileable(_crop_resize(_photo("gravel"), rng, 0.35))
    base = _normalise(base, 0.0, 1.0)
    grain = periodic_noise(TEXTURE_SIZE, rng, scales=(64, 128, 256))
    image = _normalise(0.7 * base + 0.5 * grain, 0.36, 0.09)
    return np.clip(image * _stains(TEXTURE_SIZE, rng, 0.6), 0, 1)


def _worn_asphalt(rng: np.random.Generator) -> np.ndarray:
    """Low-texture road asphalt (one tile is ~10 m of road): fine aggregate grain of low contrast that
    the mipmap averages away beyond a few metres, large worn (lighter) and darker areas, a few
    darker repair patches with sharp edges, sealed cracks and oil stains; the trackable detail of a
    real road is sparse."""
    size = TEXTURE_SIZE
    grain = periodic_noise(size, rng, scales=(128, 256))
    gravel = _normalise(make_tileable(_crop_resize(_photo("gravel"), rng, 0.35)), 0.0, 1.0)
    image = 0.34 + 0.018 * grain + 0.012 * gravel
    image *= 1.0 + 0.10 * periodic_noise(size, rng, scales=(2, 3, 5), weights=(1.0, 0.7, 0.5))  # worn areas
    canvas = np.zeros((3 * size, 3 * size), np.float32)  # draw on a 3x3 canvas and fold: features wrap seamlessly
    for _ in range(int(rng.integers(1, 4))):             # repair patches (fresh, darker asphalt)
        x, y = rng.uniform(size, 2 * size, 2)
        w, h = rng.uniform(40, 160, 2)
        corners = cv2.boxPoints(((float(x), float(y)), (float(w), float(h)), float(rng.uniform(-10, 10)))).astype(np.int32)
        cv2.fillConvexPoly(canvas, corners, float(rng.uniform(-0.09, -0.05)), lineType=cv2.LINE_AA)
    for _ in range(int(rng.integers(3, 7))):             # sealed cracks: dark, wandering, thin
        point = rng.uniform(size, 2 * size, 2)
        heading = rng.uniform(0, 2 * np.pi)
        points = [point.copy()]
        for _ in range(int(rng.integers(8, 30))):
            heading += rng.normal(0, 0.5)
            point = point + rng.uniform(4, 12) * np.array([np.cos(heading), np.sin(heading)])
            points.append(point.copy())
        cv2.polylines(canvas, [np.array(points, np.int32)], False, float(rng.uniform(-0.16, -0.1)), int(rng.integers(1, 3)), cv2.LINE_AA)
    for _ in range(int(rng.integers(2, 6))):             # oil stains
        x, y = rng.uniform(size, 2 * size, 2)
        stain = np.zeros_like(canvas)
        cv2.ellipse(stain, (int(x), int(y)), (int(rng.uniform(6, 25)), int(rng.uniform(4, 15))), float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
        canvas -= float(rng.uniform(0.04, 0.1)) * cv2.GaussianBlur(stain, (0, 0), 4)
    folded = canvas.reshape(3, size, 3, size).sum(axis=(0, 2))
    return np.clip(image + folded, 0, 1).astype(np.float32)


def _verge(rng: np.random.Generator) -> np.ndarray:
    """Roadside grass and dirt seen from a vehicle: mottled at metre scale (tufts, bare patches), fine
    blades of low contrast (the grass photograph shrunk), no cobble-like structure."""
    size = TEXTURE_SIZE
    blades = _normalise(make_tileable(_crop_resize(_photo("grass"), rng, 0.9)), 0.0, 1.0)
    fine = cv2.GaussianBlur(periodic_noise(size, rng, scales=(128, 256)), (0, 0), 0.7)
    mottle = periodic_noise(size, rng, scales=(3, 6, 12, 24), weights=(1.0, 0.8, 0.6, 0.4))
    image = (0.30 + 0.05 * blades + 0.04 * fine + 0.09 * mottle) * _stains(size, rng, 0.4)
    return np.clip(image, 0, 1).astype(np.float32)


def _grass(rng: np.random.Generator) -> np.ndarray:
    base = make_tileable(_crop_resize(_photo("grass"), rng, 0.5))
    return np.clip(_normalise(base, 0.42, 0.16) * _stains(TEXTURE_SIZE, rng, 0.6), 0, 1)


def _gravel(rng: np.random.Generator) -> np.ndarray:
    base = make_tileable(_crop_resize(_photo("gravel"), rng, 0.6))
    return np.clip(_normalise(base, 0.5, 0.17) * _stains(TEXTURE_SIZE, rng, 0.6), 0, 1)


def _brick(rng: np.random.Generator) -> np.ndarray:
    base = make_tileable(_crop_resize(np.ascontiguousarray(_photo("brick").T), rng, 0.7))  # bricks horizontal
    return np.clip(_normalise(base, 0.5, 0.18) * _stains(TEXTURE_SIZE, rng, 0.25), 0, 1)


def _concrete(rng: np.random.Generator) -> np.ndarray:
    moon = make_tileable(_crop_resize(_photo("moon"), rng, 0.5))
    noise = periodic_noise(TEXTURE_SIZE, rng, scales=(8, 32, 128, 256))
    image = _normalise(_normalise(moon, 0, 1) + 0.8 * noise, 0.6, 0.09)
    # Formwork panel joints: dark lines every quarter tile.
    joints = np.ones((TEXTURE_SIZE, TEXTURE_SIZE), np.float32)
    for k in (TEXTURE_SIZE // 4, 3 * TEXTURE_SIZE // 4):
        joints[k:k + 3, :] = 0.65
        joints[:, k:k + 3] = 0.65
    return np.clip(image * joints * _stains(TEXTURE_SIZE, rng, 0.3), 0, 1)


def _wood(rng: np.random.Generator) -> np.ndarray:
    """Planks: grain noise stretched along x, plank joints along y, per-plank tone."""
    size = TEXTURE_SIZE
    fine = periodic_noise(size, rng, scales=(64, 128))
    grain = cv2.resize(periodic_noise(size, rng, scales=(16, 32, 64)), (size * 8, size))[:, :size]
    grain = cv2.resize(grain, (size, size))
    rows = np.arange(size)
    plank = rows // (size // 8)
    tones = rng.uniform(0.35, 0.6, 8)[plank][:, None]
    image = tones + 0.2 * grain + 0.12 * fine
    joint = (rows % (size // 8)) < 3
    image[joint, :] *= 0.4
    for _ in range(24):  # knots, nail heads and butt joints: corners to track
        x, y = int(rng.integers(0, size)), int(rng.integers(0, size))
        cv2.ellipse(image, (x, y), (int(rng.integers(4, 12)), int(rng.integers(2, 6))), 0, 0, 360, float(rng.uniform(0.1, 0.3)), -1)
        cv2.line(image, (x, (y // (size // 8)) * (size // 8)), (x, (y // (size // 8) + 1) * (size // 8)), 0.2, 2)
    return np.clip(image * _stains(size, rng, 0.3), 0, 1).astype(np.float32)


def _metal(rng: np.random.Generator) -> np.ndarray:
    """Corrugated/brushed sheet metal with panel seams, rivets and rust stains."""
    size = TEXTURE_SIZE
    columns = np.arange(size, dtype=np.float32)
    corrugation = 0.08 * np.sin(2 * np.pi * columns * 16 / size)[None, :]
    brushed = cv2.resize(periodic_noise(size, rng, scales=(128, 256)), (size, size))
    streaks = cv2.GaussianBlur(np.tile(rng.standard_normal((1, size)).astype(np.float32), (size, 1)), (1, 31), 0)
    image = 0.55 + corrugation + 0.1 * brushed + 0.06 * streaks
    for seam in (0, size // 2):
        image[seam:seam + 4, :] *= 0.5
        for x in range(8, size, 32):
            cv2.circle(image, (x, seam + 14), 4, 0.25, -1)
    return np.clip(image * _stains(size, rng, 0.35), 0, 1).astype(np.float32)


def _facade(rng: np.random.Generator) -> np.ndarray:
    """Plaster or brick wall with a 2x2 grid of dark windows per tile (frames, sills, reflections)."""
    size = TEXTURE_SIZE
    wall = _brick(rng) if rng.random() < 0.5 else _concrete(rng)
    image = wall.copy()
    half = size // 2
    reflections = 0.5 * (periodic_noise(size, rng, scales=(4, 8, 16)) + 1.0)
    for row in range(2):
        for col in range(2):
            x0, y0 = col * half + half // 4, row * half + half // 5
            x1, y1 = x0 + half // 2, y0 + int(half * 0.55)
            image[y0 - 6:y1 + 10, x0 - 6:x1 + 6] = 0.8  # frame
            glass = 0.08 + 0.3 * reflections[y0:y1, x0:x1]
            image[y0:y1, x0:x1] = glass
            image[y0:y1, (x0 + x1) // 2 - 2:(x0 + x1) // 2 + 2] = 0.75  # mullion
            image[y1 + 4:y1 + 14, x0 - 12:x1 + 12] = 0.9  # sill
    return np.clip(image, 0, 1).astype(np.float32)


def _marker(rng: np.random.Generator) -> np.ndarray:
    """A 2x2 checker: black/white quadrants meeting at the tile centre (a sharp corner for tests)."""
    del rng
    size = TEXTURE_SIZE
    half = size // 2
    image = np.full((size, size), 0.1, np.float32)
    image[:half, :half] = 0.9
    image[half:, half:] = 0.9
    return image


def _dot(rng: np.random.Generator) -> np.ndarray:
    """A white disc of radius a quarter tile on a black background, centred in the tile."""
    del rng
    size = TEXTURE_SIZE
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) + 0.5
    radius = np.hypot(xx - size / 2, yy - size / 2)
    coverage = np.clip(size / 4 - radius + 0.5, 0.0, 1.0)  # anti-aliased edge
    return (0.1 + 0.8 * coverage).astype(np.float32)


def _paint(rng: np.random.Generator) -> np.ndarray:
    base = periodic_noise(TEXTURE_SIZE, rng, scales=(32, 128))
    return np.clip(0.85 + 0.05 * base, 0, 1).astype(np.float32)


TEXTURE_BUILDERS = {
    "asphalt": _asphalt,
    "worn_asphalt": _worn_asphalt,
    "road": _asphalt,
    "grass": _grass,
    "verge": _verge,
    "gravel": _gravel,
    "brick": _brick,
    "concrete": _concrete,
    "wood": _wood,
    "metal": _metal,
    "facade": _facade,
    "marker": _marker,
    "checker": _marker,
    "dot": _dot,
    "paint": _paint,
}
TEXTURE_NAMES = tuple(TEXTURE_BUILDERS)


def make_texture(name: str, seed: int = 0) -> np.ndarray:
    """The grey ``uint8`` texture ``name`` (``TEXTURE_SIZE`` square, tileable), deterministic in ``seed``.

    Unknown names fall back to a seeded variant of ``concrete`` only if they start with a known
    name followed by ``_`` (``brick_2`` is a second brick variant); otherwise :class:`ConfigError`.
    """
    base, _, variant = name.partition("_")
    builder = TEXTURE_BUILDERS.get(name) or (TEXTURE_BUILDERS.get(base) if variant else None)
    if builder is None:
        raise ConfigError(f"unknown texture {name!r}; known: {', '.join(TEXTURE_NAMES)} (or <name>_<variant>)")
    digest = sum((k + 1) * ord(c) for k, c in enumerate(name))
    rng = np.random.default_rng([seed, digest])
    return _to_uint8(builder(rng))


# ---------------------------------------------------------------------- mipmap atlas
def mipmap_pyramid(texture: np.ndarray) -> list[np.ndarray]:
    """Mip levels of a square power-of-two texture: 2x2 box averages down to 1x1 texel (float32)."""
    level = texture.astype(np.float32)
    levels = [level]
    while level.shape[0] > 1:
        level = 0.25 * (level[0::2, 0::2] + level[1::2, 0::2] + level[0::2, 1::2] + level[1::2, 1::2])
        levels.append(level)
    return levels


@dataclass(frozen=True)
class TextureAtlas:
    """All textures and their mip levels packed in one float32 image for ``cv2.remap``.

    Texture ``k`` level ``L`` occupies ``image[y0 + pad : y0 + pad + S_L, x0 + pad : x0 + pad + S_L]``
    with ``x0 = level_x[k]``, ``y0 = level_y[L]`` and ``S_L = size >> L``, surrounded by ``pad``
    texels copied from the opposite edges (wrap), so bilinear taps of a wrapped coordinate are exact.
    """

    image: np.ndarray  # (H, W) float32 grey levels 0..255
    names: tuple[str, ...]
    size: int
    level_x: np.ndarray  # (K,) column of each texture's slot
    level_y: np.ndarray  # (L,) row of each level
    num_levels: int
    pad: int = ATLAS_PAD

    def index(self, name: str) -> int:
        return self.names.index(name)


def build_atlas(textures: dict[str, np.ndarray]) -> TextureAtlas:
    """Pack ``textures`` (name -> square uint8, all ``TEXTURE_SIZE``) with their mipmaps."""
    names = tuple(textures)
    size = TEXTURE_SIZE
    pad = ATLAS_PAD
    pyramids = []
    for name in names:
        texture = textures[name]
        if texture.shape != (size, size):
            raise ConfigError(f"texture {name!r}: expected shape {(size, size)}, got {texture.shape}")
        pyramids.append(mipmap_pyramid(texture))
    num_levels = len(pyramids[0])
    level_heights = [(size >> level) + 2 * pad for level in range(num_levels)]
    level_y = np.concatenate([[0], np.cumsum(level_heights)[:-1]]).astype(np.int64)
    slot = size + 2 * pad
    width, height = slot * len(names), int(sum(level_heights))
    if width > _MAX_ATLAS_SIDE or height > _MAX_ATLAS_SIDE:
        raise ConfigError(f"too many textures for one atlas ({len(names)}): cv2.remap limit is 32767 px per side")
    atlas = np.zeros((height, width), np.float32)
    for k, pyramid in enumerate(pyramids):
        for level, image in enumerate(pyramid):
            padded = np.pad(image, pad, mode="wrap")
            y0, x0 = int(level_y[level]), k * slot
            atlas[y0:y0 + padded.shape[0], x0:x0 + padded.shape[1]] = padded
    level_x = np.arange(len(names), dtype=np.int64) * slot
    return TextureAtlas(atlas, names, size, level_x, level_y, num_levels, pad)


def load_textures(names: list[str] | tuple[str, ...] | None = None, seed: int = 0) -> dict[str, np.ndarray]:
    """Textures by name (default: all known names), deterministic in ``seed``."""
    names = TEXTURE_NAMES if names is None else tuple(dict.fromkeys(names))
    return {name: make_texture(name, seed) for name in names}
