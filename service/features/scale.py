"""Tower scale: the towers run on the pair upsampled by an integer factor, features kept at its pixels.

A tower's feature describes a window of ``receptive_field`` pixels of its input. On the pair upsampled by
``s`` that window spans ``receptive_field / s`` pixels of the image, while the towers keep the features
they learned: sharper depth edges (less foreground fattening) where the texture is dense enough for the
smaller window, and more ambiguity where sensor noise, blur or compression dominate a few pixels.
Measured (docs/training.md, "Tower scale"): at ``s = 2`` every learned model is clearly better on Cones
(a clean, densely textured photograph) and worse on the synthetic validation split (its cameras add
noise, blur and JPEG; without them adsm-fast is better at 2 there too), so 1 stays the default and 2 is a
per-call choice for imagery like Cones.

The grid is exact: pixel ``(s y, s x)`` of the upsampled image *is* pixel ``(y, x)`` of the image
(bilinear between neighbours in between), so the features kept at every ``s``-th pixel are centred on
the image's own pixels and both views keep their disparities, multiplied by nothing.

    >>> upsample(np.array([[0, 10], [20, 30]], np.uint8)[:, :, None], 2)[:, :, 0]
    array([[ 0,  5, 10],
           [10, 15, 20],
           [20, 25, 30]], dtype=uint8)
"""

from __future__ import annotations

import math

import numpy as np

MAX_TOWER_SCALE = 4  # the towers' work grows with its square


def upsampled_size(length: int, scale: int) -> int:
    """Pixels of a side of ``length`` once upsampled on the exact grid."""
    return scale * (length - 1) + 1


def scaled_halo(halo: int, scale: int) -> int:
    """Image pixels of context the towers need around a tile so that, run on the tile upsampled by
    ``scale``, the features kept at its pixels equal those of the whole image."""
    return math.ceil(halo / scale)


def upsample(image: np.ndarray, scale: int) -> np.ndarray:
    """uint8 (H, W, C) -> uint8 (s (H - 1) + 1, s (W - 1) + 1, C), bilinear on the exact grid."""
    if scale == 1:
        return image
    values = image.astype(np.float32)
    for axis in (0, 1):
        values = _interpolate(values, axis, scale)
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


def _interpolate(values: np.ndarray, axis: int, scale: int) -> np.ndarray:
    """``values`` upsampled along ``axis`` (0 or 1): sample ``s i + k`` mixes samples i and i + 1."""
    moved = np.moveaxis(values, axis, 0)
    if moved.shape[0] == 1:
        return values
    ahead = (np.arange(scale, dtype=np.float32) / scale).reshape(1, scale, *([1] * (moved.ndim - 1)))
    mixed = moved[:-1, None] * (1 - ahead) + moved[1:, None] * ahead
    mixed = mixed.reshape(-1, *moved.shape[1:])
    return np.moveaxis(np.concatenate([mixed, moved[-1:]]), 0, axis)
