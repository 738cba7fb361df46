"""Service settings, read from ``ADSM_*`` environment variables (documented in docs/service.md)."""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from service.cuda import DEVICE_ENVIRONMENT, check_device
from service.features.towers import MAX_THREADS
from service.memory import DEFAULT_MAX_REQUEST_BYTES


@dataclasses.dataclass(frozen=True, kw_only=True)
class Settings:
    """Everything an operator can tune; ``Settings.from_env()`` is what ``adsm serve`` and the image use."""

    model_dir: Path | None = None  # None -> the default model shipped inside the package
    threads: int | None = None  # Numba / ONNX Runtime threads per process; None -> all cores
    device: str = "cpu"  # where the stages after the towers run: "cpu" or "cuda" (service/cuda)
    queue_size: int = 4  # requests that may wait while one inference runs; more -> 503 at once
    max_body_bytes: int = 32 * 1024 * 1024  # whole request body, multipart framing included
    max_pixels: int = 2_100_000  # per image, checked on the header before decoding (1920x1080 fits)
    max_disparity: int = 256  # upper bound for the max_disparity query
    # Height x width x disparities of one request: bounds memory (4 bytes per cell, two int16 volumes that
    # the Matcher keeps between requests at the largest size served).
    max_cost_cells: int = 100_000_000
    # Peak bytes of one request by the memory model (service/memory.py), checked on the image headers.
    max_request_bytes: int = DEFAULT_MAX_REQUEST_BYTES
    # Seconds a request may take to deliver its whole body (408 after): an upload holds a queue place,
    # so without a deadline a few trickling clients could keep every place and everyone else at 503.
    body_timeout_s: float = 30.0
    # Seconds a client has to take a whole answer, from its first byte (api/middleware/delivery.py): a client
    # that does not read would otherwise pin its answer in memory for as long as it keeps the socket open.
    write_timeout_s: float = 60.0
    # Answer bytes not yet taken by slow clients, over all connections; above it new stereo requests get 503.
    max_unsent_bytes: int = 128 * 1024 * 1024
    warmup: bool = True  # compile and run every kernel before /readyz turns ready

    def __post_init__(self) -> None:
        for name in ("queue_size",):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("max_body_bytes", "max_pixels", "max_disparity", "max_cost_cells", "max_request_bytes",
                     "max_unsent_bytes"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.threads is not None and not 1 <= self.threads <= MAX_THREADS:
            raise ValueError(f"threads must be in 1..{MAX_THREADS}, got {self.threads}")
        check_device(self.device)
        for name in ("body_timeout_s", "write_timeout_s"):
            timeout = getattr(self, name)
            # bool is an int to Python, and nan/inf would silently mean "no deadline": refuse them all.
            if isinstance(timeout, bool) or not isinstance(timeout, int | float) or not (
                math.isfinite(timeout) and timeout > 0
            ):
                raise ValueError(f"{name} must be a positive, finite number of seconds, got {timeout!r}")

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Settings:
        """Read ``ADSM_MODEL_DIR``, ``ADSM_THREADS``, ``ADSM_DEVICE``, ``ADSM_QUEUE_SIZE``,
        ``ADSM_MAX_BODY_BYTES``, ``ADSM_MAX_PIXELS``, ``ADSM_MAX_DISPARITY``, ``ADSM_MAX_COST_CELLS``,
        ``ADSM_MAX_REQUEST_BYTES``,
        ``ADSM_BODY_TIMEOUT_S``, ``ADSM_WRITE_TIMEOUT_S``, ``ADSM_MAX_UNSENT_BYTES`` and ``ADSM_WARMUP``;
        unset or empty keeps the default."""
        env = os.environ if environ is None else environ
        values: dict[str, Any] = {}
        if model_dir := env.get("ADSM_MODEL_DIR"):
            values["model_dir"] = Path(model_dir)
        if device := env.get(DEVICE_ENVIRONMENT, "").strip():
            values["device"] = device
        for field, parse in (
            ("threads", _parse_int),
            ("queue_size", _parse_int),
            ("max_body_bytes", _parse_int),
            ("max_pixels", _parse_int),
            ("max_disparity", _parse_int),
            ("max_cost_cells", _parse_int),
            ("max_request_bytes", _parse_int),
            ("body_timeout_s", _parse_float),
            ("write_timeout_s", _parse_float),
            ("max_unsent_bytes", _parse_int),
            ("warmup", _parse_bool),
        ):
            name = f"ADSM_{field.upper()}"
            if raw := env.get(name, "").strip():
                values[field] = parse(name, raw)
        return cls(**values)


def _parse_int(name: str, raw: str) -> int:
    try:
        return int(raw.replace("_", ""))
    except ValueError:
        raise ValueError(f"{name} must be an integer, got {raw!r}") from None


def _parse_float(name: str, raw: str) -> float:
    try:
        return float(raw)  # accepts "nan" and "inf": __post_init__ refuses them with the range check
    except ValueError:
        raise ValueError(f"{name} must be a number, got {raw!r}") from None


def _parse_bool(name: str, raw: str) -> bool:
    lowered = raw.lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise ValueError(f"{name} must be true or false, got {raw!r}")
