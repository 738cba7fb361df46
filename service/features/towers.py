"""FeatureTowers: the left and right ONNX towers of a model folder, run in ONNX Runtime.

The towers map a uint8 RGB image to L2-normalised features (C, H, W); padding is inside the graphs, so
H and W are kept. Every file is checked against the manifest's sha256 before a session is created:
a folder that differs from what was exported is refused rather than served.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from service.features.manifest import TOWER_FILES, ModelError, load_manifest, verify_files
from service.features.tiles import TOWER_WORK_BYTES

logger = logging.getLogger("adsm")

# Accelerated providers in order of preference; the CPU provider is always appended as the fallback.
_PREFERRED_PROVIDERS = ("TensorrtExecutionProvider", "CUDAExecutionProvider")


def _default_threads() -> int:
    # The CPUs this process may run on (cgroup/affinity aware on Linux), not the machine's core count.
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def _pick_providers(requested: Sequence[str] | None) -> list[str]:
    available = ort.get_available_providers()
    if requested is not None:
        unknown = [p for p in requested if p not in available]
        if unknown:
            raise ModelError(f"ONNX Runtime providers {unknown} are not available here (have {available})")
        return list(requested)
    picked = [p for p in _PREFERRED_PROVIDERS if p in available]
    return [*picked, "CPUExecutionProvider"]


# ONNX Runtime starts every intra-op thread at session creation: 100000 asked for ~24,500 threads and hung
# start-up. No CPU this runs on has more cores than this.
MAX_THREADS = 256

_shared_arena = False
# Hard cap of the shared arena. Tiles keep one run under TOWER_WORK_BYTES (by a measured bound per model);
# the factor 2 leaves room for the arena's fragmentation across tile shapes. Past the cap a run fails
# with an error instead of growing the process until it is killed.
ARENA_MAX_BYTES = 2 * TOWER_WORK_BYTES
_SAME_AS_REQUESTED = 1  # arena_extend_strategy: grow by what a run asks for, not to the next power of two


def _register_shared_arena() -> None:
    """Register one CPU arena in ONNX Runtime's environment (once per process) for every session."""
    global _shared_arena
    if _shared_arena:
        return
    memory = ort.OrtMemoryInfo("Cpu", ort.OrtAllocatorType.ORT_ARENA_ALLOCATOR, 0, ort.OrtMemType.DEFAULT)
    # -1: ORT's default initial chunk and dead-bytes-per-chunk sizes.
    ort.create_and_register_allocator(memory, ort.OrtArenaCfg(ARENA_MAX_BYTES, -1, -1, -1))
    _shared_arena = True


