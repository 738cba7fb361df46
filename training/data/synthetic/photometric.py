"""Camera effects that make the two views of a synthetic pair differ as real cameras do.

Applied to each view independently, in the order light meets them: optical blur, gain and bias (exposure,
per-channel white balance), gamma, sensor noise, 8-bit quantisation, JPEG re-encoding.
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


def apply_camera(image: np.ndarray, rng: np.random.Generator, effects: Photometric | None) -> np.ndarray:
    """float32 (H, W, 3) in [0, 1] -> uint8 (H, W, 3) with random camera effects (None: quantise only)."""
    if effects is None:
        return _to_uint8(image)
    if rng.random() < effects.blur_probability:
        image = _gaussian_blur(image, float(rng.uniform(*effects.blur_sigma)))
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
