"""Which pairs an ``adsm predict`` run goes through: LEFT RIGHT, a --pairs list, a --data folder in one of
the left/right layouts, an ``adsm eval`` dataset SPEC, or a stereo video (LEFT,RIGHT or sbs:VIDEO); then
the --shard of them. Files are named here, not opened: their headers are checked in their turn
(checks.py), so that one bad pair of a batch fails alone."""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from service.datasets import StereoSample, extensions, open_dataset
from service.datasets.readers import READERS, PairList, detect_kind
from service.io.video import StereoVideo

LAYOUTS = (("left", "right"), ("image_2", "image_3"), ("image_02/data", "image_03/data"))
SIDE_BY_SIDE = "sbs:"  # --data sbs:VIDEO
# A SPEC's "WORD:" prefix: one that names no dataset kind is refused as such, not as a missing folder (two
# letters or more: "C:" starts a Windows path).
_KIND_PREFIX = re.compile(r"[A-Za-z][A-Za-z0-9_-]+:")


@dataclasses.dataclass(frozen=True)
class Pair:
    name: str
    left: Path
    right: Path | None  # None: the right image is missing (reported as a failed pair)
    max_disparity: int | None = None  # the search range a dataset recommends (StereoSample's)


@dataclasses.dataclass(frozen=True, eq=False)
class Frames:
    """A pair decoded from a video, or drawn from a dataset that is not files on disk (synthetic)."""

    name: str
    left: np.ndarray
    right: np.ndarray
    decode_seconds: float
    max_disparity: int | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class Samples:
    """A dataset whose pairs are made on access (``synthetic:N``): drawn one at a time as they are reached."""

    dataset: Sequence[StereoSample]


@dataclasses.dataclass(frozen=True)
class Skipped:
    name: str  # --skip-existing: its disparity file is there


@dataclasses.dataclass(frozen=True)
class Failed:
    name: str
    reason: str  # a video that cannot be decoded further


Item = Pair | Frames | Skipped | Failed


def pairs(args: argparse.Namespace) -> tuple[list[Pair] | StereoVideo | Samples, bool]:
    """The run's pairs (this shard's, except for a video or drawn samples, which are sharded as they are
    read) and whether it is a batch (--data or --pairs: outputs are templates)."""
    sources = [args.left is not None, args.data is not None, args.pairs is not None]
    if sum(sources) != 1:
        raise ValueError("give LEFT RIGHT, or --data SPEC, or --pairs LIST (exactly one of them)")
    if args.left is not None:
        if args.right is None:
            raise ValueError("RIGHT is missing: give LEFT RIGHT")
        return [Pair(args.left.stem, args.left, args.right)], False
    chosen = shard(args.shard)  # a bad I/N is refused before a video is opened
    if args.data is not None and _names_a_dataset(args.data):
        found = _dataset(args.data)
        if isinstance(found, Samples):
            return found, True  # sharded as it is drawn (run)
        listed = found
    else:
        videos = _videos(args.data) if args.data is not None else None
        if videos is not None:
            return StereoVideo.open(*videos, warn=_warn), True
        listed = _folder_pairs(Path(args.data)) if args.data is not None else _listed_pairs(args.pairs)
    if chosen is not None:
        index, count = chosen
        listed = listed[index::count]
    return listed, True


