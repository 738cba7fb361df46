"""Stand-ins for the Matcher, held to the same protocol as the real one.

The service holds a :class:`service.protocols.StereoMatcher` and asks it for the search range and memory
plan of a request before queueing it (service/api/inference.py). A stand-in derives from
:class:`MatcherRules`: it then answers those two with the Matcher's own rule (so the service checks
requests as in production), and it must define ``warmup`` and ``__call__`` itself with the protocol's
parameters, or its class statement fails (:func:`protocol_problems`).
"""

from __future__ import annotations

import inspect
from typing import Any

from service.protocols import StereoMatcher


def protocol_problems(cls: type, protocol: type) -> list[str]:
    """What ``cls`` lacks to satisfy ``protocol`` formally: each method defined by the class itself (not
    the protocol's stub), taking the protocol's parameters in its order and under its names, and
    asking for nothing more without a default. Data members are the instances' business."""
    problems = []
    for name, wanted in vars(protocol).items():
        if not callable(wanted) or (name.startswith("_") and name != "__call__"):
            continue
        owner = next((base for base in cls.__mro__ if name in vars(base)), None)
        if owner is None or owner is protocol or getattr(owner, "_is_protocol", False):
            problems.append(f"{cls.__name__} does not define {name}")
            continue
        expected = list(inspect.signature(wanted).parameters.values())[1:]
        given = list(inspect.signature(getattr(cls, name)).parameters.values())[1:]
        positional = [p for p in given if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
        for index, parameter in enumerate(expected):
            if index >= len(positional) or positional[index].name != parameter.name:
                problems.append(f"{cls.__name__}.{name} does not take {parameter.name!r} as parameter "
                                f"{index + 1}")
        for extra in positional[len(expected):]:
            if extra.default is extra.empty:
                problems.append(f"{cls.__name__}.{name} requires {extra.name!r}, which the protocol "
                                "never passes")
    return problems


class MatcherRules(StereoMatcher):
    """``Matcher.search_range`` and ``Matcher.plan`` for an object with a ``manifest``."""

    manifest: dict[str, Any]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if problems := protocol_problems(cls, StereoMatcher):
            raise TypeError("a Matcher stand-in must satisfy service.protocols.StereoMatcher: "
                            + "; ".join(problems))

    def search_range(self, width: int, options):
        from service.matcher import Matcher

        return Matcher.search_range(self, width, options)  # type: ignore[arg-type]

    def plan(self, height: int, width: int, options=None):
        from service.matcher import Matcher

        return Matcher.plan(self, height, width, options)  # type: ignore[arg-type]
