"""GPU path against the CPU path: per-stage medians of every model at Cones and KITTI size (issue 16).

    python -m bench gpu [--models NAME_OR_DIR ...] [--sizes cones kitti] [--repeats 3]
                        [--towers onnx|torch] [--sgm-threads N ...] [--json OUT]

For each model and size, in one process: the Matcher on the CPU and on the GPU (``device="cuda"``), each
warmed up (one untimed call: the first GPU call compiles its kernels) and then timed ``--repeats`` times
on the same pair; the stages are the Matcher's own timings (the GPU's synchronised per stage), and the
GPU result is compared with the CPU's (share of pixels whose disparity agrees within 0.01 px). Sizes and
pairs are the suite's (bench/suite.py): Cones (450x375, D=64) and a synthetic KITTI-size pair (375x1242,
D=192). ``--towers onnx`` runs the folder's ONNX towers through ONNX Runtime with the providers it has
(CUDA / TensorRT with onnxruntime-gpu, else the CPU); ``--towers torch`` runs the folder's architecture
in PyTorch on the GPU with untrained weights: the towers' time on a GPU where onnxruntime-gpu is missing,
its maps meaningless (the agreement column then compares two runs of the same untrained towers). Device
memory: what the CUDA context holds right after a call (the volumes kept for the next call included).
``--sgm-threads 32 64 128 256`` times the GPU SGM alone on a random volume of each size per threads-per-
line choice instead (service/cuda/sgm.py), the CPU's SGM on the same volume beside it.
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
from pathlib import Path
from typing import Any

import numpy as np

from bench import positive_int
from bench.suite import SIZES, pair_png
from service.features import default_model_dir

# The default's fp32 graph (adsm-rf17-int8's twin: the PyTorch towers run fp32), the former default and the
# paper's config: issue 16 times the default and the paper model.
MODELS = ("adsm-rf17", "adsm-fast", "adsm-paper")


def _towers(folder: Path, kind: str) -> Any:
    """The towers the two matchers share: the folder's ONNX ones, or its architecture in PyTorch."""
    from service.features import FeatureTowers, load_manifest

    if kind == "onnx":
        return FeatureTowers(folder)
    from training.evaluation import TorchTowers
    from training.networks import build_tower_pair

    manifest = load_manifest(folder)
    model = build_tower_pair(manifest["config"], channels=int(manifest["channels"]),
                             shared=bool(manifest.get("shared_towers", False))).cuda()
    towers = TorchTowers(model, {"cost_scale": manifest["cost"]["scale"], "p1": manifest["sgm"]["p1"],
                                 "p2": manifest["sgm"]["p2"], "input": manifest["input"],
                                 "default_max": manifest["disparity"]["default_max"]})
    towers.manifest = {**manifest, **{key: towers.manifest[key] for key in ("channels", "receptive_field")}}
    return towers


def _device_bytes() -> int | None:
    """Bytes the GPU has in use now (None on Numba's CUDA simulator, which has no memory to report)."""
    from numba import cuda

    free, total = cuda.current_context().get_memory_info()
    used = total - free
    return int(used) if np.isfinite(used) else None


def run_model(folder: Path, size: str, *, repeats: int, towers_kind: str) -> dict[str, Any]:
    """Medians per stage on the CPU and on the GPU for one model at one size, and their agreement."""
    from PIL import Image

    from service.match_options import MatchOptions
    from service.matcher import Matcher

    left, right = (np.asarray(Image.open(io.BytesIO(data)).convert("RGB")) for data in pair_png(size))
    options = MatchOptions(max_disparity=SIZES[size][2])
    towers = _towers(folder, towers_kind)
    report: dict[str, Any] = {"model": folder.name, "size": size, "towers": towers_kind,
                              "shape": [*left.shape[:2], options.max_disparity]}
    results = {}
    for device in ("cpu", "cuda"):
        matcher = Matcher(towers, device=device)
        matcher(left, right, options)  # compiles (GPU) or loads (CPU) every kernel of the path
        samples = [matcher(left, right, options) for _ in range(repeats)]
        stages = {stage: statistics.median(sample.timings[stage] for sample in samples)
                  for stage in samples[0].timings}
        report[device] = {"median": stages, "min_total": min(sample.timings["total"] for sample in samples)}
        if device == "cuda":
            report[device]["device_bytes"] = _device_bytes()
        results[device] = samples[-1]
    agree = np.isclose(results["cuda"].disparity, results["cpu"].disparity, rtol=0, atol=0.01, equal_nan=True)
    report["agreement"] = float(agree.mean())
    report["speedup"] = report["cpu"]["median"]["total"] / report["cuda"]["median"]["total"]
    return report


