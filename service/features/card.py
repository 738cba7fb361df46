"""A model folder's card (README.md, Markdown), generated from its manifest so that it cannot drift.

The card says what a user asks before trusting a model: what it is for, what it was trained on and
what that leaves out, its figures on that folder's own ONNX files (``metrics``, written by
``python -m export.measure``), its speed, licence and how it was made. Everything comes from
``manifest.json``; :func:`write_manifest` rewrites the card with every manifest it writes, ``python -m
export.card`` regenerates cards by hand, ``GET /v1/model/card`` serves the card of the served manifest,
and tests/service/features/test_model_card.py regenerates each shipped card and compares it with the file.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

CARD_NAME = "README.md"
# The project's licence (pyproject.toml; tests/service/features/test_model_card.py holds the two together).
# The shipped towers are trained and exported by the project from data its own code generates.
PROJECT_LICENCE = "Apache-2.0"
# What the data set names of export.measure stand for (others are shown with their SPEC only).
DATASET_NOTES = {
    "middlebury2003-cones": "Middlebury 2003 *Cones*, 450 x 375, a real pair: evaluation only, never "
    "trained, selected or tuned on",
    "middlebury2014-motorcycle": "Middlebury 2014 *Motorcycle* at quarter size, 741 x 500, as "
    "scikit-image's wheel ships it, occlusions derived from its truth: a real pair, evaluation only, never "
    "trained, selected or tuned on",
    "synthetic-validation": "the fixed synthetic validation split (seeds from 10^9, 256 x 512): models, "
    "checkpoints and P1/P2 are chosen on it",
}
_COLUMNS = (("bad-1 %", "bad1"), ("bad-2 %", "bad2"), ("bad-3 %", "bad3"), ("bad-5 %", "bad5"),
            ("EPE px", "epe"), ("non-occl. bad-2 %", "bad2_nonocc"), ("non-occl. EPE px", "epe_nonocc"),
            ("density %", "density"))


def model_card(manifest: Mapping[str, Any]) -> str:
    """The card of a (schema-valid) manifest, as Markdown ending in one newline."""
    sections = [_summary(manifest), _intended_use(manifest), _training_data(manifest), _metrics(manifest),
                _speed(manifest), _quantization(manifest), _provenance(manifest), _licence(manifest)]
    return "\n\n".join(section for section in sections if section) + "\n"


def write_card(folder: str | Path, manifest: Mapping[str, Any]) -> Path:
    """Write ``folder/README.md`` from ``manifest`` (not listed in ``files``: it is derived, not loaded)."""
    path = Path(folder) / CARD_NAME
    path.write_text(model_card(manifest), encoding="utf-8")
    return path


def _summary(m: Mapping[str, Any]) -> str:
    onnx, files = m["onnx"], m["files"]
    towers = "shared left/right weights" if m.get("shared_towers") else "separate left and right towers"
    rows = [("network", f"`{m['config']}`, {m['channels']} feature channels, receptive field "
                        f"{m['receptive_field']} px, {towers}"),
            ("precision", f"{onnx['precision']} (ONNX opset {onnx['opset']})"),
            ("files", ", ".join(f"`{name}` {entry['bytes']:,} bytes, sha256 `{entry['sha256'][:12]}…`"
                                for name, entry in files.items())),
            ("SGM", f"P1 {m['sgm']['p1']:g}, P2 {m['sgm']['p2']:g}, {m['sgm']['paths']} paths"),
            ("disparity", ("" if m.get("training") is None else
                           f"trained on {_range(m['disparity']['trained_range'])} px; ")
             + f"searches 0..{m['disparity']['default_max'] - 1} unless told")]
    table = "\n".join(["| | |", "| --- | --- |", *(f"| {key} | {value} |" for key, value in rows)])
    return (f"# {m['name']}\n\n{m.get('description', '')}\n\n"
            "<!-- Generated from manifest.json (service/features/card.py): edit the manifest and run "
            f"`python -m export.card --model <folder> --write`, not this file. -->\n\n{table}")


def _intended_use(m: Mapping[str, Any]) -> str:
    return ("## Intended use\n\n"
            "Dense disparity, depth and point clouds from a **rectified** stereo pair (8-bit RGB or grey, "
            "matching points on the same row) on a CPU, through this project's runtime: `adsm predict "
            f"--model {m['name']}`, `adsm serve`, `Matcher.from_folder(...)`. The runtime checks both ONNX "
            "files against the sha256 above before it runs them; the towers only make features, the "
            "matching (cost volume, SGM, left-right check, filling) is the runtime's.\n\n"
            "Not for: unrectified or swapped pairs (rectify first: `adsm predict --calib`; `adsm predict` "
            "warns about both), scenes whose disparities exceed the search range, or decisions that matter "
            "(safety, measurement) before you have measured the model on your own camera and scenes "
            "(`adsm eval`).")


def _training_data(m: Mapping[str, Any]) -> str:
    training = m.get("training")
    if training is None:
        return ("## Training data\n\nNone: the towers are built by hand, not trained (see the description). "
                "The SGM penalties were tuned on " + _tuned_on(m) + ".")
    data = str(training.get("data", ""))
    text = f"## Training data and its limits\n\n{data}.\n\n"
    selection = ((m.get("build") or {}).get("trainer_config") or {}).get("selection")
    chosen = f"checkpoint chosen by {selection}; " if selection else ""
    if data.startswith("synthetic"):
        text += ("**Synthetic only: no real stereo pair was used** to train the towers, to choose the "
                 f"checkpoint or to tune P1/P2 ({chosen}P1/P2: {_tuned_on(m)}). The `--cones` of the "
                 "training commands below only reports figures on that pair while training; the trainer "
                 "refuses it as training data (training/data/evaluation_only.py). The scenes are stacks "
                 "of textured planes "
                 "(slanted backgrounds, a ground plane, objects, thin poles and fences) painted with "
                 "procedural textures and scikit-image's bundled photos, seen through simulated camera "
                 "effects (blur, gain, gamma, noise, JPEG); ground truth and occlusions are exact "
                 "(docs/data.md). What real cameras add is absent: curved, shiny, transparent and "
                 "reflective surfaces, motion blur, rolling shutter, residual rectification error, "
                 "sensor-specific noise and colour. Real-image accuracy rests on one real pair (Cones, "
                 "below); measure on your own data before relying on it.")
    else:
        text += (f"Its limits are those of that data ({chosen}P1/P2: {_tuned_on(m)}): measure on your own "
                 "data before relying on it.")
    return text


def _metrics(m: Mapping[str, Any]) -> str:
    metrics = {name: entry for name, entry in m.get("metrics", {}).items() if isinstance(entry, Mapping)}
    if not metrics:
        return "## Metrics\n\nNone recorded (`python -m export.measure --model <folder> --write`)."
    header = ["data set", "pairs", "D", *(label for label, _ in _COLUMNS)]
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for name, entry in metrics.items():
        cells = [f"{name} (`{entry['data']}`)" if "data" in entry else name,
                 _figure(entry.get("pairs"), "{:g}"), _figure(entry.get("max_disparity"), "{:g}"),
                 *(_figure(entry.get(key), "{:.2f}") for _, key in _COLUMNS)]
        lines.append("| " + " | ".join(cells) + " |")
    notes = [f"- {name}: {DATASET_NOTES[name]}." for name in metrics if name in DATASET_NOTES]
    runs = sorted({(str(e.get("command", "")), str(e.get("date", "")), str(e.get("runtime", "")))
                   for e in metrics.values() if e.get("command")})
    measured = [f"- `{command}` ({date}; {runtime})" for command, date, runtime in runs]
    return ("## Metrics\n\nMeasured on this folder's own ONNX files through the runtime (the code of `adsm "
            "eval`), with the manifest's P1/P2 and the runtime's defaults; bad-N is the share of pixels "
            "more than N px off, over every ground-truth pixel unless \"non-occl.\"; D is the search range."
            "\n\n" + "\n".join(lines) + ("\n\n" + "\n".join(notes) if notes else "")
            + ("\n\nMeasured by:\n\n" + "\n".join(measured) if measured else ""))


def _speed(m: Mapping[str, Any]) -> str:
    timed = [(name, entry) for name, entry in m.get("metrics", {}).items()
             if isinstance(entry, Mapping) and isinstance(entry.get("seconds_per_pair"), int | float)]
    if not timed:
        return ""
    lines = [f"- {name}, D = {entry.get('max_disparity', '?')}: {entry['seconds_per_pair']:.3f} s per pair "
             f"({entry.get('runtime', 'runtime not recorded')})" for name, entry in timed]
    return ("## Speed\n\nWhole matcher call per pair after warm-up (towers, cost volume, SGM, checks), on "
            "the machine that measured the metrics above:\n\n" + "\n".join(lines) + "\n\nThe one figure "
            "here that depends on that machine; `python -m bench suite` times yours.")


def _quantization(m: Mapping[str, Any]) -> str:
    quantization = m["onnx"].get("quantization")
    if not isinstance(quantization, Mapping):
        return ""
    lines = [f"- method: {quantization.get('method', 'not recorded')}",
             f"- calibration images: {quantization.get('calibration', 'not recorded')}"]
    accuracy = quantization.get("accuracy_vs_fp32")
    if isinstance(accuracy, Mapping):
        cosines = [f"{side} mean {accuracy[key]['mean']:.4f} (1st percentile {accuracy[key]['p01']:.4f})"
                   for side, key in (("left", "feature_cosine_left"), ("right", "feature_cosine_right"))
                   if isinstance(accuracy.get(key), Mapping)]
        lines.append(f"- against the fp32 towers on {accuracy.get('pair', 'a test pair')}: feature cosine "
                     + "; ".join(cosines) + ", disparity within 1 px on "
                     + _figure(accuracy.get("disparity_agreement_1px"), "{:.2%}") + " of the pixels")
    return ("## Quantisation\n\n" + "\n".join(lines) + "\n\nThe metrics above are this int8 folder's own, "
            "not its fp32 twin's.")


def _provenance(m: Mapping[str, Any]) -> str:
    parts = ["## How it was made"]
    stage, depth = m.get("training"), 0
    while isinstance(stage, Mapping) and stage.get("command"):
        what = "Training" if depth == 0 else "Warm start from"
        facts = ", ".join(f"{label} {stage[key]}" for label, key in (
            ("iterations", "iterations"), ("wall time s", "wall_time_s"), ("on", "device")) if key in stage)
        parts.append(f"{what} ({facts}):\n\n```bash\n{stage['command']}\n```")
        stage, depth = stage.get("warm_start"), depth + 1
    build = m.get("build")
    if isinstance(build, Mapping) and build.get("command"):
        date = build.get("date", "date not recorded")
        parts.append(f"Export ({date}):\n\n```bash\n{build['command']}\n```")
    return "\n\n".join(parts) if len(parts) > 1 else ""


def _licence(m: Mapping[str, Any]) -> str:
    photos = (" The photos among the synthetic textures and the int8 calibration images are scikit-image's "
              "bundled data (their terms: scikit-image's `skimage/data/README.txt`)."
              if str((m.get("training") or {}).get("data", "")).startswith("synthetic")
              or m["onnx"].get("quantization") else "")
    return (f"## Licence\n\n{PROJECT_LICENCE}, the ADSM stereo project's licence, for the folders this "
            "project ships (trained and exported by it from data its own code generates); a folder built "
            f"elsewhere carries its builder's terms.{photos} Cones: D. Scharstein and R. Szeliski, "
            "\"High-accuracy stereo depth maps using structured light\", CVPR 2003.")


def _tuned_on(m: Mapping[str, Any]) -> str:
    return str(m["sgm"].get("tuned_on", "data not recorded"))


def _range(pair: list[int]) -> str:
    return f"{pair[0]}..{pair[1]}"


def _figure(value: Any, pattern: str) -> str:
    return pattern.format(value) if isinstance(value, int | float) and not isinstance(value, bool) else "–"
