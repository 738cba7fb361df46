"""Shared fixtures: a throw-away Numba cache for the test session and unit-norm random feature maps."""

from __future__ import annotations

import os
import tempfile

import numpy as np
import pytest

# Before any kernel module is imported (service.jit reads it once): keep test runs off the user's cache.
os.environ.setdefault("ADSM_NUMBA_CACHE_DIR", os.path.join(tempfile.gettempdir(), "adsm-test-numba-cache"))


def unit_features(rng: np.random.Generator, channels: int, height: int, width: int) -> np.ndarray:
    """float32 (C, H, W) features with unit L2 norm over C, like the towers' output."""
    features = rng.standard_normal((channels, height, width)).astype(np.float32)
    return features / np.linalg.norm(features, axis=0, keepdims=True)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
