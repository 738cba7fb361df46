"""StereoMatcher: what the HTTP service and the evaluation need of a matcher.

:class:`service.matcher.Matcher` satisfies it; so do the test suite's stand-ins (tests/stand_in.py), which
answer at once or on a signal while the service checks requests exactly as in production. The service
(service/api/inference.py) holds a ``StereoMatcher``, never the concrete class, so an embedder may hand
``create_app(matcher=...)`` anything with these members. What the Matcher in turn needs of its towers is
:class:`service.features.Towers` (service/features/protocol.py, beside the towers, since the Matcher
imports it and this module imports the Matcher's types).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from service.limits import SearchRange
from service.matcher import MatchOptions, StereoResult
from service.memory import MemoryPlan


@runtime_checkable
class StereoMatcher(Protocol):
    """A model's matcher: its manifest, a warm-up, the checks made before a request, and the call."""

    manifest: dict[str, Any]

    def warmup(self) -> None:
        """Compile or load everything the first request would, so that it pays nothing extra."""
        ...

    def search_range(self, width: int, options: MatchOptions) -> SearchRange:
        """The disparities a call with ``options`` on an image ``width`` pixels wide searches
        (service/limits.py); :class:`~service.limits.DisparityRangeError` when none fits."""
        ...

    def plan(self, height: int, width: int, options: MatchOptions) -> MemoryPlan:
        """The call's memory plan (service/memory.py), from its size alone: nothing is allocated."""
        ...

    def __call__(self, left: np.ndarray, right: np.ndarray, options: MatchOptions) -> StereoResult:
        """Disparity of the left view; ValueError for images or options this pair cannot take."""
        ...
