"""Runtime stages at KITTI size (375x1242, D=192): seconds per stage, SGM ns per cell per path, peak RSS.

Part 1 times each Numba stage on random-but-realistic unit-norm features (a slanted background, a
foreground box, feature noise), for C = 64 (the ADSM towers) and for C of the shipped baseline model.
Part 2 runs the whole Matcher of a model folder (default: the shipped model) on a synthetic textured pair
of the same size, in a fresh child process so that its peak RSS is that of one inference process alone.
Figures are medians over ``--repeats`` runs after one warm-up run.

    python -m bench runtime [--threads 2] [--repeats 5] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench import positive_int
from service import jit
from service.aggregation import shiftable_windows
from service.cost import COST_DTYPE, cost_volume
from service.disparity import left_right_winners
from service.filling import fill_invalid
from service.optimization import aggregate
from service.refinement import refine_subpixel
from service.validation import inner_check

PATHS = 4
STAGES = ("cost_volume", "shiftable_windows", "sgm", "disparity", "subpixel", "lr_check", "fill")


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def scene_disparity(height: int, width: int, disparities: int) -> np.ndarray:
    """int HxW: a slanted background (road-like, growing downwards) and a nearer box in the middle."""
    y, x = np.mgrid[0:height, 0:width]
    rising = y / max(height - 1, 1)
    background = disparities * (0.05 + 0.45 * rising + 0.02 * x / width)
    box = (abs(y - height / 2) < height / 5) & (abs(x - width / 2) < width / 8)
    return np.where(box, 0.8 * disparities, background).astype(np.int64).clip(0, disparities - 1)


def realistic_features(
    channels: int, height: int, width: int, disparities: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Unit-norm (C, H, W) features: left = right shifted by the scene's disparity, plus feature noise."""
    right = rng.standard_normal((channels, height, width), dtype=np.float32)
    shift = scene_disparity(height, width, disparities)
    rows, columns = np.mgrid[0:height, 0:width]
    source = columns - shift
    left = right[:, rows, source.clip(0)]
    left[:, source < 0] = rng.standard_normal((channels, int((source < 0).sum())), dtype=np.float32)
    left += 0.5 * rng.standard_normal(left.shape, dtype=np.float32)
    for features in (left, right):
        features /= np.linalg.norm(features, axis=0, keepdims=True)
    return left, right


def realistic_images(
    height: int, width: int, disparities: int, rng: np.random.Generator
) -> tuple[np.ndarray, ...]:
    """uint8 HxWx3 pair: smoothed noise texture warped by the scene's disparity, plus sensor noise."""
    noise = rng.uniform(0, 255, (height + 2, width + 2, 3)).astype(np.float32)
    right = sum(noise[i : i + height, j : j + width] for i in range(3) for j in range(3)) / 9.0
    shift = scene_disparity(height, width, disparities)
    rows, columns = np.mgrid[0:height, 0:width]
    left = right[rows, (columns - shift).clip(0)]
    pair = [image + rng.normal(0, 3, image.shape) for image in (left, right)]
    return tuple(np.clip(np.rint(image), 0, 255).astype(np.uint8) for image in pair)


def _median_times(run: Callable[[], dict[str, float]], repeats: int) -> dict[str, float]:
    """Median of each figure over ``repeats`` runs after a warm-up run; ``<stage>_min`` keeps the fastest
    (on a shared machine the minimum is the least disturbed run)."""
    run()  # compile / load kernels, touch memory
    samples = [run() for _ in range(repeats)]
    medians = {stage: statistics.median(sample[stage] for sample in samples) for stage in samples[0]}
    return {**medians, **{f"{stage}_min": min(sample[stage] for sample in samples) for stage in samples[0]}}


def time_stages(left: np.ndarray, right: np.ndarray, disparities: int, repeats: int) -> dict[str, float]:
    """Median seconds of each stage, with the manifest-default penalties of the paper (P1 30, P2 160)."""
    shape = (left.shape[1], left.shape[2], disparities)
    raw = np.empty(shape, COST_DTYPE)
    aggregated = np.empty(shape, COST_DTYPE)

    def run() -> dict[str, float]:
        times = {}
        clock = time.perf_counter()
        cost_volume(left, right, disparities, scale=128.0, out=raw)
        times["cost_volume"] = -clock + (clock := time.perf_counter())
        shiftable_windows(raw)
        times["shiftable_windows"] = -clock + (clock := time.perf_counter())
        cpu = time.process_time()
        aggregate(raw, p1=30.0, p2=160.0, out=aggregated)
        times["sgm_cpu"] = time.process_time() - cpu  # all threads' CPU seconds: robust to other load
        times["sgm"] = -clock + (clock := time.perf_counter())
        winners, right_winners = left_right_winners(aggregated)
        times["disparity"] = -clock + (clock := time.perf_counter())
        disparity = refine_subpixel(aggregated, winners)
        times["subpixel"] = -clock + (clock := time.perf_counter())
        validity = inner_check(disparity, right_winners, disparities)
        times["lr_check"] = -clock + (clock := time.perf_counter())
        fill_invalid(disparity, validity)
        times["fill"] = -clock + (clock := time.perf_counter())
        times["invalid_fraction"] = float(np.mean(validity != 0))
        return times

    return _median_times(run, repeats)


