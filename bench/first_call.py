"""First call: a one-off `adsm predict` (fresh process) against the warm matcher, KITTI size, stage by stage.

Issue 12, item 6: a one-off run's matcher time should be at most 1.3x the warm matcher time. Each
repeat spawns a fresh ``python -m service predict LEFT RIGHT -o OUT --max-disparity 192 --timings
--no-check`` (the real command: imports, model load, decode, one match, encode) and reads its timings
line; ``match`` is the matcher's time, ``startup`` the process's wall time outside the command's own
timings (interpreter, imports). A separate child loads the same model, warms it up and times the same
matcher call ``--repeats`` times: the warm figure. ``--compare`` also runs every one-off with
``ADSM_PREPARE=0`` (no background kernel loading and volume mapping, service/matcher.py ``prepare``),
alternating with the default so both see the same machine. Medians, minima and the load average are
printed; on a shared machine compare the ratio, not the absolute seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import positive_int

STAGES = ("prepare", "towers", "cost_volume", "sgm", "disparity", "subpixel", "right_sgm", "lr_check", "fill",
          "border")
# A stand-in package that makes `import scipy` fail, for --serve-extra: the serve extra installs no SciPy,
# and numba imports scipy.linalg (when present) at its first kernel load, looking for a BLAS.
_NO_SCIPY = 'raise ImportError("SciPy is hidden: python -m bench first_call --serve-extra")\n'


def _pair(folder: Path, height: int, width: int, disparities: int) -> tuple[Path, Path]:
    from PIL import Image

    from bench.runtime import realistic_images

    left, right = realistic_images(height, width, disparities, np.random.default_rng(0))
    paths = folder / "left.png", folder / "right.png"
    for path, image in zip(paths, (left, right), strict=True):
        Image.fromarray(image).save(path)
    return paths


def one_off(left: Path, right: Path, disparities: int, folder: Path, *, prepare: bool,
            environment: dict[str, str]) -> dict[str, float]:
    """One fresh ``adsm predict`` process: its timings line, wall seconds and CPU seconds."""
    command = [sys.executable, "-m", "service", "predict", str(left), str(right), "-o",
               str(folder / "disparity.png"), "--max-disparity", str(disparities), "--timings", "--no-check"]
    environment = {**environment, "ADSM_PREPARE": "1" if prepare else "0"}
    before = os.times()
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=environment, check=False)
    wall = time.perf_counter() - started
    after = os.times()
    if done.returncode != 0:
        raise RuntimeError(f"adsm predict failed ({done.returncode}): {done.stderr.strip()}")
    timings = json.loads(done.stderr.strip().splitlines()[-1])
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    return {**timings, "wall": wall, "cpu": cpu, "startup": wall - timings["total"]}


def warm_child(left: Path, right: Path, disparities: int, repeats: int) -> dict[str, Any]:
    """In this process: the warm matcher's seconds per call (after warm-up and one untimed call)."""
    from service.io import read_pair
    from service.matcher import Matcher, MatchOptions

    matcher = Matcher.from_folder()
    matcher.warmup()
    images = read_pair(left, right)
    options = MatchOptions(max_disparity=disparities)
    matcher(*images, options)
    calls = []
    for _ in range(repeats):
        started = time.perf_counter()
        result = matcher(*images, options)
        calls.append({"match": time.perf_counter() - started, **result.timings})
    return {"calls": calls}


