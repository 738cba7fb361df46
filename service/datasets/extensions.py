"""Dataset kinds that installed extras add to the SPEC parser, found through Python entry points.

A distribution registers ``KIND = "module:function"`` in the ``adsm.datasets`` entry-point group; the
SPEC ``KIND[:ARGUMENT]`` then opens ``function(ARGUMENT)`` ('' without one), which returns a
``Sequence[StereoSample]`` with a ``name`` and raises ValueError for a bad ARGUMENT and ImportError when
a dependency is missing. This is how ``synthetic[:N]`` reaches the generator of the train extra
(``[project.entry-points."adsm.datasets"]`` in pyproject.toml) while the runtime imports nothing of
``training``.
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Sequence
from typing import NamedTuple

from .sample import StereoSample

ENTRY_POINT_GROUP = "adsm.datasets"


class ExtraKind(NamedTuple):
    extra: str   # the optional dependency set of pyproject.toml that registers the kind
    usage: str   # how the kind is written in a SPEC


# This project's kinds that an extra provides: named in the SPEC help and in the error when it is missing.
EXTRA_KINDS = {"synthetic": ExtraKind(extra="train", usage="synthetic[:N]"),
               "synthetic-clean": ExtraKind(extra="train", usage="synthetic-clean[:N]"),
               "synthetic-curved": ExtraKind(extra="train", usage="synthetic-curved[:N]"),
               "synthetic-fine": ExtraKind(extra="train", usage="synthetic-fine[:N]"),
               "synthetic-downsampled": ExtraKind(extra="train", usage="synthetic-downsampled[:N]"),
               "motorcycle": ExtraKind(extra="train", usage="motorcycle")}


def registered() -> dict[str, importlib.metadata.EntryPoint]:
    """The installed entry points of the group, by kind."""
    return {entry.name: entry for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def usages() -> list[str]:
    """How each extension kind, installed or not, is written in a SPEC."""
    others = sorted(set(registered()) - set(EXTRA_KINDS))
    return [kind.usage for kind in EXTRA_KINDS.values()] + [f"{kind}[:ARGUMENT]" for kind in others]


def open_extension(spec: str, kind: str, argument: str) -> Sequence[StereoSample] | None:
    """The dataset of an extension kind, or None when ``kind`` is none; one-line ValueError otherwise."""
    entry = registered().get(kind)
    if entry is None and kind not in EXTRA_KINDS:
        return None
    try:
        if entry is None:
            raise ModuleNotFoundError(f"no {ENTRY_POINT_GROUP} entry point {kind!r} is installed")
        return entry.load()(argument)
    except ImportError as error:
        extra = EXTRA_KINDS[kind].extra if kind in EXTRA_KINDS else None
        needs = f"the {extra} extra (pip install -e '.[{extra}]')" if extra else "a missing module"
        raise ValueError(f"dataset {spec!r} needs {needs}: {error}") from None
    except ValueError as error:
        raise ValueError(f"dataset {spec!r}: {error}") from None
