"""Training examples cut from stereo pairs: the paper's patch pairs (section 4.2) and dense crops.

Patch pair: a P x P left patch centred on pixel (y, x) and a P x (P + 200) right strip centred on its
true match ``q = x - round(d_gt)``, so the strip holds the 201 candidate patches q - 100 .. q + 100.
Images are edge-padded before cutting, exactly as ``training.networks.dense_features`` pads a crop, so a
patch pair and a dense crop give the same features for the same pixel. Inputs are float32 in [0, 1]
(the paper's normalisation). Pixels without ground truth, or whose match falls outside the right image,
are never drawn; ``nonoccluded_only`` also skips pixels the dataset marks occluded.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from service.datasets import StereoSample
from training.losses import HALF_RANGE


@dataclasses.dataclass(frozen=True)
class PatchPairs:
    left: torch.Tensor       # [N, 3, P, P] float32 in [0, 1]
    right: torch.Tensor      # [N, 3, P, P + 2 * half_range]
    inside: torch.Tensor     # [N, 2 * half_range + 1] bool: candidate column inside the right image
    pixels: torch.Tensor     # [N, 2] (y, x) of the left pixels


@dataclasses.dataclass(frozen=True)
class Crop:
    left: torch.Tensor       # [3, h, w] float32 in [0, 1]
    right: torch.Tensor      # [3, h, w]
    disparity: torch.Tensor  # [h, w] float32, NaN where unknown (or occluded, with nonoccluded_only)


def usable_pixels(sample: StereoSample, *, nonoccluded_only: bool = False) -> np.ndarray:
    """Mask of pixels with known ground truth whose rounded match lies inside the right image."""
    known = np.isfinite(sample.disparity)
    truth = np.floor(np.where(known, sample.disparity, 0) + 0.5)
    match = np.arange(sample.disparity.shape[1])[None, :] - truth
    usable = known & (match >= 0) & (match < sample.disparity.shape[1])
    if nonoccluded_only and sample.nonoccluded is not None:
        usable &= sample.nonoccluded
    return usable


def patch_pairs(sample: StereoSample, pixels: np.ndarray, *, patch: int = 37,
                half_range: int = HALF_RANGE) -> PatchPairs:
    """Cut the patch pairs of ``pixels`` ([N, 2] rows (y, x), all usable) from ``sample``."""
    if patch % 2 != 1:
        raise ValueError(f"patch size must be odd (centred on the pixel), got {patch}")
    pixels = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    ys, xs = pixels[:, 0], pixels[:, 1]
    if not usable_pixels(sample)[ys, xs].all():
        raise ValueError("every pixel needs known ground truth with its match inside the right image")
    width, half = sample.left.shape[1], patch // 2
    match = xs - np.floor(sample.disparity[ys, xs] + 0.5).astype(np.int64)
    # Pad so that every strip, even one centred near a border, can be cut: replicate, as dense_features.
    pad = half + half_range
    left = np.pad(sample.left, ((half, half), (half, half), (0, 0)), mode="edge")
    right = np.pad(sample.right, ((half, half), (pad, pad), (0, 0)), mode="edge")
    rows = ys[:, None] + np.arange(patch)[None, :]                            # padded row indices
    left_cols = xs[:, None] + np.arange(patch)[None, :]
    right_cols = match[:, None] + np.arange(patch + 2 * half_range)[None, :]  # q - pad .. q + pad, shifted
    left_patches = left[rows[:, :, None], left_cols[:, None, :]]
    right_strips = right[rows[:, :, None], right_cols[:, None, :]]
    candidates = match[:, None] + np.arange(-half_range, half_range + 1)[None, :]
    inside = (candidates >= 0) & (candidates < width)
    return PatchPairs(left=_to_tensor(left_patches), right=_to_tensor(right_strips),
                      inside=torch.from_numpy(inside), pixels=torch.from_numpy(pixels))


def random_patch_pairs(sample: StereoSample, rng: np.random.Generator, *, count: int, patch: int = 37,
                       half_range: int = HALF_RANGE, nonoccluded_only: bool = False) -> PatchPairs:
    """``count`` patch pairs at pixels drawn uniformly from the usable ones (with replacement if few)."""
    ys, xs = np.nonzero(usable_pixels(sample, nonoccluded_only=nonoccluded_only))
    if ys.size == 0:
        raise ValueError(f"{sample.name}: no pixel with usable ground truth")
    chosen = rng.choice(ys.size, size=count, replace=ys.size < count)
    return patch_pairs(sample, np.stack([ys[chosen], xs[chosen]], axis=1), patch=patch, half_range=half_range)


def random_crop(sample: StereoSample, rng: np.random.Generator, *, height: int, width: int,
                nonoccluded_only: bool = False) -> Crop:
    """A ``height`` x ``width`` crop at a random position, the same window in both views."""
    full_height, full_width = sample.disparity.shape
    if height > full_height or width > full_width:
        raise ValueError(f"crop {height} x {width} is larger than {sample.name} "
                         f"({full_height} x {full_width})")
    top, left = int(rng.integers(full_height - height + 1)), int(rng.integers(full_width - width + 1))
    window = np.s_[top : top + height, left : left + width]
    disparity = sample.disparity[window].copy()
    if nonoccluded_only and sample.nonoccluded is not None:
        disparity[~sample.nonoccluded[window]] = np.nan
    return Crop(left=_to_tensor(sample.left[window][None])[0],
                right=_to_tensor(sample.right[window][None])[0], disparity=torch.from_numpy(disparity))


def _to_tensor(images: np.ndarray) -> torch.Tensor:
    """uint8 [N, H, W, 3] -> float32 [N, 3, H, W] in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(images.transpose(0, 3, 1, 2))).float().div_(255.0)
