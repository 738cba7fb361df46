"""Peak RSS of the service over a growing sequence of the worst shapes at the default limits.

    python -m bench memory [--model DIR] [--threads N] [--shapes H,W,D ...] [--json OUT]

A child process runs ``adsm serve`` with the default settings (``ADSM_*`` limits unset); once ready, it
gets one ``POST /pointcloud`` per shape (the largest answer) in the order given, from small to large,
and its own RSS and peak (``/proc/PID/status`` VmRSS, VmHWM) are read after each answer. Each shape
takes the most disparities the limits admit (``ADSM_MAX_COST_CELLS``, ``ADSM_MAX_DISPARITY``, the width)
unless ``D`` is given. Per shape it prints the status (413 when the service refuses it before decoding),
the request's memory plan (service/memory.py), the process's RSS after the answer and its peak so far,
both above the idle size after warm-up, against the documented bound ``memory_bound()``. The process's
ONNX Runtime arena and kept cost volumes grow with the largest request served and never shrink, which is
what the sequence exercises.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench import positive_int
from bench.serving import free_port

# Worst shapes at the default limits (2.1 Mpx, 1e8 cost cells, 256 disparities): every aspect ratio the
# pixel limit admits, smallest plan first. H, W, D (0: the most the limits admit).
DEFAULT_SHAPES = [
    (375, 1242, 192), (8, 262144, 0), (64, 32768, 0), (300, 7000, 0), (1000, 2100, 0), (1449, 1449, 0),
    (1080, 1920, 0), (2, 1050000, 1),
]


def _status(pid: int) -> tuple[int, int]:
    """(VmRSS, VmHWM) of process ``pid`` in bytes: its resident size now and its peak so far."""
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in ("VmRSS", "VmHWM"):
            fields[name] = int(value.split()[0]) * 1024
    return fields["VmRSS"], fields["VmHWM"]


def _png(height: int, width: int, seed: int) -> bytes:
    from PIL import Image

    image = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def measure(shapes: list[tuple[int, int, int]], *, model: str | None = None,
            threads: int | None = None) -> dict:
    """Run ``adsm serve`` with the default limits in a child process and send it ``shapes`` in order;
    the child's own RSS (the client's memory is not counted) above its idle size after warm-up."""
    import httpx

    from service.api import Settings
    from service.features import default_model_dir, load_manifest
    from service.memory import memory_bound, plan_request

    settings = Settings()
    manifest = load_manifest(model or default_model_dir())
    bound = memory_bound(manifest, max_pixels=settings.max_pixels, max_cost_cells=settings.max_cost_cells)
    port = free_port()
    env = {key: value for key, value in os.environ.items()
           if not key.startswith("ADSM_") or key == "ADSM_NUMBA_CACHE_DIR"}
    command = [sys.executable, "-m", "service", "serve", "--port", str(port), "--log-level", "warning"]
    command += ["--model", model] if model else []
    command += ["--threads", str(threads)] if threads else []
    server = subprocess.Popen(command, env=env)
    url = f"http://127.0.0.1:{port}"
    rows = []
    try:
        deadline = time.monotonic() + 300
        while True:
            if server.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("adsm serve did not become ready")
            try:
                if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.2)
        idle, _ = _status(server.pid)
        for height, width, disparities in shapes:
            if not disparities:
                disparities = max(1, min(settings.max_disparity, width,
                                         settings.max_cost_cells // (height * width)))
            files = {"left": ("l.png", _png(height, width, 1)), "right": ("r.png", _png(height, width, 2))}
            answer = httpx.post(f"{url}/pointcloud?focal_px=700&baseline_m=0.1&max_disparity={disparities}",
                                files=files, timeout=600)
            rss, peak = _status(server.pid)
            plan = plan_request(height, width, disparities, manifest)
            rows.append({
                "height": height, "width": width, "disparities": disparities, "status": answer.status_code,
                "plan_mib": round(plan.peak_bytes / 2**20),
                "answer_mib": round(len(answer.content) / 2**20, 1),
                "rss_mib": round((rss - idle) / 2**20), "peak_mib": round((peak - idle) / 2**20),
            })
    finally:
        server.terminate()
        server.wait(timeout=60)
    return {"model": manifest["name"], "idle_mib": round(idle / 2**20), "bound_mib": round(bound / 2**20),
            "rows": rows}


def _shape(text: str) -> tuple[int, int, int]:
    parts = [int(part) for part in text.split(",")]
    if len(parts) == 2:
        parts.append(0)
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected H,W or H,W,D, got {text!r}")
    if min(parts[:2]) < 1 or parts[2] < 0:
        raise argparse.ArgumentTypeError(f"H and W must be >= 1 and D >= 0 (0: the default), got {text!r}")
    return parts[0], parts[1], parts[2]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench memory", description=__doc__.splitlines()[0])
    parser.add_argument("--model", metavar="DIR", help="model folder (default: the shipped default)")
    parser.add_argument("--threads", type=positive_int, help="compute threads (default: all cores)")
    parser.add_argument("--shapes", nargs="+", type=_shape, default=DEFAULT_SHAPES, metavar="H,W[,D]")
    parser.add_argument("--json", type=Path, metavar="OUT", help="also write the figures as JSON")
    args = parser.parse_args(argv)
    result = measure(args.shapes, model=args.model, threads=args.threads)
    print(f"model {result['model']}: idle RSS after warm-up {result['idle_mib']} MiB; documented bound "
          f"(memory_bound) +{result['bound_mib']} MiB")
    print("| shape H x W | D | status | plan MiB | answer MiB | RSS after, above idle | peak so far, above "
          "idle |")
    print("|---|---|---|---|---|---|---|")
    for row in result["rows"]:
        print(f"| {row['height']} x {row['width']} | {row['disparities']} | {row['status']} | "
              f"{row['plan_mib']} | {row['answer_mib']} | {row['rss_mib']} | {row['peak_mib']} |")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
