"""The table in the paper's shape, ours beside the paper's figures: OUT/table.md (printed) and OUT/table.json.

Two sections: the network alone (winner-takes-all on the raw cost volume) and the full pipeline (4-path
SGM + inner check + ray filling). Each cell reads ``ours / paper (ours - paper)`` in % of ground-truth
pixels; rows of other methods show the paper's figure only; configs without a result yet say so.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from training.reproduce.tables import THRESHOLDS, Table

SECTIONS = (
    ("network", "Network alone: winner-takes-all on the raw cost volume (no SGM, no sub-pixel fit, no check, "
                "no fill)"),
    ("pipeline", "Full pipeline: towers + 4-path SGM + sub-pixel fit + inner left-right check + ray filling"),
)


def load_results(out: Path, table: Table) -> dict[str, dict[str, Any]]:
    """The results written so far for the table's configs, by config name."""
    results = {}
    for config in table.configs:
        path = out / "results" / f"{config}.json"
        if path.is_file():
            results[config] = json.loads(path.read_text())
    return results


def _cell(ours: float | None, paper: float | None, digits: int = 2) -> str:
    if ours is None and paper is None:
        return ""
    if ours is None:
        return f"- / {paper:.{digits}f}"
    if paper is None:
        return f"{ours:.{digits}f}"
    return f"{ours:.{digits}f} / {paper:.{digits}f} ({ours - paper:+.{digits}f})"


def build(table: Table, results: dict[str, dict[str, Any]], split: dict[str, Any] | None,
          protocol: dict[str, Any] | None) -> dict[str, Any]:
    """JSON-ready table: every row with the paper's figures and ours (None where not measured)."""
    rows = []
    for row in table.rows:
        paper = dict(zip([f"bad{t}" for t in THRESHOLDS], row.figures, strict=True))
        entry: dict[str, Any] = {"label": row.label, "config": row.config, "paper": paper,
                                 "paper_runtime_s": row.runtime_s}
        result = results.get(row.config) if row.config else None
        for section, _ in SECTIONS:
            if result is None:
                entry[section] = None
                continue
            figures = result[section]["all"]
            entry[section] = {**{f"bad{t}": figures[f"bad{t}"] for t in THRESHOLDS},
                              "epe": figures["epe"], "density": figures["density"],
                              "nonoccluded_bad2": (result[section]["nonoccluded"] or {}).get("bad2"),
                              "seconds_per_pair": result[section]["seconds_per_pair"]}
        if result is not None:
            entry["runtime"] = result["runtime"]
            entry["training"] = result["training"]
            entry["mode"] = result["mode"]
        rows.append(entry)
    return {"schema": "adsm-reproduce-table/1", "table": table.number, "title": table.title,
            "paper_dataset": table.dataset, "measures": table.measures, "protocol": protocol,
            "split": None if split is None else {k: split[k] for k in ("data", "seed", "train_spec",
                                                                         "test_spec") if k in split}
            | {"test_pairs": len(split["test"]) if isinstance(split.get("test"), list) else
               (protocol or {}).get("synthetic_test_pairs")},
            "rows": rows}


def render(report: dict[str, Any]) -> str:
    """Markdown: a header saying what was measured on what, then the two sections."""
    protocol, split = report["protocol"] or {}, report["split"] or {}
    lines = [f"Table {report['table']}: {report['title']}",
             f"paper: {report['paper_dataset']} ({report['measures']}); ours: test part of "
             f"{split.get('data')} ({split.get('test_pairs')} pairs, split seed {split.get('seed')})"]
    if protocol:
        lines.append(f"protocol: {protocol['iterations']} iterations, batch {protocol['batch_size']} patch "
                     f"pairs (37x37 / 37x237), {protocol['channels']} channels, "
                     f"{'shared' if protocol['shared'] else 'separate'} towers, eq. (19) label, Adam lr "
                     f"{protocol['lr']:g}, seed {protocol['seed']}; modes: "
                     + ", ".join(sorted({f"{r['mode']}" for r in report["rows"] if r.get("mode")})))
    if split.get("data") and not str(split["data"]).startswith(report["paper_dataset"]):
        lines.append(f"note: the paper measured this table on {report['paper_dataset']}; these figures are "
                     f"on {split['data']}, so the differences compare different data")
    runtime = any(r["paper_runtime_s"] is not None for r in report["rows"])
    for section, title in SECTIONS:
        lines += ["", f"{title}. Cells: ours / paper (ours - paper), % of ground-truth pixels.", ""]
        header = ["ConvNet / method", *[f"{t}-pixel-error" for t in THRESHOLDS],
                  "Runtime (s) ours / paper" if runtime else "s/pair (ONNX)"]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for row in report["rows"]:
            ours = row[section]
            cells = [_cell(None if ours is None else ours[f"bad{t}"], row["paper"][f"bad{t}"])
                     for t in THRESHOLDS]
            seconds = None if ours is None else ours["seconds_per_pair"]
            if runtime:
                time_cell = _cell(seconds, row["paper_runtime_s"], 3)
            else:
                time_cell = "" if seconds is None else f"{seconds:.3f}"
            if row["config"] and ours is None:
                cells = [f"not run / {row['paper'][f'bad{t}']:.2f}" for t in THRESHOLDS]
            lines.append("| " + " | ".join([row["label"], *cells, time_cell]) + " |")
    done = [r for r in report["rows"] if r.get("runtime")]
    if done:
        info = done[0]["runtime"]
        lines += ["", "Runtimes: seconds per pair of the Matcher (file reading excluded, after warm-up), "
                      f"{info['engine']} {info['providers']}, {info['threads']} threads on "
                      f"{info['machine']}; "
                      f"SGM P1 {info['p1']:g}, P2 {info['p2']:g} (cost scale 128)."]
    return "\n".join(lines) + "\n"


def write(out: Path, table: Table, split: dict[str, Any] | None, protocol: dict[str, Any] | None) -> str:
    """Write OUT/table.json and OUT/table.md; returns the markdown."""
    report = build(table, load_results(out, table), split, protocol)
    text = render(report)
    (out / "table.json").write_text(json.dumps(report, indent=1) + "\n")
    (out / "table.md").write_text(text)
    return text
