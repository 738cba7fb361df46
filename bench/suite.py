"""Speed and memory suite: every shipped model, Cones and KITTI size, per-stage medians, peers, targets.

    python -m bench suite [--repeats 3] [--models NAME_OR_DIR ...] [--sizes cones kitti] [--threads N]
                          [--json OUT]

Each (model folder, size) runs in its own child process, so its peak RSS is that of one inference
process alone: load + sha256 check, ``Matcher.warmup()``, one first call (timed separately: it shows
whether anything is still compiled on the request path), then ``--repeats`` timed calls of the whole
``adsm predict`` path: decode both PNGs, towers, cost volume, SGM, disparity + sub-pixel + check + fill,
png16 encode. Sizes: Cones (the real pair of ../shared/data/middlebury2003-cones, 450x375, D=64) and
KITTI (375x1242, D=192, a synthetic textured pair). In the same run: OpenCV StereoSGBM on the same
pairs, CNES libsgm on our cost volume (if installed), and a reference ONNX conv for tower efficiency
(bench/peers.py). Wall times on a loaded machine are inflated; CPU seconds are printed next to them.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import resource
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import positive_int
from training.data.evaluation_only import CONES_FOLDER

REPOSITORY = Path(__file__).resolve().parent.parent
SIZES = {"cones": (375, 450, 64), "kitti": (375, 1242, 192)}
SGM_PATHS = 4
# The "post" column: the steps after the left view's SGM up to the fill (the right view's SGM included).
POST_STAGES = ("disparity", "subpixel", "right_sgm", "lr_check", "fill")
# Targets of issue 6 (375x1242, D=192, 2 cores, whole predict minus decoding).
TARGET_DEFAULT_S, TARGET_PAPER_INT8_S, TARGET_SGM_NS, TARGET_TOWER_EFFICIENCY, TARGET_RSS_MIB = (
    1.0, 2.5, 0.8, 0.70, 1536.0)


def pair_png(size: str) -> tuple[bytes, bytes]:
    """The benchmark pair of a size as PNG bytes (decoding is a measured stage)."""
    if size == "cones":
        return (CONES_FOLDER / "left.png").read_bytes(), (CONES_FOLDER / "right.png").read_bytes()
    from PIL import Image

    from bench.runtime import realistic_images

    height, width, disparities = SIZES[size]
    encoded = []
    for image in realistic_images(height, width, disparities, np.random.default_rng(0)):
        buffer = io.BytesIO()
        Image.fromarray(image).save(buffer, format="PNG")
        encoded.append(buffer.getvalue())
    return encoded[0], encoded[1]


def _compiled_signatures() -> int:
    """Number of compiled Numba specialisations of the runtime's kernels (grows if a call compiles)."""
    import numba

    total = 0
    for name, module in list(sys.modules.items()):
        if name.startswith("service.") and module is not None:
            total += sum(len(v.signatures) for v in vars(module).values()
                         if isinstance(v, numba.core.registry.CPUDispatcher))
    return total


def machine_description() -> str:
    """The CPU model and the cores this process may use: timings mean little without them."""
    model = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                  if line.startswith("model name")), None) if Path("/proc/cpuinfo").is_file() else None
    return f"{model or platform.processor() or platform.machine()}, {len(os.sched_getaffinity(0))} cores"


