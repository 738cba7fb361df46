"""Measure a model folder's ONNX towers through today's runtime and record the figures in its manifest.

    python -m export.measure --model service/models/NAME            # print the figures
    python -m export.measure --model service/models/NAME --write    # ... and write them into manifest.json

Each data set runs through exactly what ``adsm eval`` runs: ``Matcher.from_folder`` (which verifies the
sha256 of both towers first), ``matcher.warmup()``, then ``service.evaluation.evaluate.evaluate`` with the
runtime's defaults (the manifest's P1/P2, check and fill on, dense output, D = the data set's own range).
The data sets:

- ``middlebury2003-cones``: the Cones pair (evaluation only, never tuned on), ``--cones PATH`` (default
  ``../shared/data/middlebury2003-cones`` beside the checkout); D = 64. Always measured.
- ``middlebury2014-motorcycle``: the second real pair, the SPEC ``motorcycle`` (scikit-image's copy of
  Middlebury 2014's Motorcycle, evaluation only like Cones); D = 64. Measured wherever scikit-image is
  installed (the train extra), unless ``--no-motorcycle``.
- ``synthetic-validation``: the fixed synthetic validation split (``synthetic:N``), when the manifest
  already carries it (N = its ``pairs``) or ``--synthetic N`` asks for it (``--synthetic 0``: not).
- ``--data NAME=SPEC`` (repeatable): any other ``adsm eval`` data SPEC under a name of your choice.

Every entry of ``metrics`` gets bad-1..5, D1, EPE, density and pixel count over every ground-truth pixel,
the same with ``_nonocc`` over the non-occluded ones where the data set has a mask, pairs, D, seconds
per pair (after warm-up, on this machine, so the one figure that is not reproducible elsewhere), the data
SPEC, the runtime's versions, and the exact command and date. ``--write`` replaces the whole ``metrics``
object (a figure nobody can re-measure with this command does not stay) and rewrites the manifest through
``write_manifest``: schema-validated, file hashes recomputed (and checked unchanged).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from service.features.manifest import ModelError, load_manifest, write_manifest
from training.data.evaluation_only import CONES_FOLDER as DEFAULT_CONES
from training.data.evaluation_only import CONES_NAME as CONES
from training.data.evaluation_only import MOTORCYCLE_NAME as MOTORCYCLE
from training.data.evaluation_only import MOTORCYCLE_SPEC
from training.data.motorcycle import motorcycle_files

SYNTHETIC = "synthetic-validation"
DEFAULT_SYNTHETIC_PAIRS = 20
# Figures kept per pixel subset (service.evaluation.metrics.ErrorCounts.summary).
FIGURES = ("bad1", "bad2", "bad3", "bad4", "bad5", "d1", "epe", "density", "pixels")


def default_datasets(manifest: Mapping[str, Any], *, cones: str | Path | None = DEFAULT_CONES,
                     synthetic_pairs: int | None = None, motorcycle: bool = True) -> dict[str, str]:
    """NAME -> SPEC of the data sets a folder is measured on (see the module docstring).

    ``cones`` None or a missing folder leaves Cones out (the caller decides whether that is an error);
    ``synthetic_pairs`` None means: as many pairs as the manifest's synthetic entry records, if any;
    ``motorcycle`` measures the Motorcycle pair where scikit-image's copy of it is installed.
    """
    datasets: dict[str, str] = {}
    if cones is not None and Path(cones).is_dir():
        datasets[CONES] = f"cones:{_display_path(cones)}"
    if motorcycle and motorcycle_installed():
        datasets[MOTORCYCLE] = MOTORCYCLE_SPEC
    if synthetic_pairs is None:
        recorded = manifest.get("metrics", {}).get(SYNTHETIC)
        synthetic_pairs = int(recorded.get("pairs") or DEFAULT_SYNTHETIC_PAIRS) if recorded else 0
    if synthetic_pairs > 0:
        datasets[SYNTHETIC] = f"synthetic:{synthetic_pairs}"
    return datasets


def motorcycle_installed() -> bool:
    """Whether the SPEC ``motorcycle`` can be opened here (scikit-image and its copy of the pair)."""
    try:
        motorcycle_files()
    except (ModuleNotFoundError, FileNotFoundError):
        return False
    return True


def datasets_of(manifest: Mapping[str, Any]) -> dict[str, str]:
    """NAME -> SPEC of the data sets a manifest's metrics were measured on (entries that record ``data``)."""
    return {name: entry["data"] for name, entry in manifest.get("metrics", {}).items()
            if isinstance(entry, Mapping) and isinstance(entry.get("data"), str)}


