"""Shared fixtures: a throw-away Numba cache, unit-norm random feature maps, a ready in-process service."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import AsyncIterator

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


@contextlib.asynccontextmanager
async def ready_client(app, *, timeout: float = 120) -> AsyncIterator:
    """An httpx client of ``app`` in-process, inside its lifespan, once ``/readyz`` answers 200."""
    import anyio
    import httpx

    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test", timeout=60) as client:
            with anyio.fail_after(timeout):
                while (await client.get("/readyz")).status_code != 200:
                    await anyio.sleep(0.05)
            yield client
