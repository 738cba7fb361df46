"""A dataset's pairs with sensor noise added to both views: how a matcher degrades with noisier cameras.

``adsm eval --noise SIGMA`` measures it. The synthetic split's cameras add up to 5 grey levels of noise,
which is what makes a 3x3 NCC its worst matcher while it is the best on the nearly noise-free real pairs
(docs/data.md, "What the camera effects do to the ranking of matchers"); with this, any dataset can be
measured at the noise of the cameras it stands for.

    >>> import numpy as np
    >>> from service.datasets import StereoSample
    >>> view = np.full((4, 6, 3), 100, np.uint8)
    >>> pair = StereoSample("flat", view, view, np.zeros((4, 6), np.float32))
    >>> noisy = NoisyViews([pair], sigma=2.0)[0]
    >>> noisy.name, bool((noisy.left != noisy.right).any()), noisy.disparity is pair.disparity
    ('flat', True, True)

Gaussian, independent per pixel, channel and view, rounded and clipped to 0-255 (as an 8-bit camera would
record it); the ground truth, mask and search range are kept. The noise of pair ``i`` comes from
``numpy.random.default_rng([seed, i])``, so a pair reads the same however the dataset is walked.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import overload

import numpy as np

from .sample import StereoSample

__all__ = ["MAX_NOISE_SIGMA", "NoisyViews"]

MAX_NOISE_SIGMA = 64.0  # grey levels; beyond it an 8-bit view is mostly clipped noise


class NoisyViews(Sequence[StereoSample]):
    """``dataset``'s pairs with Gaussian noise of ``sigma`` grey levels (0-255 scale) added to both views."""

    def __init__(self, dataset: Sequence[StereoSample], *, sigma: float, seed: int = 0) -> None:
        if isinstance(sigma, bool) or not isinstance(sigma, int | float) or not math.isfinite(sigma) \
                or not 0 <= sigma <= MAX_NOISE_SIGMA:
            raise ValueError(f"noise sigma must be a number of grey levels in [0, {MAX_NOISE_SIGMA:g}], "
                             f"got {sigma!r}")
        self.dataset, self.sigma, self.seed = dataset, float(sigma), seed
        self.name = f"{getattr(dataset, 'name', 'dataset')} + noise sigma {self.sigma:g}"

    def __len__(self) -> int:
        return len(self.dataset)

    @overload
    def __getitem__(self, index: int) -> StereoSample: ...
    @overload
    def __getitem__(self, index: slice) -> Sequence[StereoSample]: ...

    def __getitem__(self, index: int | slice) -> StereoSample | Sequence[StereoSample]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if not -len(self) <= index < len(self):
            raise IndexError(f"pair {index} of {len(self)}")
        index %= len(self)
        sample = self.dataset[index]
        if not self.sigma:
            return sample
        rng = np.random.default_rng([self.seed, index])
        left, right = (np.clip(np.rint(view + rng.normal(0.0, self.sigma, view.shape)), 0, 255)
                       .astype(np.uint8) for view in (sample.left, sample.right))
        return dataclasses.replace(sample, left=left, right=right)
