"""Matcher: a rectified stereo pair -> disparity, validity and stage timings; the runtime's one entry point.

    towers (at the tower scale) -> cost_volume -> shiftable_windows -> sgm -> disparity (WTA) -> subpixel
    -> right_sgm (the right view's winners) -> lr_check (inner check) -> fill -> border -> weighted_median

Defaults come from the model's manifest (``cost.scale``, ``sgm.p1``, ``sgm.p2``,
``disparity.default_max``); every post-processing step can be switched off per call with
:class:`MatchOptions`. Peak memory follows service/memory.py (images, features, the towers' tiles, two
int16 cost volumes, results), checked against ``max_request_bytes`` before anything is allocated. The
towers run in tiles (service/features/tiles.py) so that one ONNX run's work area is bounded for every
aspect ratio; the features are dropped as soon as the cost volume exists. Both volumes live in a
:class:`~service.cost.VolumeWorkspace` kept between calls (``reuse_volumes=False`` allocates them per
call instead; see that module for the measurement). With ``device="cuda"`` the stages from the cost volume
to the fill run on the GPU instead (service/cuda, docs/gpu.md), the rest as here.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from service import jit
from service.aggregation import shiftable_windows
from service.cost import VolumeWorkspace, cost_volume, right_view_volume
from service.cuda import check_device, require_cuda
from service.disparity import left_right_winners, winner_takes_all
from service.features import FeatureTowers, Towers, default_model_dir, load_manifest
from service.features.tiles import tiled_features
from service.features.towers import MAX_THREADS
from service.filling import (
    BACKGROUND_RUN,
    MC_CNN_FRACTION,
    MC_CNN_RUN,
    MISMATCH_FRACTION,
    fill_border_band,
    fill_invalid,
)
from service.filtering import weighted_median
from service.kernels import load_kernels_in_background
from service.limits import LimitError, SearchRange, search_range
from service.match_options import MatchOptions, StereoResult, colour_images
from service.memory import MemoryPlan, plan_request
from service.optimization import PATHS, aggregate
from service.refinement import refine_subpixel
from service.validation import Validity, inner_check
from service.validation.confidence import cost_confidence, weigh_by_check

__all__ = ["MatchOptions", "Matcher", "MemoryLimitError", "StereoResult", "Validity"]

logger = logging.getLogger("adsm")


class MemoryLimitError(LimitError):
    """The request's memory plan (service.memory) is over the matcher's limit; nothing was allocated."""


class Matcher:
    """Stereo matcher of one model. Not thread-safe: run one call at a time per instance.

    ``towers`` is anything that satisfies :class:`~service.features.Towers`: a folder's ONNX towers
    (:meth:`from_folder`), or the trainer's PyTorch towers. The Matcher in turn satisfies
    :class:`service.protocols.StereoMatcher`, what the HTTP service needs.
    """

    def __init__(
        self,
        towers: Towers,
        *,
        threads: int | None = None,
        reuse_volumes: bool = True,
        max_request_bytes: int | None = None,
        device: str | None = None,
    ) -> None:
        if threads is not None and not 1 <= threads <= MAX_THREADS:
            raise ValueError(f"threads must be in 1..{MAX_THREADS}, got {threads}")
        self.towers: Towers = towers
        # None: no limit (a library caller owns its memory); the service and the CLI set one.
        self.max_request_bytes = max_request_bytes
        self.threads = threads
        self.manifest: dict[str, Any] = towers.manifest
        self.workspace = VolumeWorkspace() if reuse_volumes else None
        self._preparing: list[threading.Thread] = []
        # "cpu" or "cuda" (service/cuda): where the stages after the towers run.
        self.device = check_device(device)
        self._device_workspace: Any = None
        if self.device == "cuda":
            require_cuda()
            from service.cuda.pipeline import DeviceWorkspace

            self._device_workspace = DeviceWorkspace()

    @classmethod
    def from_folder(
        cls,
        folder: str | Path | None = None,
        *,
        threads: int | None = None,
        providers: Sequence[str] | None = None,
        reuse_volumes: bool = True,
        max_request_bytes: int | None = None,
        prepare_for: tuple[int, int, MatchOptions] | None = None,
        device: str | None = None,
    ) -> Matcher:
        """Load (and sha256-verify) a model folder; ``None`` is the default shipped model.

        ``prepare_for=(height, width, options)``: the first call's pair, when it is known before the model
        loads (``adsm predict`` reads it from the headers): :meth:`prepare` starts before the towers'
        sessions are built, so its work overlaps the model load and the decoding.

        ``device``: ``"cpu"`` (the default) or ``"cuda"``, where the stages after the towers run (None:
        ``$ADSM_DEVICE``, else the CPU); :class:`~service.cuda.CudaUnavailableError` where no GPU is
        usable."""
        folder = default_model_dir() if folder is None else Path(folder)
        device = check_device(device)
        if device == "cuda":
            require_cuda()  # before the model loads: the error, not a minute's wait, comes first
        workspace = VolumeWorkspace() if reuse_volumes else None
        preparing = [] if prepare_for is None else _start_preparing(load_manifest(folder), workspace,
                                                                    *prepare_for)
        towers = FeatureTowers(folder, threads=threads, providers=providers)
        matcher = cls(towers, threads=threads, reuse_volumes=reuse_volumes,
                      max_request_bytes=max_request_bytes, device=device)
        matcher.workspace = workspace
        matcher._preparing = preparing
        return matcher

    def warmup(self) -> None:
        """Check the towers against the manifest, then run the real pipeline on a tiny pair once per set
        of options that reaches a different kernel, so every kernel is compiled (or loaded from the cache)
        before the first request. A cache that cannot be read (a corrupt index) is cleared and the kernels
        compiled afresh, once; any other failure is raised."""
        self._prepared()
        self.towers.warmup()
        rng = np.random.default_rng(0)
        left = rng.integers(0, 256, (12, 24, 3), dtype=np.uint8)
        right = np.roll(left, -2, axis=1)
        try:
            self._warm_kernels(left, right)
        except Exception as error:
            if not jit.raised_by_cache(error):
                raise
            logger.warning("numba cache %s unreadable (%s: %s): cleared, compiling the kernels afresh",
                           jit.cache_dir(), type(error).__name__, error)
            jit.clear_cache()
            self._warm_kernels(left, right)

    def _warm_kernels(self, left: np.ndarray, right: np.ndarray) -> None:
        # All on: cost volume, shiftable windows, SGM, winner-takes-all, sub-pixel, confidence, the right
        # view's volume and SGM, inner check, filling; right_sgm off: both views' winners in one pass.
        every_kernel = MatchOptions(max_disparity=4, confidence=True, shiftable_windows=True, border=True)
        for options in (every_kernel, MatchOptions(max_disparity=4, right_sgm=False)):
            self(left, right, options)

    def prepare(self, height: int, width: int, options: MatchOptions | None = None) -> None:
        """Start, in background threads, what the first call on an ``height x width`` pair would otherwise
        do first: load the Numba kernels (service/kernels.py) and map the two cost volumes with their
        pages present (service/cost/workspace.py). The next call waits for both before its towers run
        (the wait is its ``prepare`` timing). For one-off runs (``adsm predict``, whose model load and
        decoding the work overlaps); a warm matcher gains nothing. Raises as :meth:`check_memory` does;
        a failure in the threads is left to the call to meet."""
        options = MatchOptions() if options is None else options
        self.check_memory(height, width, options)
        self._preparing += _start_preparing(self.manifest, self.workspace, height, width, options)

    def _prepared(self) -> float:
        """Wait for :meth:`prepare`'s threads (the workspace must not be touched while they run); returns
        the seconds waited."""
        started = time.perf_counter()
        while self._preparing:
            self._preparing.pop().join()
        return time.perf_counter() - started

    def uses_shiftable_windows(self, options: MatchOptions) -> bool:
        """Whether a call with ``options`` runs the shiftable-window step (None: the manifest's setting)."""
        return self._model_step(options.shiftable_windows, "sgm", "shiftable_windows", absent=False)

    def uses_border_band(self, options: MatchOptions) -> bool:
        """Whether a call with ``options`` runs the border band step (None: the manifest's setting)."""
        return self._model_step(options.border, "filling", "border_band", absent=True)

    def _model_step(self, asked: bool | None, section: str, key: str, *, absent: bool) -> bool:
        # A step whose default is the model's: the call's choice, else manifest[section][key], else absent.
        if asked is None:
            return bool(self.manifest.get(section, {}).get(key, absent))
        return bool(asked)

    def search_range(self, width: int, options: MatchOptions) -> SearchRange:
        """The range a call searches (service/limits.py): the option's, else the model's default size
        clipped to the width; DisparityRangeError (a ValueError) when the range cannot fit the image."""
        return search_range(width, min_disparity=options.min_disparity, max_disparity=options.max_disparity,
                            default_max=int(self.manifest["disparity"]["default_max"]))

    def plan(self, height: int, width: int, options: MatchOptions | None = None) -> MemoryPlan:
        """Peak memory of a call on an ``height x width`` pair (service/memory.py), before any allocation."""
        options = MatchOptions() if options is None else options
        return plan_request(height, width, self.search_range(width, options).count, self.manifest,
                            scale=options.tower_scale)

    def check_memory(self, height: int, width: int, options: MatchOptions | None = None) -> MemoryPlan:
        """The plan of a call; raise :class:`MemoryLimitError` when it is over ``max_request_bytes``."""
        plan = self.plan(height, width, options)
        if self.max_request_bytes is not None and plan.peak_bytes > self.max_request_bytes:
            raise MemoryLimitError(
                f"{width} x {height} pixels x {plan.disparities} disparities would need "
                f"{plan.describe()}, over the limit of {self.max_request_bytes / 2**20:.0f} MiB per request; "
                "send smaller images or lower max_disparity"
            )
        return plan

    def __call__(
        self, left: np.ndarray, right: np.ndarray, options: MatchOptions | None = None, **settings: Any
    ) -> StereoResult:
        """Disparity of the left view of a rectified pair (uint8 HxWx3 or HxW grey each, same size).

        Options come as a :class:`MatchOptions`, as keywords (``matcher(left, right, max_disparity=64)``),
        or both (the keywords replace the object's fields).
        """
        options = MatchOptions() if options is None else options
        if not isinstance(options, MatchOptions):
            raise ValueError(f"options must be MatchOptions, got {type(options).__name__}")
        if settings:
            unknown = sorted(set(settings) - {field.name for field in dataclasses.fields(MatchOptions)})
            if unknown:
                raise ValueError(f"unknown match option {unknown[0]!r}; MatchOptions has "
                                 + ", ".join(field.name for field in dataclasses.fields(MatchOptions)))
            options = dataclasses.replace(options, **settings)
        left, right = colour_images(left, right)
        width = left.shape[1]
        disparities = self.check_memory(left.shape[0], width, options).disparities
        offset = options.min_disparity
        p1 = float(self.manifest["sgm"]["p1"] if options.p1 is None else options.p1)
        p2 = float(self.manifest["sgm"]["p2"] if options.p2 is None else options.p2)
        jit.set_threads(self.threads)

        timings: dict[str, float] = {}
        start = clock = time.perf_counter()

        def lap(stage: str) -> None:
            nonlocal clock
            now = time.perf_counter()
            timings[stage] = now - clock
            clock = now

        if self._preparing:  # Matcher.prepare's work, if it is still running
            self._prepared()
            lap("prepare")

        # A list the stages empty: the features are freed as soon as the cost volume exists.
        features = list(tiled_features(self.towers, left, right, scale=options.tower_scale))
        lap("towers")
        match_volume = self._match_on_cpu if self._device_workspace is None else self._match_on_gpu
        disparity, validity, confidence = match_volume(
            features, left, right, disparities=disparities, offset=offset,
            scale=float(self.manifest["cost"]["scale"]), p1=p1, p2=p2, options=options, lap=lap)
        if self.uses_border_band(options):
            disparity, validity = fill_border_band(disparity, validity,
                                                   surface_run=options.border_surface_run)
            lap("border")
        if options.weighted_median:
            disparity = weighted_median(disparity, left)
            lap("weighted_median")
        if confidence is not None:
            confidence = weigh_by_check(confidence, validity, disparity)
        timings["total"] = time.perf_counter() - start
        return StereoResult(disparity, validity, timings, confidence)

    def _match_on_cpu(
        self, features: list[np.ndarray], left: np.ndarray, right: np.ndarray, *, disparities: int,
        offset: int, scale: float, p1: float, p2: float, options: MatchOptions, lap: Callable[[str], None],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The stages from the cost volume to the fill on the CPU (Numba): (disparity, validity, the
        peak-ratio confidence or None)."""
        left_features, right_features = features
        features.clear()
        shape = (left.shape[0], left.shape[1], disparities)
        raw, aggregated = (None, None) if self.workspace is None else self.workspace.volumes(shape)
        volume = cost_volume(left_features, right_features, disparities, scale=scale, min_disparity=offset,
                             out=raw)
        del left_features, right_features
        lap("cost_volume")
        if self.uses_shiftable_windows(options):
            shiftable_windows(volume)
            lap("shiftable_windows")
        cost = volume
        if options.sgm:
            guide = left.mean(axis=2, dtype=np.float32) if options.adaptive_p2 else None
            volume = aggregate(volume, p1=p1, p2=p2, out=aggregated, guide=guide)
        lap("sgm")
        # The right view aggregated in its own frame needs its own pass, after the left volume is read.
        right_sgm = options.lr_check and options.sgm and options.right_sgm
        if options.lr_check and not right_sgm:
            winners, right_winners = left_right_winners(volume, min_disparity=offset)
        else:
            winners = winner_takes_all(volume)
        lap("disparity")
        if options.subpixel:
            disparity = refine_subpixel(volume, winners)
            lap("subpixel")
        else:
            disparity = winners.astype(np.float32)
        confidence = None
        if options.confidence:
            # The lowest cost the volume can hold: every path's L is at least the raw cost, >= -scale.
            confidence = cost_confidence(volume, winners, lowest=-(PATHS if options.sgm else 1) * scale)
            lap("confidence")
        if right_sgm:
            # In place: the left view's raw costs become the right view's, aggregated into the buffer that
            # held the left view's (both read for the last time above).
            cost = right_view_volume(cost, scale=scale, min_disparity=offset, out=cost)
            guide = right.mean(axis=2, dtype=np.float32) if options.adaptive_p2 else None
            right_winners = winner_takes_all(aggregate(cost, p1=p1, p2=p2, out=volume, guide=guide))
            lap("right_sgm")
        del volume, raw, aggregated, cost
        if offset:  # cell indices -> disparities
            disparity += np.float32(offset)
            if options.lr_check:
                right_winners += np.int32(offset)
        if options.lr_check:
            validity = inner_check(disparity, right_winners, disparities, min_disparity=offset,
                                   threshold=options.lr_check_threshold)
            lap("lr_check")
            if options.fill:
                run, fraction = ((BACKGROUND_RUN, MISMATCH_FRACTION) if options.background_fill
                                 else (MC_CNN_RUN, MC_CNN_FRACTION))
                disparity, validity = fill_invalid(disparity, validity, background_run=run,
                                                   mismatch_fraction=fraction)
                lap("fill")
            else:
                disparity[validity != Validity.VALID] = np.nan
        else:
            validity = np.zeros(disparity.shape, np.uint8)
        return disparity, validity, confidence

    def _match_on_gpu(
        self, features: list[np.ndarray], left: np.ndarray, right: np.ndarray, *, disparities: int,
        offset: int, scale: float, p1: float, p2: float, options: MatchOptions, lap: Callable[[str], None],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The same stages on the GPU (service/cuda/pipeline.py)."""
        from service.cuda.pipeline import match_volume

        left_features, right_features = features
        features.clear()
        return match_volume(left_features, right_features, left, right, disparities=disparities,
                            min_disparity=offset, scale=scale, p1=p1, p2=p2, options=options,
                            shiftable=self.uses_shiftable_windows(options), workspace=self._device_workspace,
                            lap=lap)


def _start_preparing(manifest: dict[str, Any], workspace: VolumeWorkspace | None, height: int, width: int,
                     options: MatchOptions) -> list[threading.Thread]:
    """Threads loading the kernels and reserving the volumes of a call (Matcher.prepare)."""
    span = search_range(width, min_disparity=options.min_disparity, max_disparity=options.max_disparity,
                        default_max=int(manifest["disparity"]["default_max"]))
    threads = [load_kernels_in_background(confidence=options.confidence)]
    if workspace is not None:
        shape = (height, width, span.count)
        threads.append(threading.Thread(target=_quietly, args=(workspace.reserve, shape), name="adsm-volumes",
                                        daemon=True))
        threads[-1].start()
    return threads


def _quietly(job: Any, *arguments: Any) -> None:
    """Run a preparation job; an error is logged only (the call itself allocates again and meets it)."""
    try:
        job(*arguments)
    except Exception as error:  # an optimisation must not fail the run
        logger.debug("preparing the first call failed: %s: %s", type(error).__name__, error)
