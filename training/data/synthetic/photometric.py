"""Camera effects that make the two views of a synthetic pair differ as real cameras do.

Applied to each view independently, in the order light meets them: optical blur, vignetting (off unless
asked), gain and bias (exposure, per-channel white balance), gamma, sensor noise, 8-bit quantisation, JPEG
re-encoding. ``rectify_imperfectly`` models the other way two real views differ: a rectification that is
off by a fraction of a pixel (training only; the ground truth stays that of the ideal rig).
"""

from __future__ import annotations

import dataclasses
import io

import numpy as np
from PIL import Image


@dataclasses.dataclass(frozen=True, kw_only=True)
class Photometric:
    """Ranges the per-view effects are drawn from (uniformly unless said otherwise)."""

    gain: tuple[float, float] = (0.8, 1.2)
    channel_gain: float = 0.05          # extra per-channel gain spread (white balance)
    bias: tuple[float, float] = (-0.05, 0.05)
    gamma: tuple[float, float] = (0.8, 1.25)
    noise_sigma: tuple[float, float] = (0.0, 0.02)
    blur_probability: float = 0.3
    blur_sigma: tuple[float, float] = (0.3, 1.0)
    jpeg_probability: float = 0.4
    jpeg_quality: tuple[int, int] = (60, 95)
    # Radial fall-off 1 - k r^2 (r = 1 at the image corner), k drawn per view; (0, 0) draws nothing, so the
    # fixed validation split, made without it, keeps its pixels.
    vignetting: tuple[float, float] = (0.0, 0.0)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Rectification:
    """Residual rectification error of the right view: ranges (uniform, symmetric about 0) of a vertical
    shift in pixels, a rotation in degrees and a scale change, about the image centre (their vertical
    parts: :func:`rectify_imperfectly`). The defaults: what a calibrated rig keeps after rectification,
    up to about a pixel of vertical disparity at the image edges."""

    vertical_shift: float = 1.0
    rotation_deg: float = 0.2
    scale: float = 0.003


def apply_camera(image: np.ndarray, rng: np.random.Generator, effects: Photometric | None) -> np.ndarray:
    """float32 (H, W, 3) in [0, 1] -> uint8 (H, W, 3) with random camera effects (None: quantise only)."""
    if effects is None:
        return _to_uint8(image)
    if rng.random() < effects.blur_probability:
        image = _gaussian_blur(image, float(rng.uniform(*effects.blur_sigma)))
    if effects.vignetting != (0.0, 0.0):
        image = image * _falloff(image.shape[:2], float(rng.uniform(*effects.vignetting)))[:, :, None]
    gain = rng.uniform(*effects.gain) * (1 + rng.uniform(-effects.channel_gain, effects.channel_gain, 3))
    image = np.clip(image * gain.astype(np.float32) + np.float32(rng.uniform(*effects.bias)), 0, 1)
    image = image ** np.float32(rng.uniform(*effects.gamma))
    sigma = rng.uniform(*effects.noise_sigma)
    if sigma > 0:
        image = image + rng.normal(0, sigma, size=image.shape).astype(np.float32)
    encoded = _to_uint8(image)
    if rng.random() < effects.jpeg_probability:
        buffer = io.BytesIO()
        quality = int(rng.integers(effects.jpeg_quality[0], effects.jpeg_quality[1] + 1))
        Image.fromarray(encoded).save(buffer, format="JPEG", quality=quality)
        buffer.seek(0)
        with Image.open(buffer) as decoded:
            encoded = np.asarray(decoded.convert("RGB")).copy()
    return encoded


def rectify_imperfectly(image: np.ndarray, rng: np.random.Generator, error: Rectification) -> np.ndarray:
    """float32 (H, W, 3) resampled (bilinear, edge-clamped) with a small random vertical misalignment:
    a shift, plus the vertical parts of a rotation and a scale change about the centre.

    Only rows move: the horizontal parts of a residual rotation or scale act as a disparity offset that
    calibration absorbs, and leaving them out keeps the horizontal ground truth exact."""
    height, width = image.shape[:2]
    shift = rng.uniform(-error.vertical_shift, error.vertical_shift)
    slope = np.tan(np.deg2rad(rng.uniform(-error.rotation_deg, error.rotation_deg)))
    scale = rng.uniform(-error.scale, error.scale)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    offset = shift + slope * (x - (width - 1) / 2) + scale * (y - (height - 1) / 2)
    return _resample_rows(image, y - offset)


def _resample_rows(image: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``image`` sampled at row ``y[r, c]`` of each column c: linear between rows, edge-clamped."""
    height = image.shape[0]
    y = np.clip(y, 0, height - 1)
    y0 = np.minimum(np.floor(y).astype(int), height - 2)
    fy = (y - y0)[..., None].astype(np.float32)
    columns = np.arange(image.shape[1])[None, :]
    return (image[y0, columns] * (1 - fy) + image[y0 + 1, columns] * fy).astype(np.float32)


def _falloff(shape: tuple[int, ...], strength: float) -> np.ndarray:
    height, width = shape
    y, x = np.ogrid[0:height, 0:width]
    cy, cx = (height - 1) / 2, (width - 1) / 2
    r2 = ((y - cy) ** 2 + (x - cx) ** 2) / (cy ** 2 + cx ** 2)
    return (1.0 - strength * r2).astype(np.float32)


def _gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur with mirrored borders (kernel radius 3 sigma)."""
    radius = max(1, int(np.ceil(3 * sigma)))
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2).astype(np.float32)
    taps /= taps.sum()
    for axis in (0, 1):
        padded = np.pad(image, [(radius, radius) if a == axis else (0, 0) for a in range(3)], mode="reflect")
        size = image.shape[axis]
        image = sum(w * np.take(padded, np.arange(i, i + size), axis=axis) for i, w in enumerate(taps))
    return image.astype(np.float32, copy=False)


def _to_uint8(image: np.ndarray) -> np.ndarray:
    return (np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8)
