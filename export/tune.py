"""Choose a model folder's SGM penalties by the project's one rule, on its own ONNX towers.

    python -m export.tune --model service/models/NAME              # print the grid and the choice
    python -m export.tune --model DIR --write                      # ... and write it into manifest.json
    python -m export.tune --model DIR --shiftable-windows --write  # tuned with the step, which it records
    python -m export.tune --model DIR --no-border-band --write     # tuned without the border band, likewise

The rule is ``service.evaluation.tuning.tune_penalties``: every (P1, P2) of the grid through the runtime's
Matcher on the synthetic validation split (``--pairs`` of it, 20 by default: ``synthetic:20``), the lowest
all-pixel bad-2 wins, EPE breaks ties. ``training.validate --tune`` applies it to a checkpoint; this
command applies it to an exported folder (an int8 twin, a hybrid, an NCC window), so a folder is tuned on
exactly the towers it ships. The towers run once per pair (service.features.CachedTowers, which holds
``8 C H W`` bytes per pair: 1.3 GB for a 64-channel model on 20 pairs). ``--write`` sets ``sgm.p1``,
``sgm.p2``, ``sgm.tuned_on`` and then measures the folder again on the data sets its metrics name
(``export.measure``): figures of the old penalties do not stay.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from export.measure import datasets_of, measure_folder
from service.evaluation.tuning import P1_GRID, P2_GRID, TUNING_DATA, tune_penalties
from service.features.manifest import ModelError, load_manifest, write_manifest


def tune_folder(folder: str | Path, *, pairs: int = 20, p1_grid: Sequence[float] = P1_GRID,
                p2_grid: Sequence[float] = P2_GRID, log: Any = None,
                shiftable_windows: bool | None = None,
                border_band: bool | None = None) -> tuple[dict[str, float], str]:
    """The rule's (P1, P2) for ``folder`` and the ``sgm.tuned_on`` text that says how it was chosen.

    ``shiftable_windows`` and ``border_band`` tune with that step on or off (None: as the folder's
    manifest says).
    """
    from service.datasets import open_dataset
    from service.features import CachedTowers, FeatureTowers
    from service.matcher import Matcher, MatchOptions

    spec = f"{TUNING_DATA.partition(':')[0]}:{pairs}"
    # The towers (which verify both files' sha256) run once per pair, not once per pair and grid point.
    matcher = Matcher(CachedTowers(FeatureTowers(folder), pairs=pairs))
    options = MatchOptions(shiftable_windows=shiftable_windows, border=border_band)
    choice, _ = tune_penalties(matcher, open_dataset(spec), p1_grid=p1_grid, p2_grid=p2_grid, log=log,
                               options=options)
    grid = f"grid P1 {list(p1_grid)} x P2 {list(p2_grid)}"
    grid += ", shiftable windows on" if matcher.uses_shiftable_windows(options) else ""
    grid += "" if matcher.uses_border_band(options) else ", border band off"
    return choice, f"{grid}, lowest bad-2 on the synthetic validation split ({pairs} pairs; export.tune)"


def write_penalties(folder: str | Path, choice: dict[str, float], tuned_on: str, *, command: str,
                    shiftable_windows: bool | None = None, border_band: bool | None = None) -> Path:
    """Set the folder's ``sgm`` to ``choice`` (and ``sgm.shiftable_windows``, ``filling.border_band``
    unless None) and re-measure the metrics it records."""
    manifest = load_manifest(folder)
    manifest["sgm"] = {**manifest["sgm"], "p1": choice["p1"], "p2": choice["p2"], "tuned_on": tuned_on}
    if shiftable_windows is not None:
        manifest["sgm"]["shiftable_windows"] = shiftable_windows
    if border_band is not None:
        manifest["filling"] = {**manifest.get("filling", {}), "border_band": border_band}
    datasets = datasets_of(manifest)
    manifest["metrics"] = {}
    path = write_manifest(folder, manifest)
    if datasets:
        manifest["metrics"] = measure_folder(folder, datasets, command=command)
        path = write_manifest(folder, manifest)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.tune", description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True, metavar="DIR", help="model folder to tune")
    parser.add_argument("--pairs", type=int, default=20, help="synthetic validation pairs (%(default)s)")
    parser.add_argument("--p1", type=float, nargs="+", default=list(P1_GRID), help="P1 grid")
    parser.add_argument("--p2", type=float, nargs="+", default=list(P2_GRID), help="P2 grid")
    parser.add_argument("--shiftable-windows", action=argparse.BooleanOptionalAction, default=None,
                        help="tune with the shiftable-window step on / off and record it in the manifest "
                        "with --write (default: as the manifest says)")
    parser.add_argument("--border-band", action=argparse.BooleanOptionalAction, default=None,
                        help="tune with the border band step on / off and record it in the manifest "
                        "(filling.border_band) with --write (default: as the manifest says)")
    parser.add_argument("--write", action="store_true", help="write the choice into DIR/manifest.json")
    args = parser.parse_args(argv)
    command = " ".join(["python", "-m", "export.tune", *(sys.argv[1:] if argv is None else argv)])
    try:
        if args.pairs < 1:
            raise ValueError(f"--pairs must be >= 1, got {args.pairs}")
        load_manifest(args.model)  # a clear error before any matching
        choice, tuned_on = tune_folder(args.model, pairs=args.pairs, p1_grid=args.p1, p2_grid=args.p2,
                                       log=lambda row: print(row, file=sys.stderr),
                                       shiftable_windows=args.shiftable_windows,
                                       border_band=args.border_band)
        print(json.dumps(choice))
        if args.write:
            path = write_penalties(args.model, choice, tuned_on, command=command,
                                   shiftable_windows=args.shiftable_windows,
                                   border_band=args.border_band)
            print(f"wrote {path}", file=sys.stderr)
    except (OSError, ValueError, ModelError) as error:
        print(f"export.tune: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