def measure_folder(folder: str | Path, datasets: Mapping[str, str], *, command: str,
                   threads: int | None = None, log: Callable[[str], Any] = lambda _: None) -> dict[str, Any]:
    """The ``metrics`` object of ``folder`` measured on ``datasets`` (NAME -> ``adsm eval`` SPEC)."""
    import numba
    import onnxruntime

    from service.datasets import open_dataset
    from service.evaluation.evaluate import evaluate
    from service.matcher import Matcher

    matcher = Matcher.from_folder(folder, threads=threads)  # verifies both towers' sha256
    matcher.warmup()  # JIT compilation is not timed, as in adsm eval
    date = datetime.now(UTC).isoformat(timespec="seconds")
    runtime = (f"onnxruntime {onnxruntime.__version__}, numba {numba.__version__}, "
               f"threads {threads or 'all CPUs'}")
    metrics: dict[str, Any] = {}
    for name, spec in datasets.items():
        dataset = open_dataset(spec)
        report = evaluate(matcher, dataset)
        ranges = sorted({pair["max_disparity"] for pair in report["per_pair"]})
        entry: dict[str, Any] = {key: report["all"][key] for key in FIGURES}
        if report["nonoccluded"] is not None:
            entry |= {f"{key}_nonocc": report["nonoccluded"][key] for key in FIGURES}
        entry |= {"pairs": report["pairs"], "max_disparity": ranges[0] if len(ranges) == 1 else None,
                  "seconds_per_pair": report["seconds_per_pair"], "data": spec, "runtime": runtime,
                  "command": command, "date": date}
        metrics[name] = entry
        log(f"{Path(folder).name} on {name}: bad-2 {entry['bad2']:.2f} %, EPE {entry['epe']:.2f} px, "
            f"{entry['seconds_per_pair']:.3f} s per pair")
    return metrics


def write_metrics(folder: str | Path, metrics: dict[str, Any]) -> Path:
    """Replace ``metrics`` in ``folder``'s manifest; the files' hashes must come out unchanged."""
    manifest = load_manifest(folder)
    path = write_manifest(folder, {**manifest, "metrics": metrics})
    if load_manifest(folder)["files"] != manifest["files"]:  # pragma: no cover - the files were not touched
        raise ModelError(f"{folder}: the tower files changed while they were measured")
    return path


def measure_command(folder: str | Path, datasets: Mapping[str, str], *, write: bool = True) -> str:
    """The ``python -m export.measure`` command line that measures ``folder`` on ``datasets``."""
    argv = ["python", "-m", "export.measure", "--model", _display_path(folder)]
    synthetic = datasets.get(SYNTHETIC, "synthetic:0").partition(":")[2]
    argv += ["--synthetic", synthetic]
    if CONES in datasets:
        argv += ["--cones", datasets[CONES].partition(":")[2]]
    if MOTORCYCLE not in datasets:
        argv += ["--no-motorcycle"]
    argv += [item for name, spec in datasets.items() if name not in (CONES, SYNTHETIC, MOTORCYCLE)
             for item in ("--data", f"{name}={spec}")]
    return shlex.join(argv + (["--write"] if write else []))


README_FIGURES = ("bad2", "bad1", "bad3", "bad4", "bad5", "epe", "bad2_nonocc")  # the table's Cones columns
README_MOTORCYCLE_FIGURES = ("bad2", "bad1")  # then the Motorcycle columns