class FeatureTowers:
    """Left and right feature towers of one model folder.

    ``threads`` sets ONNX Runtime's intra-op threads (default: the CPUs available to this process);
    inter-op parallelism is 1 because each tower is one chain of convolutions. ``providers`` overrides
    the automatic choice (TensorRT, then CUDA, then CPU).
    """

    def __init__(
        self, folder: str | Path, *, threads: int | None = None, providers: Sequence[str] | None = None
    ) -> None:
        if threads is not None and not 1 <= threads <= MAX_THREADS:
            raise ValueError(f"threads must be in 1..{MAX_THREADS}, got {threads}")
        self.folder = Path(folder)
        self.manifest: dict[str, Any] = load_manifest(self.folder)
        verify_files(self.folder, self.manifest)
        spec = self.manifest["input"]
        low, high = (float(v) for v in spec["range"])
        mean = np.asarray(spec["mean"], np.float32)
        std = np.asarray(spec["std"], np.float32)
        # uint8 -> range -> (x - mean) / std folded into one affine map per channel: x * gain + offset.
        self._gain = ((high - low) / 255.0 / std).astype(np.float32)
        self._offset = ((low - mean) / std).astype(np.float32)
        self.channels = int(self.manifest["channels"])

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads or _default_threads()
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        # Memory: ORT's pattern planner and a CPU arena per session keep every intermediate of the largest
        # image seen twice over (~2.4 GB for adsm-fast-int8 at 375x1242). Shrinking the arena after each
        # run kept the peak low but page-faulted ~1 GB back in on every call (0.45 s of system time on
        # 2 cores). Instead both towers share one process-wide arena (they run one after the other) and
        # the pattern planner is off, so the arena holds one tower run's buffers and is reused without
        # faults: adsm-fast-int8 towers 1.48 -> 0.84 CPU s, peak 769 -> 676 MiB (python -m bench suite).
        options.enable_mem_pattern = False
        options.add_session_config_entry("session.use_env_allocators", "1")
        _register_shared_arena()
        self._run_options = ort.RunOptions()
        chosen = _pick_providers(providers)
        self._sessions = {}
        for name in TOWER_FILES:
            path = self.folder / name
            try:
                session = ort.InferenceSession(str(path), sess_options=options, providers=chosen)
            except Exception as error:  # onnxruntime raises its own exception types
                raise ModelError(f"ONNX Runtime cannot load {path}: {error}") from error
            self._sessions[name] = session
        self.providers: list[str] = self._sessions["left.onnx"].get_providers()
        logger.info(
            "feature towers %s (%s): providers %s, %d intra-op threads",
            self.manifest["name"], self.folder, self.providers, options.intra_op_num_threads,
        )

    def input_batch(self, image: np.ndarray, side: str = "image") -> np.ndarray:
        """uint8 (H, W, 3) -> the graph's input [1, 3, H, W] float32 (the manifest's input normalisation)."""
        if not (isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3
                and image.shape[2] == 3):
            raise ValueError(
                f"{side} image must be a uint8 array of shape (H, W, 3), got "
                f"{getattr(image, 'dtype', type(image).__name__)} {getattr(image, 'shape', '')}"
            )
        # One pass: the channel-first view is cast and scaled into a fresh contiguous NCHW buffer.
        planar = image.transpose(2, 0, 1)
        batch = np.empty((1, 3, *image.shape[:2]), np.float32)
        np.multiply(planar, self._gain[:, None, None], out=batch[0], dtype=np.float32)
        batch[0] += self._offset[:, None, None]
        return batch

    def _run(self, name: str, batch: np.ndarray) -> np.ndarray:
        session = self._sessions[name]
        (features,) = session.run(None, {session.get_inputs()[0].name: batch}, self._run_options)
        expected = (1, self.channels, *batch.shape[2:])
        if features.shape != expected or features.dtype != np.float32:
            raise ModelError(
                f"{self.folder.name}/{name} returned {features.dtype} {features.shape}, expected float32 "
                f"{expected} (manifest channels {self.channels})"
            )
        return features[0]

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Features of both views: two float32 arrays (C, H, W), unit L2 norm over C."""
        if getattr(left, "shape", None) != getattr(right, "shape", None):
            raise ValueError(
                f"left and right images differ in size: {getattr(left, 'shape', None)} vs "
                f"{getattr(right, 'shape', None)}"
            )
        left_batch = self.input_batch(left, "left")
        right_batch = self.input_batch(right, "right")
        return self._run("left.onnx", left_batch), self._run("right.onnx", right_batch)

    def warmup(self) -> None:
        """Run both towers once (session initialisation) and check them against the manifest.

        The manifest is not hashed (it holds the hashes), so a hand-edited ``channels`` or
        ``receptive_field`` would pass :func:`verify_files`; both are measured here instead. Channels: the
        graph's declared output and the features of a run. Receptive field: one pixel of a random image
        is changed, and the features that change must reach exactly ``receptive_field // 2`` pixels from
        it (farther: the tiles would cut context; nearer: the manifest overstates it). Raises
        :class:`ModelError` with one line naming the file, the manifest value and the measured one.
        """
        halo = int(self.manifest["receptive_field"]) // 2
        size = 2 * (halo + 2) + 1  # room to see a reach of up to halo + 2
        rng = np.random.default_rng(0)
        image = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
        changed = image.copy()
        centre = size // 2
        changed[centre, centre] = 255 - changed[centre, centre]
        for name in TOWER_FILES:
            declared = self._sessions[name].get_outputs()[0].shape
            if len(declared) != 4 or (isinstance(declared[1], int) and declared[1] != self.channels):
                raise ModelError(
                    f"{self.folder.name}/{name} outputs shape {declared}, but the manifest says "
                    f"channels {self.channels}"
                )
            base = self._run(name, self.input_batch(image, "probe"))
            moved = np.abs(self._run(name, self.input_batch(changed, "probe")) - base).max(axis=0) > 0
            rows, columns = np.nonzero(moved)
            reach = int(max(np.abs(rows - centre).max(), np.abs(columns - centre).max())) if rows.size else 0
            if reach != halo:
                raise ModelError(
                    f"{self.folder.name}/{name} has a receptive field of {2 * reach + 1} pixels (a change "
                    f"reaches {reach} px), but the manifest says receptive_field {halo * 2 + 1}"
                )