def sgm_threads_sweep(size: str, choices: list[int], *, repeats: int) -> list[dict[str, Any]]:
    """The GPU SGM's time per threads-per-line choice on a random volume of ``size``, beside the CPU's."""
    import time

    from numba import cuda

    from service.cuda import sgm
    from service.optimization import aggregate

    height, width, disparities = SIZES[size]
    volume = np.random.default_rng(0).integers(-128, 129, (height, width, disparities)).astype(np.int16)
    device_volume, device_out = cuda.to_device(volume), cuda.device_array(volume.shape, np.int16)

    def seconds(run: Any) -> float:
        run()  # compiles or loads first
        samples = []
        for _ in range(repeats):
            started = time.perf_counter()
            run()
            cuda.synchronize()
            samples.append(time.perf_counter() - started)
        return statistics.median(samples)

    cpu = seconds(lambda: aggregate(volume, p1=30, p2=540))
    rows = []
    for threads in choices:
        gpu = seconds(lambda threads=threads: sgm.aggregate(device_volume, p1=30, p2=540, out=device_out,
                                                            threads=threads))
        rows.append({"size": size, "threads": threads, "gpu_s": gpu, "cpu_s": cpu})
        print(f"SGM at {size} {volume.shape}, {threads:>3} threads per line: {1000 * gpu:7.2f} ms "
              f"(CPU {1000 * cpu:.1f} ms, x{cpu / gpu:.1f})")
    return rows


def _print(report: dict[str, Any]) -> None:
    stages = [stage for stage in report["cuda"]["median"] if stage != "total"]
    used = report["cuda"]["device_bytes"]
    memory = "n/a" if used is None else f"{used / 2**20:.0f} MiB"
    print(f"\n{report['model']} at {report['size']} {report['shape']} (towers: {report['towers']}); "
          f"agreement {100 * report['agreement']:.2f} %, device memory {memory}")
    print(f"  {'stage':<18}{'cpu ms':>10}{'cuda ms':>10}")
    for stage in [*stages, "total"]:
        cpu = report["cpu"]["median"].get(stage)
        print(f"  {stage:<18}{'-' if cpu is None else f'{1000 * cpu:.1f}':>10}"
              f"{1000 * report['cuda']['median'][stage]:>10.1f}")
    print(f"  speedup x{report['speedup']:.1f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench gpu", description=__doc__.split("\n")[0])
    parser.add_argument("--models", nargs="+", default=list(MODELS), metavar="NAME_OR_DIR")
    parser.add_argument("--sizes", nargs="+", choices=sorted(SIZES), default=["cones", "kitti"])
    parser.add_argument("--repeats", type=positive_int, default=3)
    parser.add_argument("--towers", choices=("onnx", "torch"), default="onnx")
    parser.add_argument("--sgm-threads", nargs="+", type=int, metavar="N",
                        help="instead of the models: the GPU SGM alone at each size with N threads per scan "
                             "line (32, 64, 128, 256), beside the CPU's SGM")
    parser.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    args = parser.parse_args(argv)
    from service.cuda import require_cuda

    require_cuda()
    if args.sgm_threads:
        rows = [row for size in args.sizes
                for row in sgm_threads_sweep(size, args.sgm_threads, repeats=args.repeats)]
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
        return 0
    reports = []
    for name in args.models:
        folder = Path(name) if Path(name).is_dir() else default_model_dir().parent / name
        for size in args.sizes:
            reports.append(run_model(folder, size, repeats=args.repeats, towers_kind=args.towers))
            _print(reports[-1])
            if args.json:  # after every row: a run cut short keeps what it measured
                args.json.write_text(json.dumps(reports, indent=2) + "\n")
    return 0
