"""Seconds per dense training step on the CPU: the loss's two forms, glibc's allocator as is and kept.

    python -m bench training_step [--config 11-5conv] [--channels 32] [--batch-size 4] [--rounds 3]

One batch of the trainer's own synthetic crops (seed 0, examples 0..B-1, the edge weight 4 of the shipped
recipes), then full steps (both towers, the loss, backward, Adam) of the dense objective in four variants,
each in a fresh process (the allocator setting cannot be undone in one), interleaved round by round:

- *candidates*: each labelled pixel's 201 candidate logits gathered into ``[M, 201]`` tensors
  (``pixel_candidates`` + ``matching_loss``: the trainer's loss until the thirty-third session);
- *banded*: ``pixel_losses``, the same loss as a masked log-sum-exp over the product volume's rows;
- each with glibc's default mmap and trim thresholds, and *kept* (``training.allocator``);
- *both-views*: banded, kept, with eq. (18) from the right view too (``--both-views``: the mirrored
  pair's volume as well).

The trainer uses *banded, kept* (and *both-views* with ``--both-views``). Prints each variant's median
seconds per step over the rounds and its ratio to the first variant; the machine should be otherwise
idle (docs/training.md, "Trainer speed").
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from unittest import mock

from bench import positive_int
from training.allocator import keep_freed_memory

LOSSES = ("candidates", "banded", "both-views")
VARIANTS = (("candidates", False), ("banded", False), ("candidates", True), ("banded", True),
            ("both-views", True))


def step_seconds(*, config: str, channels: int, batch_size: int, steps: int, threads: int, loss: str,
                  kept: bool) -> float:
    """Median seconds of ``steps`` timed steps (after two untimed ones) in this process."""
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    if kept and not keep_freed_memory():
        raise RuntimeError("glibc's mallopt is not available here: the 'kept' variants cannot run")
    import torch

    from training.losses import matching_loss, pixel_candidates
    from training.networks import build_tower_pair
    from training.trainer import objective
    from training.trainer.batches import BatchSpec, TrainingData

    def candidate_losses(features_left, features_right, pixels, truth, *, temperature, shift, shape,
                         vertex_weight=0.0, fractional_shift=None):
        if vertex_weight:
            raise ValueError("the candidates variant times eq. (18) alone (no --subpixel-loss)")
        logits, inside = pixel_candidates(features_left, features_right, pixels, truth,
                                          temperature=temperature)
        return matching_loss(logits, inside, shift=shift, shape=shape, reduction="none")

    torch.set_num_threads(threads)
    torch.manual_seed(0)
    batch = TrainingData("synthetic", seed=0, spec=BatchSpec()).crops(range(batch_size))
    dense = objective.Objective(build_tower_pair(config, channels=channels, shared=True), mode="dense",
                                edge_weight=4.0, both_views=loss == "both-views")
    replaced = candidate_losses if loss == "candidates" else objective.pixel_losses
    with mock.patch.object(objective, "pixel_losses", replaced):
        return _timed_steps(dense, batch, steps=steps)


def _timed_steps(objective, batch, *, steps: int) -> float:  # type: ignore[no-untyped-def]
    import torch

    optimizer = torch.optim.Adam(objective.parameters(), lr=1e-4)
    times = []
    for step in range(steps + 2):
        start = time.perf_counter()
        value, _ = objective(*batch)
        optimizer.zero_grad()
        value.backward()
        optimizer.step()
        if step >= 2:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench training_step", description=__doc__.split("\n")[0])
    parser.add_argument("--config", default="11-5conv")
    parser.add_argument("--channels", type=positive_int, default=32)
    parser.add_argument("--batch-size", type=positive_int, default=4)
    parser.add_argument("--steps", type=positive_int, default=4, help="timed steps per process")
    parser.add_argument("--rounds", type=positive_int, default=3, help="processes per variant, interleaved")
    parser.add_argument("--threads", type=positive_int, default=2)
    parser.add_argument("--child", help=argparse.SUPPRESS)  # LOSS,KEPT: one variant, in this process
    args = parser.parse_args(argv)
    settings = dict(config=args.config, channels=args.channels, batch_size=args.batch_size, steps=args.steps,
                    threads=args.threads)
    if args.child:
        loss, kept = args.child.split(",")
        print(json.dumps(step_seconds(**settings, loss=loss, kept=kept == "kept")))
        return 0
    seconds: dict[tuple[str, bool], list[float]] = {variant: [] for variant in VARIANTS}
    passed = [f"--{key.replace('_', '-')}={value}" for key, value in settings.items()]
    for _ in range(args.rounds):
        for loss, kept in VARIANTS:
            child = [sys.executable, "-m", "bench", "training_step", *passed,
                     f"--child={loss},{'kept' if kept else 'default'}"]
            done = subprocess.run(child, capture_output=True, text=True, check=False)
            if done.returncode:
                raise RuntimeError(f"the {loss} variant failed: {done.stderr.strip().splitlines()[-1:]}")
            seconds[(loss, kept)].append(float(done.stdout.strip().splitlines()[-1]))
    print(f"{args.config}, {args.channels} channels, batch {args.batch_size} of 128 x 256, {args.threads} "
          f"threads; median s per step over {args.rounds} processes x {args.steps} steps")
    first = statistics.median(seconds[VARIANTS[0]])
    for (loss, kept), values in seconds.items():
        median = statistics.median(values)
        allocator = "kept" if kept else "glibc default"
        print(f"  {loss:<11} {allocator:<14} {median:6.3f} s  {first / median:4.2f}x")
    return 0