def checkout_commit() -> str | None:
    """The checkout's commit (with '+dirty' when files differ from it), or None outside a git checkout."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPOSITORY, capture_output=True, text=True,
                              timeout=30, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPOSITORY,
                               capture_output=True, text=True, timeout=30, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "")


def _command(argv: list[str] | None) -> str:
    return shlex.join(["python", "-m", "bench", "suite", *(sys.argv[1:] if argv is None else argv)])


def measure_model(folder: Path, size: str, repeats: int, threads: int | None) -> dict[str, Any]:
    """One model at one size, in this process: medians per stage, CPU seconds, first call, peak RSS."""
    from bench import peers
    from service.io.disparity import encode_disparity
    from service.io.images import read_image
    from service.matcher import Matcher, MatchOptions

    height, width, disparities = SIZES[size]
    left_png, right_png = pair_png(size)
    matcher = Matcher.from_folder(folder, threads=threads)
    matcher.warmup()
    options = MatchOptions(max_disparity=disparities)

    def run() -> dict[str, float]:
        cpu = time.process_time()
        clock = time.perf_counter()
        left, right = read_image(left_png), read_image(right_png)
        decode = time.perf_counter() - clock
        result = matcher(left, right, options)
        clock = time.perf_counter()
        encode_disparity(result.disparity, "png16")
        t = result.timings
        stages = {"decode": decode, "towers": t["towers"], "cost_volume": t["cost_volume"], "sgm": t["sgm"],
                  "post": sum(t.get(k, 0.0) for k in POST_STAGES),
                  "encode": time.perf_counter() - clock}
        stages["total"] = decode + t["total"] + stages["encode"]
        stages["predict"] = stages["total"] - decode
        stages["cpu"] = time.process_time() - cpu
        return stages

    compiled = _compiled_signatures()
    first = run()
    compiled_on_request = _compiled_signatures() - compiled
    samples = [run() for _ in range(repeats)]
    medians = {k: statistics.median(s[k] for s in samples) for k in samples[0]}
    manifest = matcher.manifest
    report = {"model": manifest["name"], "folder": str(folder), "precision": manifest["onnx"]["precision"],
              "channels": manifest["channels"], "size": size, "shape": [height, width, disparities],
              "files": manifest["files"],  # the towers' sha256: which weights these figures belong to
              "median": medians, "min_predict": min(s["predict"] for s in samples),
              "first_call_total": first["total"], "kernels_compiled_on_request": compiled_on_request,
              "sgm_ns_per_cell_per_path": medians["sgm"] / (height * width * disparities * SGM_PATHS) * 1e9}
    # Before the reference conv below, whose int8 calibration would otherwise set this process's peak.
    report["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    flops = peers.conv_flops(folder / "left.onnx", height, width)
    report["towers_gflops"] = 2 * flops / medians["towers"] / 1e9  # both towers
    # Reference: one 11x11 conv of the model's channels and precision with about one tower's FLOPs.
    channels = int(manifest["channels"])
    reference_width = max(peers.REFERENCE_KERNEL + 1,
                          round(flops / (2 * channels**2 * peers.REFERENCE_KERNEL**2 * height)))
    report["reference_conv_gflops"] = peers.reference_conv_gflops(
        channels, height, reference_width, precision=report["precision"],
        threads=threads or len(os.sched_getaffinity(0)), repeats=max(1, min(repeats, 2)))
    return report


def measure_peers(folder: Path, size: str, repeats: int, threads: int) -> dict[str, Any]:
    """Peers at one size: our SGM vs libsgm on one cost volume, OpenCV SGBM, the reference conv."""
    from bench import peers
    from service import jit
    from service.cost import cost_volume
    from service.io.images import read_image
    from service.matcher import Matcher
    from service.optimization import aggregate

    disparities = SIZES[size][2]
    left, right = (read_image(data) for data in pair_png(size))
    matcher = Matcher.from_folder(folder, threads=threads)
    matcher.warmup()
    jit.set_threads(threads)
    manifest = matcher.manifest
    p1, p2 = float(manifest["sgm"]["p1"]), float(manifest["sgm"]["p2"])
    features = matcher.towers(left, right)
    volume = cost_volume(*features, disparities, scale=float(manifest["cost"]["scale"]))
    del features
    cells_paths = volume.size * SGM_PATHS
    result = np.empty_like(volume)
    wall, cpu = peers.median_seconds(lambda: aggregate(volume, p1=p1, p2=p2, out=result), repeats)
    report: dict[str, Any] = {
        "size": size, "model": manifest["name"],
        "ours_sgm": {"wall_s": wall, "cpu_s": cpu, "paths": SGM_PATHS,
                     "ns_per_cell_per_path": wall / cells_paths * 1e9,
                     "cpu_ns_per_cell_per_path": cpu / cells_paths * 1e9},
        "libsgm": peers.libsgm_aggregate(volume, p1=p1, p2=p2, repeats=max(1, min(repeats, 2))),
    }
    report["opencv_sgbm"] = peers.opencv_sgbm(left, right, disparities, threads=threads, repeats=repeats)
    return report


def shipped_models() -> list[Path]:
    from service.features.manifest import MODELS_DIR

    return sorted(path.parent for path in MODELS_DIR.glob("*/manifest.json"))


def _child(args: list[str]) -> dict[str, Any]:
    command = [sys.executable, "-m", "bench", "suite", *args]
    completed = subprocess.run(command, capture_output=True, text=True, check=False, cwd=REPOSITORY)
    if completed.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed:\n{completed.stderr.strip()[-2000:]}")
    return json.loads(completed.stdout.strip().splitlines()[-1])


def model_folder(name: str) -> Path:
    """A folder given by path, or by its name under service/models."""
    from service.features.manifest import MODELS_DIR

    path = Path(name)
    return path if path.is_dir() else MODELS_DIR / name


def print_tables(report: dict[str, Any]) -> None:
    columns = ("decode", "towers", "cost_volume", "sgm", "post", "encode", "total", "predict", "cpu")
    print(f"\nseconds, median of {report['repeats']} (post = disparity + sub-pixel + the right view's SGM + "
          "check + fill; "
          "predict = total - decode; cpu = CPU s of all threads)")
    print(f"{'model':<20} {'size':<6}" + "".join(f"{c[:8]:>9}" for c in columns)
          + f"{'RSS MiB':>9}{'1st call':>9}{'SGM ns':>8}{'GFLOP/s':>9}{'ref':>7}")
    for row in report["models"]:
        m = row["median"]
        print(f"{row['model']:<20} {row['size']:<6}" + "".join(f"{m[c]:9.3f}" for c in columns)
              + f"{row['peak_rss_mib']:9.0f}{row['first_call_total']:9.3f}"
              + f"{row['sgm_ns_per_cell_per_path']:8.3f}{row['towers_gflops']:9.1f}"
              + f"{row['reference_conv_gflops']:7.0f}")
    print("(GFLOP/s: both towers' convs; ref: one 11x11 conv of the model's channels and precision, "
          "same run)")
    for peer in report["peers"]:
        ours = peer["ours_sgm"]
        print(f"\npeers at {peer['size']} (cost volume of {peer['model']}):")
        print(f"  our SGM, 4 paths     {ours['wall_s']:.3f} s  "
              f"{ours['ns_per_cell_per_path']:.3f} ns/cell/path  "
              f"(CPU {ours['cpu_ns_per_cell_per_path']:.3f})")
        libsgm = peer["libsgm"]
        if libsgm:
            print(f"  CNES libsgm, 8 paths {libsgm['wall_s']:.3f} s  {libsgm['ns_per_cell_per_path']:.3f} "
                  f"ns/cell/path (CPU {libsgm['cpu_ns_per_cell_per_path']:.3f})  -> ours is "
                  f"{libsgm['ns_per_cell_per_path'] / ours['ns_per_cell_per_path']:.1f}x faster "
                  "per cell-path")
        else:
            print("  CNES libsgm: not installed (pip install libsgm)")
        sgbm = peer["opencv_sgbm"]
        ours_rows = [r for r in report["models"] if r["size"] == peer["size"] and r["model"] == peer["model"]]
        if sgbm:
            ratio = ""
            if ours_rows:
                ratio = ours_rows[0]["median"]["predict"] / sgbm["wall_s"]
                ratio = f" -> our whole predict takes {ratio:.2f}x its time"
            print(f"  OpenCV {sgbm['version']} StereoSGBM HH4 {sgbm['wall_s']:.3f} s{ratio}")


def check_targets(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Issue 6's targets at KITTI size, each with the figure that decides it."""
    kitti = {row["model"]: row for row in report["models"] if row["size"] == "kitti"}
    peer = next((p for p in report["peers"] if p["size"] == "kitti"), None)
    checks = []

    def add(name: str, value: float, limit: float, holds: bool) -> None:
        checks.append({"target": name, "value": value, "limit": limit, "holds": bool(holds)})

    # The default model's target also applies to adsm-fast fp32/int8, the intended default.
    for name in dict.fromkeys([report.get("default_model"), "adsm-fast", "adsm-fast-int8"]):
        if name in kitti:
            value = kitti[name]["median"]["predict"]
            add(f"{name} predict <= {TARGET_DEFAULT_S} s", value, TARGET_DEFAULT_S, value <= TARGET_DEFAULT_S)
    if "adsm-paper-int8" in kitti:
        value = kitti["adsm-paper-int8"]["median"]["predict"]
        add(f"adsm-paper-int8 predict <= {TARGET_PAPER_INT8_S} s", value, TARGET_PAPER_INT8_S,
            value <= TARGET_PAPER_INT8_S)
    if peer:
        value = peer["ours_sgm"]["ns_per_cell_per_path"]
        add(f"SGM <= {TARGET_SGM_NS} ns/cell/path", value, TARGET_SGM_NS, value <= TARGET_SGM_NS)
    for name, row in kitti.items():
        if name.startswith("adsm"):  # the NCC baseline's towers are a correlation, not a conv stack
            efficiency = row["towers_gflops"] / row["reference_conv_gflops"]
            add(f"{name} towers >= {TARGET_TOWER_EFFICIENCY:.0%} of reference conv GFLOP/s", efficiency,
                TARGET_TOWER_EFFICIENCY, efficiency >= TARGET_TOWER_EFFICIENCY)
        add(f"{name} peak RSS <= {TARGET_RSS_MIB:.0f} MiB", row["peak_rss_mib"], TARGET_RSS_MIB,
            row["peak_rss_mib"] <= TARGET_RSS_MIB)
        add(f"{name} no JIT compile on the first request", row["kernels_compiled_on_request"], 0,
            row["kernels_compiled_on_request"] == 0)
    return checks


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench suite", description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=positive_int, default=3)
    parser.add_argument("--models", nargs="+",
                        help="model folder names or paths (default: every shipped one)")
    parser.add_argument("--sizes", nargs="+", choices=sorted(SIZES), default=["cones", "kitti"])
    parser.add_argument("--threads", type=positive_int,
                        help="Numba and ONNX Runtime threads (default: all CPUs)")
    parser.add_argument("--no-peers", action="store_true", help="skip OpenCV, libsgm, the reference conv")
    parser.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    parser.add_argument("--child", nargs=2, metavar=("KIND", "FOLDER"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.repeats < 1 or (args.threads is not None and args.threads < 1):
        parser.error("--repeats and --threads must be >= 1")
    threads = args.threads or len(os.sched_getaffinity(0))
    if args.child:
        kind, folder = args.child
        measure = measure_model if kind == "model" else measure_peers
        size = args.sizes[0]
        chosen = args.threads if kind == "model" else threads
        print(json.dumps(measure(Path(folder), size, args.repeats, chosen)))
        return 0

    from service.features.manifest import ModelError, default_model_dir

    folders = [model_folder(name) for name in args.models] if args.models else shipped_models()
    missing = [str(f) for f in folders if not (f / "manifest.json").is_file()]
    if missing:
        parser.error(f"not a model folder (no manifest.json): {', '.join(missing)}")
    try:
        default = default_model_dir()
    except ModelError:
        default = folders[0]
    started = time.perf_counter()
    report: dict[str, Any] = {"repeats": args.repeats, "threads": threads, "load_before": os.getloadavg(),
                              "machine": machine_description(), "commit": checkout_commit(),
                              "command": _command(argv),
                              "default_model": default.name, "models": [], "peers": []}
    common = ["--repeats", str(args.repeats)] + (["--threads", str(args.threads)] if args.threads else [])
    for size in args.sizes:
        for folder in folders:
            print(f"measuring {folder.name} at {size} ...", file=sys.stderr, flush=True)
            report["models"].append(_child(["--child", "model", str(folder), "--sizes", size, *common]))
        if not args.no_peers:
            print(f"measuring peers at {size} ...", file=sys.stderr, flush=True)
            report["peers"].append(_child(["--child", "peers", str(default), "--sizes", size, *common]))
    report["load_after"] = os.getloadavg()
    report["seconds"] = time.perf_counter() - started
    report["targets"] = check_targets(report)
    print_tables(report)
    print(f"\ntargets at KITTI size ({threads} threads; load average before {report['load_before'][0]:.2f}, "
          f"after {report['load_after'][0]:.2f}; suite took {report['seconds']:.0f} s):")
    for check in report["targets"]:
        print(f"  [{'holds' if check['holds'] else 'FAILS'}] {check['target']}: {check['value']:.3g}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
