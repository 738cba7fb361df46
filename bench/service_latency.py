"""POST /disparity latency through a real `adsm serve` process: the Cones pair and a 375x1242 pair.

Starts ``python -m service serve`` on a free loopback port (the shipped model unless ``--model``),
waits for /readyz, sends one untimed request per pair, then ``--repeats`` timed ones. Reports the
client-side wall time (upload, queue, inference, encoding, download of the png16 answer) and the
server's own stage split from the Server-Timing header, as medians.

    python -m bench service_latency [--repeats 5] [--threads N] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np

from bench import positive_int
from bench.serving import free_port, multipart, png, wait_ready
from training.data.evaluation_only import CONES_FOLDER


def kitti_size_pair(height: int = 375, width: int = 1242, shift: int = 30) -> tuple[bytes, bytes]:
    """Smoothed random texture seen with a constant disparity: content does not change the work done."""
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (height, width + shift, 3)).astype(np.float32)
    texture = (noise + np.roll(noise, 1, axis=1) + np.roll(noise, 1, axis=0)) / 3.0
    texture = texture.astype(np.uint8)
    return png(np.ascontiguousarray(texture[:, :width])), png(np.ascontiguousarray(texture[:, shift:]))


def _post(url: str, body: bytes, content_type: str) -> tuple[float, dict[str, float]]:
    request = urllib.request.Request(url, data=body, headers={"Content-Type": content_type}, method="POST")
    started = time.perf_counter()
    with urllib.request.urlopen(request, timeout=600) as response:
        response.read()
        timing = response.headers["Server-Timing"]
    elapsed = time.perf_counter() - started
    stages = {}
    for metric in timing.split(","):
        name, _, duration = metric.strip().partition(";dur=")
        stages[name] = float(duration) / 1000.0
    return elapsed, stages


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench service_latency", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--repeats", type=positive_int, default=5)
    parser.add_argument("--threads", type=positive_int,
                        help="ADSM_THREADS for the server (default: all cores)")
    parser.add_argument("--model", help="model folder (default: the shipped model)")
    parser.add_argument("--cones", type=Path, default=CONES_FOLDER, help="folder with left.png and right.png")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)

    pairs = {
        "cones 450x375 D=64": (
            (args.cones / "left.png").read_bytes(), (args.cones / "right.png").read_bytes(), 64
        ),
        "synthetic 1242x375 D=128": (*kitti_size_pair(), 128),
    }
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    env = dict(os.environ, ADSM_QUEUE_SIZE="1")
    if args.threads:
        env["ADSM_THREADS"] = str(args.threads)
    command = [sys.executable, "-m", "service", "serve", "--host", "127.0.0.1", "--port", str(port),
               "--log-level", "warning"]
    if args.model:
        command += ["--model", args.model]
    server = subprocess.Popen(command, env=env)
    results = {}
    try:
        ready_s = wait_ready(base, server)
        print(f"server ready after {ready_s:.1f} s (model load + JIT warm-up)")
        for label, (left, right, disparities) in pairs.items():
            body, content_type = multipart(left, right)
            url = f"{base}/disparity?max_disparity={disparities}&format=png16"
            _post(url, body, content_type)  # untimed: first-call effects
            runs = [_post(url, body, content_type) for _ in range(args.repeats)]
            wall = statistics.median(elapsed for elapsed, _ in runs)
            stages = {name: statistics.median(r[1][name] for r in runs) for name in runs[0][1]}
            results[label] = {"wall_s": wall, "stages_s": stages, "repeats": args.repeats}
            split = ", ".join(f"{name} {seconds * 1000:.0f}" for name, seconds in stages.items())
            print(f"{label:<26} median wall {wall * 1000:7.0f} ms   server ms: {split}")
    finally:
        server.terminate()
        server.wait(timeout=60)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
