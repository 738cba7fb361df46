"""The stages between the towers and the border band on the GPU, in the Matcher's order (service/matcher.py):

    cost volume -> shiftable windows -> SGM -> winner-takes-all -> sub-pixel -> confidence -> the right
    view's SGM and winners -> inner check -> fill

The features go up once, the disparity, validity and confidence maps come down once; the two int16 cost
volumes live on the GPU only, in a :class:`DeviceWorkspace` kept between calls, and swap roles the way
the CPU path's two buffers do. Each stage ends with a synchronisation so that the per-stage timings are
the GPU's work and not the launch's. The border band and the weighted median run on the host afterwards:
they read H x W maps only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import cuda

from service.aggregation.shiftable_windows import SHIFT_RADIUS
from service.cost import COST_DTYPE
from service.cuda import pixels, sgm, volume
from service.filling import BACKGROUND_RUN, MC_CNN_FRACTION, MC_CNN_RUN, MISMATCH_FRACTION
from service.filling.rays import _DIRECTIONS
from service.limits import LimitError
from service.match_options import MatchOptions
from service.optimization import PATHS
from service.optimization.sgm import P2_EDGE
from service.validation import Validity
from service.validation.inner_check import CAUSE_TOLERANCE

# The GPU check hard-codes MC-CNN's 1-px cause tolerance; a change there must reach the kernel too.
assert CAUSE_TOLERANCE == 1


class GpuMemoryError(LimitError):
    """A call would need more GPU memory than the GPU has free; nothing was allocated (HTTP 413, like the
    host's memory plan)."""


def device_bytes(height: int, width: int, disparities: int, channels: int) -> int:
    """GPU memory of one call: the two int16 volumes, both views' float32 features and the H x W maps
    (winners of both views, the disparity, the filled disparity, the confidence: 4 bytes each; two
    validity maps: 1 byte each)."""
    pixels = height * width
    return 2 * 2 * pixels * disparities + 2 * 4 * channels * pixels + (5 * 4 + 2) * pixels


def free_device_bytes() -> float:
    """Bytes free on the current GPU (NaN on Numba's CUDA simulator, which reports none)."""
    free, _ = cuda.current_context().get_memory_info()
    return float(free)


class DeviceWorkspace:
    """The two int16 cost volumes on the GPU, kept for the next call of the same shape."""

    def __init__(self) -> None:
        self._shape: tuple[int, int, int] | None = None
        self._volumes: tuple[Any, Any] | None = None

    def held_bytes(self) -> int:
        """Bytes of the volumes kept now (freed or reused by the next call)."""
        return 0 if self._shape is None else 2 * 2 * int(np.prod(self._shape))

    def check(self, needed: int) -> None:
        """:class:`GpuMemoryError` unless ``needed`` bytes fit in what is free plus what this workspace
        holds, checked before anything is allocated: an out-of-memory error inside a kernel launch would
        leave the service with a failed request and a confused context instead of a clear refusal."""
        available = free_device_bytes() + self.held_bytes()
        if math.isfinite(available) and needed > available:
            raise GpuMemoryError(
                f"the GPU path would need {needed / 2**20:.0f} MiB of GPU memory, {available / 2**20:.0f} "
                "MiB are free; send smaller images or lower max_disparity"
            )

    def volumes(self, shape: tuple[int, int, int]) -> tuple[Any, Any]:
        if self._volumes is None or self._shape != shape:
            self._volumes = None  # the old pair is freed before the new one is allocated
            self._volumes = (cuda.device_array(shape, COST_DTYPE), cuda.device_array(shape, COST_DTYPE))
            self._shape = shape
        return self._volumes


def match_volume(
    left_features: np.ndarray, right_features: np.ndarray, left: np.ndarray, right: np.ndarray, *,
    disparities: int, min_disparity: int, scale: float, p1: float, p2: float, options: MatchOptions,
    shiftable: bool, workspace: DeviceWorkspace, lap: Callable[[str], None],
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(disparity, validity, peak-ratio confidence or None) of the left view, as the CPU path computes
    them from the same features (service.matcher.Matcher), with the volumes on the GPU."""
    height, width = left.shape[:2]
    shape = (height, width, disparities)
    if disparities > sgm.MAX_DISPARITIES:
        raise ValueError(f"the GPU path searches at most {sgm.MAX_DISPARITIES} disparities, "
                         f"got {disparities}")
    workspace.check(device_bytes(height, width, disparities, int(left_features.shape[0])))
    raw, spare = workspace.volumes(shape)
    volume.cost_volume(cuda.to_device(np.ascontiguousarray(left_features, np.float32)),
                       cuda.to_device(np.ascontiguousarray(right_features, np.float32)),
                       disparities, scale=scale, min_disparity=min_disparity, out=raw)
    _done(lap, "cost_volume")
    if shiftable:
        volume.shiftable_windows(raw, radius=SHIFT_RADIUS, out=spare)
        raw, spare = spare, raw
        _done(lap, "shiftable_windows")
    aggregated = raw
    if options.sgm:
        guide = _guide(left) if options.adaptive_p2 else None
        sgm.aggregate(raw, p1=p1, p2=p2, out=spare, guide=guide, edge=_edge(options))
        aggregated = spare
    _done(lap, "sgm")
    pixel_blocks = pixels.blocks(height * width)
    winners = cuda.device_array((height, width), np.int32)
    right_winners = cuda.device_array((height, width), np.int32)
    pixels.winners[pixel_blocks, pixels.THREADS](aggregated, winners)
    right_sgm = options.lr_check and options.sgm and options.right_sgm
    if options.lr_check and not right_sgm:
        pixels.right_winners[pixel_blocks, pixels.THREADS](aggregated, min_disparity, right_winners)
    _done(lap, "disparity")
    if options.subpixel:
        disparity = cuda.device_array((height, width), np.float32)
        pixels.refine[pixel_blocks, pixels.THREADS](aggregated, winners, disparity)
        _done(lap, "subpixel")
    else:
        disparity = cuda.to_device(winners.copy_to_host().astype(np.float32))
    confidence = None
    if options.confidence:
        lowest = np.int32(np.floor(-(PATHS if options.sgm else 1) * scale))
        peak = cuda.device_array((height, width), np.float32)
        pixels.confidence[pixel_blocks, pixels.THREADS](aggregated, winners, lowest, peak)
        confidence = peak.copy_to_host()
        _done(lap, "confidence")
    if right_sgm:
        # The left view's aggregated volume has been read for the last time: its buffer takes the right
        # view's raw costs, and the raw buffer their aggregation.
        volume.right_view_volume(raw, scale=scale, min_disparity=min_disparity, out=spare)
        guide = _guide(right) if options.adaptive_p2 else None
        sgm.aggregate(spare, p1=p1, p2=p2, out=raw, guide=guide, edge=_edge(options))
        pixels.winners[pixel_blocks, pixels.THREADS](raw, right_winners)
        _done(lap, "right_sgm")
    if min_disparity:
        pixels.add_offset[pixel_blocks, pixels.THREADS](disparity, right_winners, np.int32(min_disparity))
    if not options.lr_check:
        return disparity.copy_to_host(), np.zeros((height, width), np.uint8), confidence
    validity = cuda.device_array((height, width), np.uint8)
    pixels.check[pixel_blocks, pixels.THREADS](disparity, right_winners, min_disparity, disparities,
                                                np.float32(options.lr_check_threshold), validity)
    _done(lap, "lr_check")
    if not options.fill:
        host_disparity, host_validity = disparity.copy_to_host(), validity.copy_to_host()
        host_disparity[host_validity != Validity.VALID] = np.nan
        return host_disparity, host_validity, confidence
    run, (numerator, denominator) = ((BACKGROUND_RUN, MISMATCH_FRACTION) if options.background_fill
                                     else (MC_CNN_RUN, MC_CNN_FRACTION))
    filled = cuda.device_array((height, width), np.float32)
    filled_validity = cuda.device_array((height, width), np.uint8)
    pixels.fill[pixel_blocks, pixels.THREADS](disparity, validity, cuda.to_device(_DIRECTIONS), run,
                                               numerator, denominator, filled, filled_validity)
    result = filled.copy_to_host(), filled_validity.copy_to_host(), confidence
    _done(lap, "fill")
    return result


def _guide(image: np.ndarray) -> Any:
    return cuda.to_device(image.mean(axis=2, dtype=np.float32))


def _edge(options: MatchOptions) -> float:
    return P2_EDGE if options.adaptive_p2 else 0.0


def _done(lap: Callable[[str], None], stage: str) -> None:
    cuda.synchronize()
    lap(stage)