def readme_row(metrics: Mapping[str, Any]) -> str:
    """The README model table's figures, in its column order: synthetic bad-2 % ("-" when not measured),
    then Cones bad-2, bad-1, bad-3, bad-4, bad-5 %, EPE px, non-occluded bad-2 %, then Motorcycle bad-2
    and bad-1 % ("-" when not measured)."""
    cones = metrics[CONES]
    synthetic = f"{metrics[SYNTHETIC]['bad2']:.2f}" if SYNTHETIC in metrics else "-"
    motorcycle = metrics.get(MOTORCYCLE)
    cells = ([synthetic] + [f"{cones[key]:.2f}" for key in README_FIGURES]
             + [f"{motorcycle[key]:.2f}" if motorcycle else "-" for key in README_MOTORCYCLE_FIGURES])
    return "| " + " | ".join(cells) + " |"


def _display_path(path: str | Path) -> str:
    """``path`` relative to the current directory when it lies below or beside it, else absolute."""
    resolved = Path(path).resolve()
    for base, prefix in ((Path.cwd(), ""), (Path.cwd().parent, "../")):
        if resolved.is_relative_to(base):
            return prefix + str(resolved.relative_to(base))
    return str(resolved)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m export.measure", description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 2)[2],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", required=True, type=Path, metavar="DIR", help="model folder to measure")
    parser.add_argument("--cones", type=Path, default=DEFAULT_CONES, metavar="PATH",
                        help="the Cones folder (default: %(default)s)")
    parser.add_argument("--no-motorcycle", action="store_true",
                        help="leave out the Motorcycle pair (measured by default where scikit-image is "
                             "installed)")
    parser.add_argument("--synthetic", type=int, metavar="N",
                        help="synthetic validation pairs (default: as many as the manifest records, "
                             "0 if it records none)")
    parser.add_argument("--data", action="append", default=[], metavar="NAME=SPEC",
                        help="also measure an `adsm eval` data SPEC under NAME (repeatable)")
    parser.add_argument("--threads", type=int, metavar="N", help="runtime threads (default: all CPUs)")
    parser.add_argument("--write", action="store_true", help="write the figures into DIR/manifest.json")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    command = shlex.join(["python", "-m", "export.measure", *(sys.argv[1:] if argv is None else argv)])
    try:
        if args.synthetic is not None and args.synthetic < 0:
            raise ValueError(f"--synthetic must be >= 0, got {args.synthetic}")
        if not args.cones.is_dir():
            raise ValueError(f"no Cones folder at {args.cones} (--cones PATH)")
        manifest = load_manifest(args.model)
        datasets = default_datasets(manifest, cones=args.cones, synthetic_pairs=args.synthetic,
                                    motorcycle=not args.no_motorcycle)
        for item in args.data:
            name, equals, spec = item.partition("=")
            if not (name and equals and spec):
                raise ValueError(f"--data wants NAME=SPEC, got {item!r}")
            if name in (CONES, SYNTHETIC, MOTORCYCLE):  # its figures would be recorded as that data set's
                raise ValueError(f"--data {item!r}: {name} is measured by --cones / --synthetic / "
                                 "--no-motorcycle; give this data set another NAME")
            datasets[name] = spec
        metrics = measure_folder(args.model, datasets, command=command, threads=args.threads,
                                 log=lambda line: print(line, file=sys.stderr))
        print(json.dumps(metrics, indent=2))
        print(f"README row figures (synthetic bad-2; Cones bad-2, bad-1, bad-3..5, EPE, non-occl. bad-2; "
              "Motorcycle bad-2, bad-1): "
              f"{readme_row(metrics)}", file=sys.stderr)
        if args.write:
            print(f"wrote {write_metrics(args.model, metrics)}", file=sys.stderr)
    except (OSError, ValueError, ModelError) as error:
        print(f"export.measure: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