def _summary(samples: list[dict[str, float]], keys: tuple[str, ...]) -> dict[str, dict[str, float]]:
    return {key: {"median": round(statistics.median(s.get(key, 0.0) for s in samples), 3),
                  "min": round(min(s.get(key, 0.0) for s in samples), 3)} for key in keys}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench first_call", description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=positive_int, default=5,
                        help="one-off processes (and warm calls) per variant")
    parser.add_argument("--size", default="375x1242", help="HEIGHTxWIDTH of the synthetic pair (KITTI size)")
    parser.add_argument("--max-disparity", type=positive_int, default=192)
    parser.add_argument("--compare", action="store_true", help="also run every one-off with ADSM_PREPARE=0")
    parser.add_argument("--serve-extra", action="store_true",
                        help="hide SciPy from the children, as a `pip install .[serve]` has none")
    parser.add_argument("--json", metavar="OUT", help="write the figures as JSON")
    parser.add_argument("--warm-child", nargs=2, metavar=("LEFT", "RIGHT"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.warm_child:
        left, right = (Path(path) for path in args.warm_child)
        print(json.dumps(warm_child(left, right, args.max_disparity, args.repeats)))
        return 0

    height, width = (int(part) for part in args.size.lower().split("x"))
    load_before = os.getloadavg()
    variants = {"one-off": True, **({"one-off, ADSM_PREPARE=0": False} if args.compare else {})}
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        left, right = _pair(folder, height, width, args.max_disparity)
        environment = dict(os.environ)
        if args.serve_extra:
            (folder / "hidden" / "scipy").mkdir(parents=True)
            (folder / "hidden" / "scipy" / "__init__.py").write_text(_NO_SCIPY)
            paths = [str(folder / "hidden"), environment.get("PYTHONPATH", "")]
            environment["PYTHONPATH"] = os.pathsep.join(path for path in paths if path)
        # Untimed: fills the Numba cache (as any earlier run, or the image's build, does) and the page cache.
        one_off(left, right, args.max_disparity, folder, prepare=True, environment=environment)
        one_offs: dict[str, list[dict[str, float]]] = {name: [] for name in variants}
        for _ in range(args.repeats):  # alternating, so every variant sees the same machine
            for name, prepare in variants.items():
                one_offs[name].append(one_off(left, right, args.max_disparity, folder, prepare=prepare,
                                              environment=environment))
        command = [sys.executable, "-m", "bench", "first_call", "--warm-child", str(left), str(right),
                   "--max-disparity", str(args.max_disparity), "--repeats", str(args.repeats)]
        done = subprocess.run(command, capture_output=True, text=True, check=True, env=environment)
        warm = json.loads(done.stdout.strip().splitlines()[-1])["calls"]
    keys = ("match", *STAGES)
    report: dict[str, Any] = {
        "size": [height, width], "max_disparity": args.max_disparity, "repeats": args.repeats,
        "scipy_hidden": args.serve_extra,
        "load_before": [round(value, 2) for value in load_before],
        "warm": _summary(warm, keys),
        "one_off": {name: _summary(samples, (*keys, "load_model", "decode", "startup", "wall", "cpu"))
                    for name, samples in one_offs.items()},
        "load_after": [round(value, 2) for value in os.getloadavg()],
    }
    warm_match = report["warm"]["match"]["median"]
    for figures in report["one_off"].values():
        figures["ratio_to_warm"] = round(figures["match"]["median"] / warm_match, 2)
    print(format_report(report))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
    return 0


def format_report(report: dict[str, Any]) -> str:
    height, width = report["size"]
    hidden = ", SciPy hidden (serve extra)" if report["scipy_hidden"] else ""
    lines = [f"first call: {width}x{height}, D = {report['max_disparity']}, {report['repeats']} repeats"
             f"{hidden}, load average {report['load_before'][0]:.2f} before, "
             f"{report['load_after'][0]:.2f} after",
             f"{'seconds (median / min)':<28}" + "".join(f"{key:>16}" for key in ("match", *STAGES[:4]))]
    rows = [("warm matcher", report["warm"]), *report["one_off"].items()]
    for name, figures in rows:
        cells = "".join(f"{figures[key]['median']:>9.3f} / {figures[key]['min']:<4.2f}"
                        for key in ("match", *STAGES[:4]))
        lines.append(f"{name:<28}{cells}")
    for name, figures in report["one_off"].items():
        lines.append(f"{name}: match {figures['ratio_to_warm']:.2f}x the warm matcher (target <= 1.3x); "
                     f"process wall {figures['wall']['median']:.2f} s (startup and imports "
                     f"{figures['startup']['median']:.2f}, model load {figures['load_model']['median']:.2f}, "
                     f"decode {figures['decode']['median']:.2f}), CPU {figures['cpu']['median']:.2f} s")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
