"""Synthetic stereo generator speed: milliseconds per pair, and how the time splits across the stages.

    python -m bench synthetic [--size 256 512] [--max-disparity 128] [--pairs 20] [--json OUT]
    python -m bench synthetic --size 128 256 --max-disparity 96 --camera-draws 1 4 8   (training examples)

Pairs use seeds 1..N (seed 0 is generated first and not timed: it loads the photos). Reports the median
and mean wall time per pair, and for the median pair's seed the split: scene drawing + textures, rendering
of both views, camera effects. One process, one thread of NumPy work (the generator is single-threaded).
``--camera-draws`` also times the trainer's dense examples (``TrainingData.crops``, batches of 8 crops of
the whole size, N batches after one untimed) with each number of camera draws per rendered scene: where
generating examples bounds a training run (a GPU's), examples per second is its steps per second.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from bench import positive_int
from training.data.synthetic import SyntheticConfig, apply_camera, generate, random_scene
from training.data.synthetic.scene import render

EXAMPLES_PER_BATCH = 8  # the GPU recipe's batch size (docs/training.md)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench synthetic", description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=positive_int, nargs=2, default=(256, 512), metavar=("H", "W"))
    parser.add_argument("--max-disparity", type=positive_int, default=128)
    parser.add_argument("--pairs", type=positive_int, default=20)
    parser.add_argument("--camera-draws", type=positive_int, nargs="+", metavar="K",
                        help="also time training examples with K camera draws per scene (K divides 8)")
    parser.add_argument("--json", type=Path, metavar="OUT")
    args = parser.parse_args(argv)
    if any(EXAMPLES_PER_BATCH % draws for draws in args.camera_draws or ()):
        parser.error(f"--camera-draws: each K must divide the batch of {EXAMPLES_PER_BATCH} examples")
    config = SyntheticConfig(height=args.size[0], width=args.size[1], max_disparity=args.max_disparity)
    generate(0, config)
    seconds = []
    for seed in range(1, args.pairs + 1):
        started = time.perf_counter()
        generate(seed, config)
        seconds.append(time.perf_counter() - started)
    median_seed = 1 + int(np.argsort(seconds)[len(seconds) // 2])
    stages = _stages(median_seed, config)
    report = {"size": list(args.size), "max_disparity": args.max_disparity, "pairs": args.pairs,
              "ms_per_pair_median": round(1000 * statistics.median(seconds), 1),
              "ms_per_pair_mean": round(1000 * statistics.fmean(seconds), 1),
              "pairs_per_second": round(len(seconds) / sum(seconds), 2),
              "stage_ms_median_pair": stages}
    print(f"synthetic {args.size[0]}x{args.size[1]}, max disparity {args.max_disparity}: "
          f"{report['ms_per_pair_median']} ms per pair (median of {args.pairs}), "
          f"mean {report['ms_per_pair_mean']} ms; stages {stages}")
    if args.camera_draws:
        examples = {draws: _ms_per_example(draws, args) for draws in args.camera_draws}
        report["training_ms_per_example"] = {str(draws): ms for draws, ms in examples.items()}
        for draws, ms in examples.items():
            print(f"training examples, {draws} camera draw(s) per scene: {ms} ms per example "
                  f"({examples[min(examples)] / ms:.2f}x the examples per second of {min(examples)})")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


def _ms_per_example(draws: int, args: argparse.Namespace) -> float:
    """Mean wall time per example of the trainer's dense batches (seed 0, ``args.pairs`` batches)."""
    from training.trainer.batches import BatchSpec, TrainingData  # torch: only for this measurement

    spec = BatchSpec(height=args.size[0], width=args.size[1], max_disparity=args.max_disparity,
                     camera_draws=draws)
    data = TrainingData("synthetic", seed=0, spec=spec)
    data.crops(range(EXAMPLES_PER_BATCH))
    started = time.perf_counter()
    for batch in range(1, args.pairs + 1):
        data.crops(range(batch * EXAMPLES_PER_BATCH, (batch + 1) * EXAMPLES_PER_BATCH))
    return round(1000 * (time.perf_counter() - started) / (args.pairs * EXAMPLES_PER_BATCH), 2)


def _stages(seed: int, config: SyntheticConfig) -> dict[str, float]:
    """Wall time of each stage of ``generate`` for one seed (same calls, timed separately)."""
    rng = np.random.default_rng(seed)
    clock = time.perf_counter()
    layers = random_scene(rng, height=config.height, width=config.width, max_disparity=config.max_disparity,
                          photo_probability=config.photo_probability)
    scene = time.perf_counter()
    rendering = render(layers, height=config.height, width=config.width)
    rendered = time.perf_counter()
    apply_camera(rendering.left, rng, config.photometric)
    apply_camera(rendering.right, rng, config.photometric)
    done = time.perf_counter()
    return {"scene_and_textures": round(1000 * (scene - clock), 1),
            "render": round(1000 * (rendered - scene), 1), "camera": round(1000 * (done - rendered), 1),
            "layers": len(layers)}
