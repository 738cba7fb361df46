"""Towers that remember the features of the last few pairs they saw.

The SGM penalty rule (service.evaluation.tuning) matches the same pairs once per (P1, P2) of its grid,
25 times, and only the stages after the towers depend on P1 and P2. Wrapped in :class:`CachedTowers`,
the towers run once per pair instead: on the split's 256 x 512 pairs adsm-paper-int8's towers are ~94 %
of a pair's matching at one thread (7.5 of 8.0 s), adsm-fast's ~62 % (0.61 of 0.98 s).

>>> towers = CachedTowers(FeatureTowers("service/models/adsm-fast"), pairs=20)  # a model  # doctest: +SKIP
>>> matcher = Matcher(towers)                           # its towers run once per pair  # doctest: +SKIP

A cached pair holds both views' features, ``8 C H W`` bytes (C channels): 67 MB for a 64-channel model
on one split pair, 1.3 GB for the 20 pairs of ``synthetic:20``. The cache keeps copies: ONNX Runtime's
outputs live in its capped arena (service/features/towers.py) for as long as the arrays do, and 20 pairs
of them ran it out of memory. The copies are returned as stored, so whoever receives them must not write
into them; the Matcher only reads its features.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from typing import Any

import numpy as np

from service.features.protocol import Towers


class CachedTowers:
    """:class:`~service.features.Towers` that run ``towers`` once per distinct pair, keeping the
    features of the ``pairs`` most recently used pairs (at least one)."""

    def __init__(self, towers: Towers, *, pairs: int) -> None:
        if pairs < 1:
            raise ValueError(f"pairs must be >= 1, got {pairs}")
        self.towers = towers
        self.pairs = pairs
        self._features: OrderedDict[bytes, tuple[np.ndarray, np.ndarray]] = OrderedDict()

    @property
    def manifest(self) -> dict[str, Any]:
        return self.towers.manifest

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = _digest(left, right)
        if key in self._features:
            self._features.move_to_end(key)
            return self._features[key]
        left_features, right_features = self.towers(left, right)
        features = (np.array(left_features), np.array(right_features))
        self._features[key] = features
        if len(self._features) > self.pairs:
            self._features.popitem(last=False)
        return features

    def warmup(self) -> None:
        self.towers.warmup()


def _digest(left: np.ndarray, right: np.ndarray) -> bytes:
    # The shapes and dtypes are part of the key: the same bytes may be another image.
    digest = hashlib.blake2b(digest_size=20)
    for image in (left, right):
        digest.update(f"{image.shape}{image.dtype.str}".encode())
        digest.update(np.ascontiguousarray(image).data)
    return digest.digest()
