"""``python -m bench gpu`` (bench/gpu.py) on a tiny pair: both devices timed stage by stage, the GPU's
maps compared with the CPU's. On a GPU and, through test_simulated.py, on Numba's CUDA simulator."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from bench import gpu
from service.features import default_model_dir
from tests.helpers import require_gpu, slanted_plane_pair

require_gpu()


def test_a_row_times_both_devices_and_compares_their_maps(monkeypatch: pytest.MonkeyPatch) -> None:
    left, right, _, _ = slanted_plane_pair(5, 16)

    def png(image: np.ndarray) -> bytes:
        buffer = io.BytesIO()
        Image.fromarray(image).save(buffer, format="PNG")
        return buffer.getvalue()

    monkeypatch.setitem(gpu.SIZES, "tiny", (5, 16, 6))
    monkeypatch.setattr(gpu, "pair_png", lambda size: (png(left), png(right)))
    report = gpu.run_model(default_model_dir(), "tiny", repeats=1, towers_kind="onnx")
    assert report["shape"] == [5, 16, 6]
    for device in ("cpu", "cuda"):
        assert {"towers", "cost_volume", "sgm", "right_sgm", "lr_check", "fill", "total"} <= set(
            report[device]["median"])
    assert report["agreement"] >= 0.99
    assert report["speedup"] > 0


def test_the_sgm_sweep_times_each_threads_choice(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(gpu.SIZES, "tiny", (2, 5, 40))
    rows = gpu.sgm_threads_sweep("tiny", [32, 64], repeats=1)
    assert [row["threads"] for row in rows] == [32, 64]
    assert all(row["gpu_s"] > 0 and row["cpu_s"] > 0 for row in rows)