def time_matcher(model: str | None, size: tuple[int, int, int], threads: int | None, repeats: int) -> dict:
    """Whole-Matcher medians, measured in this process (call it in a fresh one for a clean peak RSS)."""
    from service.matcher import Matcher, MatchOptions

    height, width, disparities = size
    matcher = Matcher.from_folder(model, threads=threads)
    matcher.warmup()
    left, right = realistic_images(height, width, disparities, np.random.default_rng(0))
    options = MatchOptions(max_disparity=disparities)
    medians = _median_times(lambda: matcher(left, right, options).timings, repeats)
    return {"model": matcher.manifest["name"], "timings": medians, "peak_rss_mib": peak_rss_mib()}


def _matcher_in_child(args: argparse.Namespace) -> dict:
    command = [sys.executable, "-m", "bench", "runtime", "--matcher-child", "--repeats", str(args.repeats)]
    for option in ("height", "width", "disparities"):
        command += [f"--{option}", str(getattr(args, option))]
    if args.threads:
        command += ["--threads", str(args.threads)]
    if args.model:
        command += ["--model", args.model]
    repository = Path(__file__).resolve().parent.parent  # `-m bench` needs it on sys.path
    completed = subprocess.run(command, capture_output=True, text=True, check=False, cwd=repository)
    if completed.returncode != 0:
        raise RuntimeError(f"matcher benchmark failed:\n{completed.stderr.strip()}")
    return json.loads(completed.stdout.strip().splitlines()[-1])


def _baseline_channels() -> int | None:
    from service.features import ModelError, default_model_dir, load_manifest

    try:
        return int(load_manifest(default_model_dir())["channels"])
    except ModelError:
        return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench runtime", description=__doc__.splitlines()[0])
    parser.add_argument("--height", type=positive_int, default=375)
    parser.add_argument("--width", type=positive_int, default=1242)
    parser.add_argument("--disparities", type=positive_int, default=192)
    parser.add_argument("--channels", type=positive_int, nargs="*",
                        help="feature channels (default: 64, the model's)")
    parser.add_argument("--repeats", type=positive_int, default=5)
    parser.add_argument("--threads", type=positive_int,
                        help="Numba and ONNX Runtime threads (default: all CPUs)")
    parser.add_argument("--model", help="model folder for the whole-Matcher run (default: the shipped one)")
    parser.add_argument("--no-matcher", action="store_true", help="time the Numba stages only")
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    parser.add_argument("--matcher-child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if min(args.height, args.width, args.disparities, args.repeats) < 1:
        parser.error("sizes and --repeats must be >= 1")
    size = (args.height, args.width, args.disparities)
    threads = jit.set_threads(args.threads)
    if args.matcher_child:
        print(json.dumps(time_matcher(args.model, size, args.threads, args.repeats)))
        return 0

    report: dict[str, Any] = {"size": dict(zip(("height", "width", "disparities"), size, strict=True)),
                              "numba_threads": threads, "repeats": args.repeats, "stages": {}}
    channels = args.channels or sorted({64, *filter(None, [_baseline_channels()])})
    rng = np.random.default_rng(0)
    print(f"stages at {args.height}x{args.width}, D={args.disparities}, {threads} Numba threads, "
          f"median of {args.repeats}")
    for count in channels:
        left, right = realistic_features(count, args.height, args.width, args.disparities, rng)
        stages = time_stages(left, right, args.disparities, args.repeats)
        del left, right
        cells = args.height * args.width * args.disparities * PATHS
        ns_per_cell_path = stages["sgm"] / cells * 1e9
        # CPU seconds / threads: what the wall time would be with the cores to ourselves (OpenMP's
        # spin-waiting makes it an upper bound).
        ns_cpu = stages["sgm_cpu_min"] / threads / cells * 1e9
        report["stages"][f"C={count}"] = {
            **stages, "sgm_ns_per_cell_per_path": ns_per_cell_path,
            "sgm_ns_per_cell_per_path_min": stages["sgm_min"] / cells * 1e9,
            "sgm_cpu_ns_per_cell_per_path": ns_cpu,
        }
        listed = "  ".join(f"{k} {v:.3f}s" for k, v in stages.items() if k in STAGES)
        print(f"  C={count:<4d} {listed}  | SGM {ns_per_cell_path:.3f} ns/cell/path "
              f"(best {stages['sgm_min'] / cells * 1e9:.3f}, CPU/threads {ns_cpu:.3f}) "
              f"| invalid {stages['invalid_fraction']:.1%}")
    report["stages_peak_rss_mib"] = peak_rss_mib()
    print(f"  peak RSS of the stage run (features, 2 volumes, maps): {report['stages_peak_rss_mib']:.0f} MiB")

    if not args.no_matcher:
        matcher = _matcher_in_child(args)
        report["matcher"] = matcher
        listed = "  ".join(f"{k} {v:.3f}s" for k, v in matcher["timings"].items() if not k.endswith("_min"))
        print(f"matcher ({matcher['model']}): {listed}")
        print(f"  peak RSS of the matcher process: {matcher['peak_rss_mib']:.0f} MiB")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