def shard(text: str | None) -> tuple[int, int] | None:
    """--shard I/N as ``(I, N)``, None without the flag."""
    if text is None:
        return None
    try:
        index, count = (int(part) for part in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard must be I/N with integers, got {text!r}") from None
    if not 0 <= index < count:
        raise ValueError(f"--shard I/N needs 0 <= I < N, got {text!r}")
    return index, count


def video_total(video: StereoVideo, chosen: tuple[int, int] | None) -> int | None:
    """How many pairs the shard ``chosen`` holds by the headers (None when a container does not tell)."""
    first, step = chosen or (0, 1)
    return None if video.frame_count is None else len(range(first, video.frame_count, step))


def frame_name(index: int) -> str:
    return f"frame_{index:06d}"


def _videos(spec: str) -> tuple[Path, Path | None] | None:
    """``(left, right)`` video files of a --data SPEC, ``(video, None)`` for ``sbs:VIDEO``, None for a
    folder. ``A,B`` splits at the comma that leaves two existing files (a name may hold a comma)."""
    if spec.startswith(SIDE_BY_SIDE):
        return Path(spec[len(SIDE_BY_SIDE):]), None
    if Path(spec).is_dir():
        return None
    if "," in spec:
        splits = [(Path(spec[:at]), Path(spec[at + 1:])) for at, char in enumerate(spec) if char == ","]
        return next((split for split in splits if split[0].is_file() and split[1].is_file()), splits[0])
    if Path(spec).is_file():
        raise ValueError(f"--data {spec!r} is one file: give two videos as LEFT,RIGHT, or "
                         f"{SIDE_BY_SIDE}VIDEO for a side-by-side video, or a folder")
    return None


def _warn(message: str) -> None:
    print(f"adsm: warning: {message}", file=sys.stderr)


def _dataset_kinds() -> list[str]:
    """The kinds an ``adsm eval`` SPEC may start with: the readers' and those of extras (installed or not)."""
    return [*READERS, *sorted(set(extensions.EXTRA_KINDS) | set(extensions.registered()))]


def _names_a_dataset(spec: str) -> bool:
    """True when ``spec`` starts with a dataset kind (``kitti2015:PATH``, ``synthetic``); an existing file
    or folder named like a bare kind ("cones") is that file or folder, as open_dataset reads it."""
    kind, colon, _ = spec.partition(":")
    return kind in _dataset_kinds() and (bool(colon) or not Path(spec).exists())


def _dataset(spec: str) -> list[Pair] | Samples:
    """The pairs of an ``adsm eval`` dataset SPEC, in eval's order and with eval's names. Pairs on disk are
    read as the folder form reads them (headers checked first; the ground truth is not read)."""
    dataset = open_dataset(spec)
    if not isinstance(dataset, PairList):
        return Samples(dataset)
    found = [Pair(files.name, files.left, files.right, files.max_disparity) for files in dataset.pairs]
    twice = sorted(name for name, count in Counter(pair.name for pair in found).items() if count > 1)
    if twice:  # Middlebury's trainingQ/ and trainingH/ hold scenes of the same names
        raise ValueError(f"--data {spec!r}: several pairs are named {', '.join(twice[:3])}; outputs would "
                         "collide: point --data at one folder of them")
    return found


def _spec_forms() -> str:
    readers = ", ".join(f"{kind}:PATH" for kind in READERS)
    return (f"{readers}, {', '.join(extensions.usages())}, LEFT_VIDEO,RIGHT_VIDEO, {SIDE_BY_SIDE}VIDEO "
            "or a folder with left/ and right/")


def _folder_pairs(root: Path) -> list[Pair]:
    if not root.is_dir():
        prefix = _KIND_PREFIX.match(str(root))
        if prefix:
            raise ValueError(f"--data {str(root)!r}: unknown dataset kind {prefix.group()[:-1]!r}; "
                             f"expected {_spec_forms()}")
        raise ValueError(f"--data {str(root)!r} is not a folder (nor LEFT,RIGHT or "
                         f"{SIDE_BY_SIDE}VIDEO videos)")
    for left_name, right_name in LAYOUTS:
        left_dir, right_dir = root / left_name, root / right_name
        if left_dir.is_dir() and right_dir.is_dir():
            lefts = {path.name: path for path in left_dir.iterdir()
                     if path.is_file() and not path.name.startswith(".")}
            rights = {path.name: path for path in right_dir.iterdir() if path.is_file()}
            if not lefts:
                raise ValueError(f"--data: {left_dir} holds no files")
            return [Pair(Path(name).stem, lefts[name], rights.get(name)) for name in sorted(lefts)]
    try:
        kind = detect_kind(root)
    except ValueError:
        layouts = ", ".join(f"{left}/ + {right}/" for left, right in LAYOUTS)
        raise ValueError(f"--data {str(root)!r}: no pair of folders ({layouts}) and no dataset layout "
                         "(KITTI 2012/2015, Middlebury, Cones)") from None
    found = _dataset(f"{kind}:{root}")
    assert isinstance(found, list)  # the readers' datasets are files on disk
    return found


def _listed_pairs(listing: Path) -> list[Pair]:
    if not listing.is_file():
        raise ValueError(f"--pairs {str(listing)!r} does not exist or is not a file")
    try:
        text = listing.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"--pairs {str(listing)!r} is not a UTF-8 text file (one 'LEFT RIGHT' pair per "
                         "line)") from None
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) != 2:
            raise ValueError(
                f"--pairs {listing.name} line {number}: expected 'LEFT RIGHT', got {line.strip()!r}"
            )
        left = Path(fields[0]) if Path(fields[0]).is_absolute() else listing.parent / fields[0]
        right = Path(fields[1]) if Path(fields[1]).is_absolute() else listing.parent / fields[1]
        found.append(Pair(left.stem, left, right))
    names = [pair.name for pair in found]
    if len(set(names)) != len(names):
        raise ValueError(f"--pairs {listing.name}: two left images share a file stem; outputs would collide")
    return found
