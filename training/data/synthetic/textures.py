"""Surface textures for synthetic scenes: procedural noise and bundled natural photos.

Procedural kinds: multi-octave value noise, stripes, checker, blobs, and nearly flat paint (the hard,
textureless case). Photos come from the images that scikit-image ships inside its wheel (astronaut,
coffee, brick, grass, ...), read as plain files with Pillow (``training.data.photos``).
Its ``motorcycle_left/right`` pair is a real stereo pair (Middlebury 2014) and is deliberately excluded.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from PIL import Image, ImageDraw

from training.data.photos import data_folder

# Natural photos and photographed textures in scikit-image's data folder (never a stereo pair).
PHOTOS = ("astronaut.png", "brick.png", "camera.png", "chelsea.png", "coffee.png", "coins.png",
          "grass.png", "gravel.png", "hubble_deep_field.jpg", "ihc.png", "moon.png", "page.png",
          "retina.jpg", "rocket.jpg", "text.png")
PROCEDURAL = ("noise", "stripes", "checker", "blobs", "flat")


@dataclasses.dataclass(frozen=True)
class ImageTexture:
    """An RGB image laid on a surface: surface point (x, y) shows image pixel ((x, y) - origin) * scale.

    ``transpose`` swaps the image axes and a negative ``scale`` flips them, so one stored photo yields all
    its rotations and mirrorings without a copy; ``tint`` multiplies the colours. Sampling is bilinear and
    the image is mirrored beyond its border, so any surface size is covered.
    """

    image: np.ndarray            # float32 (h, w, 3) in [0, 1]
    origin: tuple[float, float] = (0.0, 0.0)
    scale: tuple[float, float] = (1.0, 1.0)
    transpose: bool = False
    tint: tuple[float, float, float] | None = None

    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        height, width = self.image.shape[:2]
        u = (x - self.origin[0]) * self.scale[0]
        v = (y - self.origin[1]) * self.scale[1]
        if self.transpose:
            u, v = v, u
        u0, v0 = np.floor(u), np.floor(v)
        fu, fv = (u - u0)[:, None], (v - v0)[:, None]
        u0, v0 = u0.astype(np.int64), v0.astype(np.int64)
        c0, c1 = _mirror(u0, width), _mirror(u0 + 1, width)
        r0, r1 = _mirror(v0, height) * width, _mirror(v0 + 1, height) * width
        flat = self.image.reshape(-1, 3)
        top = np.take(flat, r0 + c0, axis=0) * (1 - fu) + np.take(flat, r0 + c1, axis=0) * fu
        bottom = np.take(flat, r1 + c0, axis=0) * (1 - fu) + np.take(flat, r1 + c1, axis=0) * fu
        colour = top * (1 - fv) + bottom * fv
        if self.tint is not None:
            colour = np.clip(colour * np.asarray(self.tint, dtype=np.float32), 0, 1)
        return colour.astype(np.float32, copy=False)


@functools.lru_cache(maxsize=1)
def load_photos() -> tuple[np.ndarray, ...]:
    """The bundled photos as float32 RGB arrays in [0, 1] (grey photos repeated over 3 channels)."""
    folder = data_folder()
    photos = []
    for name in PHOTOS:
        path = folder / name
        if not path.is_file():
            raise FileNotFoundError(f"bundled photo {path} is missing: reinstall scikit-image")
        with Image.open(path) as image:
            photos.append(np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0)
    return tuple(photos)


def random_texture(rng: np.random.Generator, *, height: int, width: int, origin: tuple[float, float],
                   photo_probability: float) -> ImageTexture:
    """A random texture covering a ``height`` x ``width`` surface region whose corner is ``origin``."""
    if rng.random() < photo_probability:
        return _photo_texture(rng, origin)
    kind = PROCEDURAL[rng.choice(len(PROCEDURAL), p=(0.45, 0.15, 0.08, 0.2, 0.12))]
    field = _PATTERNS[kind](rng, height + 2, width + 2)
    return ImageTexture(_colorize(field, rng), origin=origin)


def minified(texture: ImageTexture) -> ImageTexture:
    """The texture at twice its spatial frequency: its image averaged over 2 x 2 blocks, laid with the same
    origin and scale. The box prefilter keeps the finer paint from aliasing; drawn on a region twice the
    surface's size, a procedural texture then covers the surface without mirroring.

    >>> minified(ImageTexture(np.zeros((9, 6, 3), np.float32))).image.shape
    (4, 3, 3)
    """
    pixels = blocks(texture.image, 2)
    if pixels.size == 0:
        return texture
    return dataclasses.replace(texture, image=pixels.mean(axis=(1, 3), dtype=np.float32))


def blocks(image: np.ndarray, factor: int) -> np.ndarray:
    """``image`` (H, W, ...) cut to whole ``factor`` x ``factor`` blocks and viewed as (H // factor, factor,
    W // factor, factor, ...): a reduction over axes (1, 3) is one value per block.

    >>> blocks(np.zeros((5, 6)), 2).shape
    (2, 2, 3, 2)
    """
    height, width = image.shape[0] // factor, image.shape[1] // factor
    return image[:height * factor, :width * factor].reshape(height, factor, width, factor, *image.shape[2:])


def value_noise(rng: np.random.Generator, height: int, width: int, *, octaves: int, period: float,
                persistence: float) -> np.ndarray:
    """Multi-octave value noise in [0, 1]: random lattices upsampled bicubically, halving the period."""
    total = np.zeros((height, width), dtype=np.float32)
    amplitude, weight = 1.0, 0.0
    for _ in range(octaves):
        cells = (max(2, int(np.ceil(height / period)) + 2), max(2, int(np.ceil(width / period)) + 2))
        lattice = Image.fromarray(rng.random(cells, dtype=np.float32))
        big = lattice.resize((int(cells[1] * period), int(cells[0] * period)), Image.Resampling.BICUBIC)
        total += amplitude * np.asarray(big)[:height, :width]
        weight += amplitude
        amplitude *= persistence
        period = max(1.0, period / 2)
    return np.clip(total / weight, 0.0, 1.0)


def _noise(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    period, finest = float(np.exp(rng.uniform(np.log(12), np.log(128)))), rng.uniform(1, 4)
    octaves = max(2, int(np.ceil(np.log2(period / finest))) + 1)  # down to a few pixels: real detail
    return value_noise(rng, height, width, octaves=octaves, period=period,
                       persistence=float(rng.uniform(0.5, 0.85)))


def _stripes(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    angle, period = rng.uniform(0, np.pi), rng.uniform(3, 40)
    wave = np.sin(2 * np.pi * (x * np.cos(angle) + y * np.sin(angle)) / period + rng.uniform(0, 2 * np.pi))
    sharpness = rng.uniform(1, 8)
    return 0.5 + 0.5 * np.tanh(sharpness * wave) * 0.8 + 0.1 * (_noise(rng, height, width) - 0.5)


def _checker(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    angle, size = rng.uniform(0, np.pi / 2), rng.uniform(4, 48)
    u, v = x * np.cos(angle) + y * np.sin(angle), -x * np.sin(angle) + y * np.cos(angle)
    board = ((np.floor(u / size) + np.floor(v / size)) % 2).astype(np.float32)
    return 0.15 + 0.7 * board + 0.15 * _noise(rng, height, width)


def _blobs(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    canvas = Image.fromarray((_noise(rng, height, width) * 255).astype(np.uint8))
    draw = ImageDraw.Draw(canvas)
    count = int(np.clip(height * width / rng.uniform(150, 2000), 4, 3000))
    centres = rng.random((count, 2)) * (width, height)
    radii = rng.uniform(1.5, max(2.0, 0.08 * min(height, width)), size=(count, 2))
    shades = rng.integers(0, 256, size=count)
    for (cx, cy), (rx, ry), shade in zip(centres, radii, shades, strict=True):
        draw.ellipse((cx - rx, cy - ry, cx + rx, cy + ry), fill=int(shade))
    return np.asarray(canvas, dtype=np.float32) / 255.0


def _flat(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    # Nearly uniform paint: matching must come from the SGM smoothness term, not from the texture.
    return 0.5 + rng.uniform(0.01, 0.06) * (_noise(rng, height, width) - 0.5)


_PATTERNS = {"noise": _noise, "stripes": _stripes, "checker": _checker, "blobs": _blobs, "flat": _flat}


def _colorize(field: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Map a scalar field in [0, 1] to RGB between two random colours (often near-grey, like real scenes)."""
    low, high = rng.random(3), rng.random(3)
    if rng.random() < 0.5:
        grey_low, grey_high = rng.random(), rng.random()
        low, high = 0.7 * grey_low + 0.3 * low, 0.7 * grey_high + 0.3 * high
    if abs(float(np.mean(high - low))) < 0.25:  # keep contrast: a swatch of one colour teaches nothing
        high = np.clip(low + np.sign(rng.random() - 0.5) * 0.5, 0, 1)
    field = np.clip(field, 0, 1)[..., None]
    return (low + field * (high - low)).astype(np.float32)


def _photo_texture(rng: np.random.Generator, origin: tuple[float, float]) -> ImageTexture:
    photos = load_photos()
    photo = photos[rng.integers(len(photos))]
    # |scale| > 1 shrinks the photo on the surface (finer detail), < 1 magnifies it; signs mirror it.
    size = float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))
    signs = rng.choice((-1.0, 1.0), size=2)
    shift = rng.random(2) * photo.shape[1::-1] / size
    tint = rng.uniform(0.75, 1.25, size=3)
    return ImageTexture(photo, origin=(origin[0] - shift[0], origin[1] - shift[1]),
                        scale=(size * signs[0], size * signs[1]), transpose=bool(rng.random() < 0.5),
                        tint=(float(tint[0]), float(tint[1]), float(tint[2])))


def _mirror(index: np.ndarray, size: int) -> np.ndarray:
    if size == 1:
        return np.zeros_like(index)
    period = 2 * size - 2
    index = np.mod(index, period)
    return np.where(index < size, index, period - index)
