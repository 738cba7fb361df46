"""Load and soak of a real `adsm serve` on loopback: concurrent clients, then RSS over changing shapes.

1. Load: ``--clients`` threads POST /disparity for ``--duration`` seconds (at most ``--max-requests``
   in all). Only 200 and 503 with a Retry-After header are allowed; a client told 503 waits as
   Retry-After says (the contract), capped at ``--max-backoff``. Reports status counts, requests per
   second and p50/p99 latency of the 200s.
2. Soak: ``--warmup`` (the largest size first) then ``--sequential`` requests, one at a time, each
   of a fresh random size up to 199x319 (ONNX Runtime's arena and Numba's buffers see a new shape
   every time). The server's RSS after the warm-up and after the soak must differ by less than
   ``--max-rss-growth`` (5 %). Measured: RSS climbs over the first ~50 requests of new shapes
   (first-use allocations of ONNX Runtime and Numba, allocator high-water marks), then stays flat;
   hence 60 warm-up requests by default.
3. Shutdown: SIGTERM; the server must exit by itself.

Exits 1 when any check fails. The server listens on 127.0.0.1 only.

    python -m bench load [--duration 60] [--clients 8] [--sequential 200] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections import Counter
from email.message import Message
from pathlib import Path

import numpy as np
import psutil

from bench import positive_float, positive_int
from bench.serving import free_port, multipart, png, wait_ready


def textured_pair(rng: np.random.Generator, height: int, width: int, shift: int = 4) -> tuple[bytes, bytes]:
    noise = rng.integers(0, 256, (height, width + shift, 3)).astype(np.float32)
    texture = ((noise + np.roll(noise, 1, axis=0) + np.roll(noise, 1, axis=1)) / 3).astype(np.uint8)
    return png(np.ascontiguousarray(texture[:, :width])), png(np.ascontiguousarray(texture[:, shift:]))


def post(url: str, body: bytes, content_type: str) -> tuple[int, Message, float]:
    """Status, headers and seconds of one POST; HTTP errors are answers too."""
    request = urllib.request.Request(url, data=body, headers={"Content-Type": content_type}, method="POST")
    started = time.perf_counter()
    try:
        with urllib.request.urlopen(request, timeout=120) as response:
            response.read()
            return response.status, response.headers, time.perf_counter() - started
    except urllib.error.HTTPError as error:
        error.read()
        return error.code, error.headers, time.perf_counter() - started


def load(url: str, body: bytes, content_type: str, *, clients: int, duration: float, max_requests: int,
         max_backoff: float) -> dict:
    statuses: Counter[str] = Counter()
    latencies: list[float] = []  # of the 200s
    problems: list[str] = []
    lock = threading.Lock()
    deadline = time.monotonic() + duration

    def client() -> None:
        while time.monotonic() < deadline:
            with lock:
                if sum(statuses.values()) >= max_requests:
                    return
            try:
                status, headers, seconds = post(url, body, content_type)
            except OSError as error:  # refused, reset, timed out: never acceptable
                status, headers, seconds = 0, Message(), 0.0
                with lock:
                    problems.append(f"transport error: {error}")
            retry_after = headers.get("Retry-After")
            with lock:
                statuses[str(status or "transport error")] += 1
                if status == 200:
                    latencies.append(seconds)
                elif status == 503 and not (retry_after and retry_after.isdigit()):
                    problems.append(f"503 without a valid Retry-After ({retry_after!r})")
                elif status not in (200, 503) and status:
                    problems.append(f"status {status}")
            if status == 503 and retry_after and retry_after.isdigit():
                time.sleep(min(float(retry_after), max_backoff, max(0.0, deadline - time.monotonic())))

    started = time.monotonic()
    threads = [threading.Thread(target=client) for _ in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    elapsed = time.monotonic() - started
    ordered = np.sort(np.array(latencies)) if latencies else np.array([np.nan])
    return {
        "clients": clients, "seconds": elapsed, "requests": sum(statuses.values()),
        "statuses": dict(sorted(statuses.items())), "ok_per_s": len(latencies) / elapsed,
        "p50_ms": float(np.percentile(ordered, 50) * 1000),
        "p99_ms": float(np.percentile(ordered, 99) * 1000),
        "max_ms": float(ordered[-1] * 1000), "problems": sorted(set(problems)),
    }


def soak(base: str, process: psutil.Process, *, warmup: int, sequential: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)

    def one(size: tuple[int, int] | None = None) -> tuple[int, int, int]:
        height, width = size or (int(rng.integers(40, 200)), int(rng.integers(64, 320)))
        body, content_type = multipart(*textured_pair(rng, height, width))
        status, _, _ = post(f"{base}/disparity?max_disparity=32", body, content_type)
        return status, height, width

    # The warm-up starts with the largest size: the baseline then includes the high-water mark of the
    # allocators, and any later growth is a leak rather than a first visit to a bigger shape.
    one((199, 319))
    for _ in range(warmup - 1):
        one()
    before = process.memory_info().rss
    peak = before
    statuses: Counter[str] = Counter()
    shapes = set()
    for _ in range(sequential):
        status, height, width = one()
        statuses[str(status)] += 1
        shapes.add((height, width))
        peak = max(peak, process.memory_info().rss)
    after = process.memory_info().rss
    return {
        "warmup": warmup, "requests": sequential, "distinct_shapes": len(shapes),
        "statuses": dict(statuses), "rss_before_mb": before / 2**20, "rss_after_mb": after / 2**20,
        "rss_peak_mb": peak / 2**20, "rss_growth_pct": 100.0 * (after - before) / before,
    }


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench load", description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=positive_float, default=60.0, help="seconds of concurrent load")
    parser.add_argument("--clients", type=positive_int, default=8)
    parser.add_argument("--max-requests", type=positive_int, default=20_000,
                        help="cap on load requests in all")
    parser.add_argument("--max-backoff", type=positive_float, default=2.0,
                        help="cap on a client's Retry-After wait")
    parser.add_argument("--size", default="64x96", help="HxW of the load pair")
    parser.add_argument("--warmup", type=int, default=60, help="soak requests before the RSS baseline")
    parser.add_argument("--sequential", type=positive_int, default=200, help="soak requests measured")
    parser.add_argument("--max-rss-growth", type=positive_float, default=5.0, help="percent")
    parser.add_argument("--threads", type=positive_int,
                        help="ADSM_THREADS for the server (default: all cores)")
    parser.add_argument("--model", help="model folder (default: the shipped model)")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    height, width = (int(side) for side in args.size.lower().split("x"))

    port = free_port()
    base = f"http://127.0.0.1:{port}"
    env = dict(os.environ)
    if args.threads:
        env["ADSM_THREADS"] = str(args.threads)
    command = [sys.executable, "-m", "service", "serve", "--host", "127.0.0.1", "--port", str(port),
               "--log-level", "warning"] + (["--model", args.model] if args.model else [])
    server = subprocess.Popen(command, env=env)
    report: dict = {}
    try:
        report["ready_s"] = wait_ready(base, server)
        process = psutil.Process(server.pid)
        report["rss_ready_mb"] = process.memory_info().rss / 2**20
        body, content_type = multipart(*textured_pair(np.random.default_rng(0), height, width))
        url = f"{base}/disparity?max_disparity=32"
        report["load"] = load(url, body, content_type, clients=args.clients, duration=args.duration,
                              max_requests=args.max_requests, max_backoff=args.max_backoff)
        report["soak"] = soak(base, process, warmup=args.warmup, sequential=args.sequential, seed=1)
    finally:
        stopping = time.monotonic()
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(timeout=60)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        report["shutdown"] = {"exit_code": server.returncode, "seconds": time.monotonic() - stopping}

    failures = list(report.get("load", {}).get("problems", []))
    if "soak" in report:
        if set(report["soak"]["statuses"]) != {"200"}:
            failures.append(f"soak statuses {report['soak']['statuses']}")
        if report["soak"]["rss_growth_pct"] >= args.max_rss_growth:
            growth = report["soak"]["rss_growth_pct"]
            failures.append(f"RSS grew {growth:.1f} % (limit {args.max_rss_growth} %)")
    if report["shutdown"]["exit_code"] not in (0, -signal.SIGTERM):
        failures.append(f"exit code {report['shutdown']['exit_code']} after SIGTERM")
    report["failures"] = failures
    _print(report)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2), encoding="utf-8")
    return 1 if failures else 0


def _print(report: dict) -> None:
    print(f"server ready after {report.get('ready_s', float('nan')):.1f} s, "
          f"RSS {report.get('rss_ready_mb', float('nan')):.0f} MB")
    if "load" in report:
        load = report["load"]
        print(f"load: {load['clients']} clients x {load['seconds']:.1f} s: {load['requests']} requests, "
              f"statuses {load['statuses']}, {load['ok_per_s']:.1f} ok/s, "
              f"p50 {load['p50_ms']:.0f} ms, p99 {load['p99_ms']:.0f} ms, max {load['max_ms']:.0f} ms")
    if "soak" in report:
        soak = report["soak"]
        print(f"soak: {soak['requests']} sequential requests ({soak['distinct_shapes']} shapes) after "
              f"{soak['warmup']} warm-up: statuses {soak['statuses']}, RSS {soak['rss_before_mb']:.1f} -> "
              f"{soak['rss_after_mb']:.1f} MB ({soak['rss_growth_pct']:+.2f} %), "
              f"peak {soak['rss_peak_mb']:.1f} MB")
    shutdown = report["shutdown"]
    print(f"SIGTERM: exit code {shutdown['exit_code']} after {shutdown['seconds']:.1f} s")
    print("failures: " + ("; ".join(report["failures"]) if report["failures"] else "none"))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
