"""The rules a stereo request must pass before anything is allocated, shared by the CLI, the Python API and
the HTTP service: the search range, and the size limits (pixels, range size, cost-volume cells, bytes).

**Search range.** A call searches the disparities ``[min_disparity, min_disparity + D)`` where ``D`` is
``max_disparity`` (the range *size*, as OpenCV's numDisparities). On an image ``W`` pixels wide only
``-(W - 1) .. W - 1`` can be seen by both cameras, so ``|min_disparity| < W`` and an explicit range must
end at ``W - 1`` at the latest (``min_disparity + D <= W``); a range beyond it asks for the impossible and
is refused. Only the model's default size is clipped to fit, since the caller did not choose it.

**Size limits.** :class:`RequestLimits` holds the defaults the server and the CLI share (the server reads
them from ``ADSM_*`` variables, the CLI from the same variables or its flags). :func:`check_request` applies
them to an image size and a search range, before any pixel is decoded (the service, whose matcher makes
its own plan, applies :func:`check_range_size` and :func:`check_plan`, the same rules); ``None`` turns a
limit off.
Errors: :class:`DisparityRangeError` (a bad range: HTTP 400) and :class:`LimitError` (over a limit: 413).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import Any

from service.memory import (
    DEFAULT_MAX_REQUEST_BYTES,
    TOWER_WORK_FACTOR,
    MemoryPlan,
    plan_request,
    tower_work_limit,
)

# Per image, checked on the header before decoding (1920x1080 fits).
DEFAULT_MAX_PIXELS = 2_100_000
# Upper bound of a request's range size D.
DEFAULT_MAX_DISPARITY = 256
# Height x width x D of one request: bounds memory (4 bytes per cell, two int16 volumes that a Matcher keeps
# between calls at the largest size served).
DEFAULT_MAX_COST_CELLS = 100_000_000

# RequestLimits field -> the ADSM_* variable that sets it (for the server and the CLI alike).
ENVIRONMENT = {
    "max_pixels": "ADSM_MAX_PIXELS",
    "max_disparity": "ADSM_MAX_DISPARITY",
    "max_cost_cells": "ADSM_MAX_COST_CELLS",
    "max_request_bytes": "ADSM_MAX_REQUEST_BYTES",
}


class DisparityRangeError(ValueError):
    """The search range cannot be searched on this image (or is not a range at all)."""


class LimitError(ValueError):
    """The request is over a size limit; nothing was allocated."""


@dataclasses.dataclass(frozen=True)
class SearchRange:
    """Disparities ``minimum .. minimum + count - 1``."""

    minimum: int
    count: int

    @property
    def maximum(self) -> int:
        return self.minimum + self.count - 1


def _integer(name: str, value: Any) -> int:
    if isinstance(value, bool) or not (isinstance(value, int) or hasattr(value, "__index__")):
        raise DisparityRangeError(f"{name} must be an integer, got {value!r}")
    return int(value)


def recommended_size(recommended: int, width: int, *, min_disparity: int = 0) -> int:
    """A dataset's recommended range size (KITTI 192, Cones 64, ...) fitted to an image ``width`` wide:
    a default, not the caller's choice, so it shrinks instead of being refused. ``adsm eval`` and
    ``adsm predict --data`` both search it when no range is given."""
    return min(recommended, width - min_disparity)


def search_range(width: int, *, min_disparity: int = 0, max_disparity: int | None = None,
                 default_max: int) -> SearchRange:
    """The range a call on an image ``width`` pixels wide searches; :class:`DisparityRangeError` if none.

    >>> search_range(100, max_disparity=None, default_max=128)
    SearchRange(minimum=0, count=100)
    >>> search_range(100, min_disparity=-20, max_disparity=64, default_max=128)
    SearchRange(minimum=-20, count=64)
    """
    minimum = _integer("min_disparity", min_disparity)
    if not -width < minimum < width:
        raise DisparityRangeError(
            f"min_disparity {minimum} leaves no disparity an image {width} pixels wide can hold: "
            f"it must lie in {-(width - 1)}..{width - 1}"
        )
    if max_disparity is None:
        return SearchRange(minimum, min(int(default_max), width - minimum))
    count = _integer("max_disparity", max_disparity)
    if count < 1:
        raise DisparityRangeError(f"max_disparity must be >= 1, got {count}")
    if minimum + count > width:
        start = "" if minimum == 0 else f" from min_disparity {minimum}"
        raise DisparityRangeError(
            f"max_disparity {count} exceeds the image width {width}: at most {width - minimum} "
            f"disparities{start} ({minimum}..{width - 1}) fit"
        )
    return SearchRange(minimum, count)


@dataclasses.dataclass(frozen=True, kw_only=True)
class RequestLimits:
    """Size limits of one request; ``None`` switches a limit off (a library caller owns its memory)."""

    max_pixels: int | None = DEFAULT_MAX_PIXELS
    max_disparity: int | None = DEFAULT_MAX_DISPARITY
    max_cost_cells: int | None = DEFAULT_MAX_COST_CELLS
    max_request_bytes: int | None = DEFAULT_MAX_REQUEST_BYTES
    # How a user changes each limit, named in the refusal (the server names its ADSM_* variables).
    how: Mapping[str, str] = dataclasses.field(default_factory=lambda: dict(ENVIRONMENT))

    def __post_init__(self) -> None:
        for name in ENVIRONMENT:
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None, **overrides: Any) -> RequestLimits:
        """The defaults, replaced by the ``ADSM_*`` variables that are set, then by ``overrides`` that are
        not None (a CLI's flags)."""
        env = os.environ if environ is None else environ
        values: dict[str, Any] = {}
        for field, variable in ENVIRONMENT.items():
            if raw := env.get(variable, "").strip():
                try:
                    values[field] = int(raw.replace("_", ""))
                except ValueError:
                    raise ValueError(f"{variable} must be an integer, got {raw!r}") from None
        values.update((name, value) for name, value in overrides.items() if value is not None)
        return cls(**values)

    def _named(self, field: str) -> str:
        return f" ({self.how[field]})" if field in self.how else ""


def check_request(height: int, width: int, manifest: dict[str, Any], limits: RequestLimits, *,
                  min_disparity: int = 0, max_disparity: int | None = None, tower_scale: int = 1,
                  who: str = "this server") -> tuple[SearchRange, MemoryPlan]:
    """Every rule of a request on an ``height x width`` pair, from the image headers alone.

    Returns the search range and the memory plan; raises :class:`DisparityRangeError` or
    :class:`LimitError` with one sentence saying what to change. ``who`` names the limits' owner
    ("this server", "adsm predict").
    """
    if limits.max_pixels is not None and height * width > limits.max_pixels:
        raise LimitError(
            f"{width} x {height} = {height * width} pixels exceeds {who}'s limit of {limits.max_pixels}"
            f"{limits._named('max_pixels')}; send smaller images"
        )
    check_range_size(max_disparity, limits, who=who)
    span = search_range(width, min_disparity=min_disparity, max_disparity=max_disparity,
                        default_max=int(manifest["disparity"]["default_max"]))
    plan = plan_request(height, width, span.count, manifest, scale=tower_scale)
    check_plan(plan, manifest, limits, who=who)
    return span, plan


def check_range_size(max_disparity: int | None, limits: RequestLimits, *, who: str = "this server") -> None:
    """:class:`DisparityRangeError` when a requested range size is over the limit's ceiling."""
    ceiling = limits.max_disparity
    if max_disparity is not None and ceiling is not None and max_disparity > ceiling:
        raise DisparityRangeError(
            f"max_disparity {max_disparity} exceeds {who}'s limit of {ceiling}"
            f"{limits._named('max_disparity')}"
        )


def check_plan(plan: MemoryPlan, manifest: dict[str, Any], limits: RequestLimits, *,
               who: str = "this server") -> None:
    """The limits on a request's memory plan (service/memory.py, from any matcher's ``plan``): cost-volume
    cells, peak bytes and the towers' work; :class:`LimitError` with what to change."""
    height, width, disparities = plan.height, plan.width, plan.disparities
    cells = height * width * disparities
    if limits.max_cost_cells is not None and cells > limits.max_cost_cells:
        raise LimitError(
            f"{width} x {height} pixels x {disparities} disparities = {cells} cost-volume cells exceeds "
            f"{who}'s limit of {limits.max_cost_cells}{limits._named('max_cost_cells')}; lower "
            "max_disparity or send smaller images"
        )
    if limits.max_request_bytes is not None and plan.peak_bytes > limits.max_request_bytes:
        raise LimitError(
            f"{width} x {height} pixels x {disparities} disparities would need {plan.describe()}, over "
            f"{who}'s limit of {limits.max_request_bytes / 2**20:.0f} MiB per request"
            f"{limits._named('max_request_bytes')}; send smaller images or lower max_disparity"
        )
    if limits.max_pixels is not None:
        work_limit = tower_work_limit(manifest, max_pixels=limits.max_pixels)
        if plan.work_pixels > work_limit:
            raise LimitError(
                f"a {width} x {height} image makes the feature towers compute {plan.work_pixels} padded "
                f"pixels (each side is padded by half the receptive field), over {who}'s limit of "
                f"{work_limit} ({TOWER_WORK_FACTOR:g} x the work of a square image of the pixel limit"
                f"{limits._named('max_pixels')}); " + _tower_work_advice(plan.scale)
            )


def _tower_work_advice(tower_scale: int) -> str:
    """What to change when a request's towers would compute too many padded pixels."""
    if tower_scale > 1:
        return (f"tower_scale {tower_scale} makes them compute {tower_scale ** 2} times the pixels: lower "
                "tower_scale or send smaller images")
    return ("images only a few pixels tall or wide cost far more than their size: send a less elongated "
            "image")
