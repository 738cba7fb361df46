"""The Matcher on the GPU (``device="cuda"``) against the same Matcher on the CPU, end to end (issue 16).

Same towers, same features: the maps may differ only where a cost cell rounded the other way
(test_kernels.py), which on these pairs moves a few pixels at most; and a call over the free GPU memory is
refused before it allocates. Runs on a GPU and, in every test run, on Numba's CUDA simulator
(test_simulated.py), where the pair is tiny.
"""

from __future__ import annotations

import numpy as np
import pytest
from numba import config

from service.features import default_model_dir
from service.match_options import MatchOptions
from service.matcher import Matcher
from tests.helpers import require_gpu, slanted_plane_pair

require_gpu()

SIMULATED = bool(config.ENABLE_CUDASIM)
HEIGHT, WIDTH, DISPARITIES = (5, 16, 6) if SIMULATED else (96, 160, 32)
# Every kernel of the GPU path, and the variants that reach other ones.
OPTIONS = {
    "defaults": MatchOptions(max_disparity=DISPARITIES),
    "every_step": MatchOptions(max_disparity=DISPARITIES, confidence=True, shiftable_windows=True,
                               adaptive_p2=True, border=True),
    "right_winners_from_the_left_volume": MatchOptions(max_disparity=DISPARITIES, right_sgm=False),
    "negative_min_disparity": MatchOptions(min_disparity=-3, max_disparity=DISPARITIES),
    "no_fill": MatchOptions(max_disparity=DISPARITIES, fill=False, background_fill=False),
    "mc_cnn_fill_no_subpixel": MatchOptions(max_disparity=DISPARITIES, background_fill=False, subpixel=False),
    "no_check": MatchOptions(max_disparity=DISPARITIES, lr_check=False),
    "no_sgm": MatchOptions(max_disparity=DISPARITIES, sgm=False),
}


@pytest.fixture(scope="module")
def matchers() -> tuple[Matcher, Matcher]:
    folder = default_model_dir()
    return Matcher.from_folder(folder, device="cpu"), Matcher.from_folder(folder, device="cuda")


@pytest.mark.parametrize("name", sorted(OPTIONS))
def test_the_gpu_path_equals_the_cpu_path(matchers: tuple[Matcher, Matcher], name: str) -> None:
    left, right, _, _ = slanted_plane_pair(HEIGHT, WIDTH)
    on_cpu, on_gpu = (matcher(left, right, OPTIONS[name]) for matcher in matchers)
    same_validity = on_gpu.validity == on_cpu.validity
    same_disparity = np.isclose(on_gpu.disparity, on_cpu.disparity, rtol=0, atol=1e-5, equal_nan=True)
    assert same_validity.mean() >= 0.99 and same_disparity.mean() >= 0.99, name
    assert (on_cpu.confidence is None) == (on_gpu.confidence is None)
    if on_cpu.confidence is not None:
        assert np.isclose(on_gpu.confidence, on_cpu.confidence, rtol=0, atol=1e-5).mean() >= 0.99
    # The GPU stages are timed like the CPU's, stage by stage.
    assert set(on_gpu.timings) == set(on_cpu.timings), name


def test_a_call_over_the_free_gpu_memory_is_refused_before_anything_is_allocated(
        matchers: tuple[Matcher, Matcher], monkeypatch: pytest.MonkeyPatch) -> None:
    from service.cuda import pipeline
    from service.limits import LimitError

    left, right, _, _ = slanted_plane_pair(HEIGHT, WIDTH)
    options = OPTIONS["defaults"]
    needed = pipeline.device_bytes(HEIGHT, WIDTH, DISPARITIES, int(matchers[1].manifest["channels"]))
    held = matchers[1]._device_workspace.held_bytes()
    monkeypatch.setattr(pipeline, "free_device_bytes", lambda: float(needed - held - 1))
    with pytest.raises(LimitError, match=r"would need \d+ MiB of GPU memory"):
        matchers[1](left, right, options)
    monkeypatch.setattr(pipeline, "free_device_bytes", lambda: float(needed - held))
    matchers[1](left, right, options)  # exactly enough
