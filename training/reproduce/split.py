"""The paper's 75 % / 25 % random split of a dataset's training pairs, reproducible from a recorded seed.

The paper (section 4) trains on 75 % of the KITTI training pairs drawn at random and tests on the rest,
without publishing which. Here the draw is ``numpy.random.default_rng(seed).permutation`` of the pairs
sorted by name, so the seed (recorded in ``OUT/split.json``) and the dataset's file list give the split
back on any machine. Each part is written as a folder of symbolic links in the dataset's own layout
(``OUT/split/train``, ``OUT/split/test``), so the trainer and the evaluation read it with the usual
reader (``kitti2015:OUT/split/train``) and never see the other part.

``--data synthetic`` has no pairs to split: training draws fresh generator seeds and the test part is
the fixed synthetic validation split (disjoint by construction: docs/data.md).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from service.datasets import open_dataset
from service.datasets.readers import READERS, PairList, detect_kind

TRAIN_FRACTION = 0.75
SPLIT_FILE = "split.json"
KITTI_KINDS = ("kitti2012", "kitti2015")


def split_names(names: Sequence[str], seed: int, fraction: float = TRAIN_FRACTION
                ) -> tuple[list[str], list[str]]:
    """(train, test) names: a seeded permutation of the sorted names, the first ``fraction`` to train.

    At least one pair lands on each side when there are two or more.
    """
    ordered = sorted(names)
    if len(set(ordered)) != len(ordered):
        raise ValueError("pair names must be unique")
    if len(ordered) < 2:
        raise ValueError(f"a train/test split needs at least 2 pairs, got {len(ordered)}")
    order = np.random.default_rng(seed).permutation(len(ordered))
    count = min(max(int(fraction * len(ordered) + 0.5), 1), len(ordered) - 1)   # rounded half up
    train = sorted(ordered[i] for i in order[:count])
    test = sorted(ordered[i] for i in order[count:])
    return train, test


def parse_data(data: str) -> tuple[str, Path | None]:
    """``kitti2015:PATH`` / ``kitti2012:PATH`` / a KITTI folder / ``synthetic`` -> (kind, path)."""
    if data == "synthetic":
        return "synthetic", None
    kind, _, argument = data.partition(":")
    if not argument:
        kind, argument = detect_kind(data), data
    if kind not in KITTI_KINDS:
        raise ValueError(f"--data {data!r}: the paper's tables are measured on KITTI; give kitti2015:PATH, "
                         "kitti2012:PATH or 'synthetic'")
    return kind, Path(argument).resolve()


def make_split(data: str, out: Path, *, seed: int, synthetic_test_pairs: int = 20) -> dict[str, Any]:
    """Draw the split, write ``out/split.json`` and the two link folders; returns the split record.

    Idempotent: the same data and seed write the same files (several Kubernetes pods may call it at
    once; every write is a rename of a complete file or link).
    """
    kind, root = parse_data(data)
    if kind == "synthetic":
        record = {"data": "synthetic", "kind": "synthetic", "seed": seed, "fraction": None,
                  "train_spec": "synthetic",
                  "test_spec": f"synthetic:{synthetic_test_pairs}",
                  "train": "generated on the fly (generator seeds below the validation split)",
                  "test": f"the synthetic validation split, first {synthetic_test_pairs} pairs"}
    else:
        pairs: PairList = READERS[kind](root)
        files = {files.name: files for files in pairs.pairs}
        train, test = split_names(list(files), seed)
        folders = {}
        for part, names in (("train", train), ("test", test)):
            folder = out / "split" / part
            _link_pairs(folder, [files[name] for name in names])
            folders[part] = f"{kind}:{folder}"
        record = {"data": f"{kind}:{root}", "kind": kind, "seed": seed, "fraction": TRAIN_FRACTION,
                  "pairs": len(files), "train_spec": folders["train"], "test_spec": folders["test"],
                  "train": train, "test": test,
                  "draw": "numpy.random.default_rng(seed).permutation(len(names)) over the pair names "
                          "sorted; the first floor(0.75 n + 0.5) are the training part"}
    _write_json(out / SPLIT_FILE, record)
    return record


def check_split(out: Path, data: str, seed: int) -> dict[str, Any] | None:
    """The recorded split of ``out`` if any; ValueError when it was drawn from other data or seed."""
    path = out / SPLIT_FILE
    if not path.is_file():
        return None
    record = json.loads(path.read_text())
    kind, root = parse_data(data)
    wanted = "synthetic" if kind == "synthetic" else f"{kind}:{root}"
    if record["data"] != wanted or record["seed"] != seed:
        raise ValueError(f"{out} holds a split of {record['data']} with seed {record['seed']}, not {wanted} "
                         f"with seed {seed}: use another --out")
    return record


def _link_pairs(folder: Path, pairs: Sequence[Any]) -> None:
    """``folder/<layout dir>/<file>`` -> the dataset's file, for each file of each pair."""
    for files in pairs:
        for source in (files.left, files.right, files.disparity, files.nonoccluded):
            if source is None:
                continue
            source = Path(source).resolve()
            target = folder / source.parent.name / source.name
            target.parent.mkdir(parents=True, exist_ok=True)
            if target.is_symlink() and Path(os.readlink(target)) == source:
                continue
            temporary = target.with_name(f".{target.name}.{os.getpid()}.tmp")
            try:
                temporary.unlink(missing_ok=True)
                temporary.symlink_to(source)
            except OSError:  # a file system without symbolic links: copy
                shutil.copyfile(source, temporary)
            os.replace(temporary, target)


def _write_json(path: Path, record: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    temporary.write_text(json.dumps(record, indent=1) + "\n")
    os.replace(temporary, path)


def open_part(record: dict[str, Any], part: str):
    """The ``train`` or ``test`` part as a dataset (``Sequence[StereoSample]``)."""
    return open_dataset(record[f"{part}_spec"])
