"""Learned vs fixed softmax temperature for L2-normalised towers: patch accuracy after a short training.

    python -m bench temperature [--config 29-1deconv3-4conv] [--channels 8] [--steps 300]
                                [--initial 10] [--fixed 3 10 30]

The towers end in an L2 normalisation, so the paper's logits (eq. 16-18) become temperature x cosine.
This trains the same small tower from the same seed with the temperature learned (from each
--initial) and with each fixed value, on 37x237-style patch pairs (eq. 19 soft labels) cut from the
project's synthetic stereo pairs, and reports the held-out share of patches whose argmax is within
1 px of the truth. It is the measurement behind ``TowerPair``'s default (docs/networks.md); not a
test, it takes minutes.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from bench import positive_int
from training.data.synthetic import SyntheticConfig, generate
from training.networks import build_tower_pair
from training.networks.pair import INITIAL_TEMPERATURE

CANDIDATES = 201                    # the paper's right strip: 200 px wider than the patch
LABEL = {0: 0.5, 1: 0.2, 2: 0.05}   # eq. (19)


def patch_pairs(seeds: range, count: int, patch: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
    """``count`` (left patch, right strip) pairs with the true match at the strip's centre candidate."""
    half, reach = patch // 2, (CANDIDATES - 1) // 2
    config = SyntheticConfig(height=128, width=2 * (reach + half) + 160, max_disparity=64)
    lefts, rights = [], []
    samples = [generate(seed, config) for seed in seeds]
    while len(lefts) < count:
        sample = samples[int(rng.integers(len(samples)))]
        y = int(rng.integers(half, config.height - half))
        x = int(rng.integers(reach + half + 64, config.width - reach - half))
        if not np.isfinite(sample.disparity[y, x]) or not sample.nonoccluded[y, x]:
            continue
        q = x - round(float(sample.disparity[y, x]))
        lefts.append(sample.left[y - half:y + half + 1, x - half:x + half + 1])
        rights.append(sample.right[y - half:y + half + 1, q - reach - half:q + reach + half + 1])
    to_tensor = lambda views: torch.from_numpy(np.stack(views)).permute(0, 3, 1, 2).float() / 255.0  # noqa: E731
    return to_tensor(lefts), to_tensor(rights)


def soft_labels(batch: int) -> torch.Tensor:
    labels = torch.zeros(batch, CANDIDATES)
    centre = CANDIDATES // 2
    for offset, weight in LABEL.items():
        labels[:, centre - offset] = weight
        labels[:, centre + offset] = weight
    return labels


def train(config: str, channels: int, steps: int, fixed: float | None, data: tuple[torch.Tensor, ...],
          *, initial: float = INITIAL_TEMPERATURE, batch: int = 64) -> tuple[float, float]:
    """Held-out 1-px accuracy and the final temperature of one run (learned from ``initial`` if not fixed)."""
    torch.manual_seed(0)
    pair = build_tower_pair(config, channels=channels, temperature=fixed or initial,
                            learn_temperature=fixed is None)
    optimizer = torch.optim.Adam(pair.parameters(), lr=1e-3)
    train_left, train_right, test_left, test_right = data
    labels = soft_labels(batch)
    generator = torch.Generator().manual_seed(1)
    for _ in range(steps):
        index = torch.randint(len(train_left), (batch,), generator=generator)
        logits = pair(train_left[index], train_right[index])
        loss = -(labels * torch.log_softmax(logits, dim=1)).sum(dim=1).mean()  # eq. (18)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    pair.eval()
    with torch.no_grad():
        winners = pair(test_left, test_right).argmax(dim=1)
    return float(((winners - CANDIDATES // 2).abs() <= 1).float().mean()), pair.temperature


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench temperature", description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="29-1deconv3-4conv")
    parser.add_argument("--channels", type=positive_int, default=8)
    parser.add_argument("--steps", type=positive_int, default=300)
    parser.add_argument("--fixed", type=float, nargs="*", default=[3.0, 10.0, 30.0])
    parser.add_argument("--initial", type=float, nargs="+", default=[INITIAL_TEMPERATURE],
                        help="starting values of the learned temperature (default: %(default)s)")
    args = parser.parse_args(argv)
    patch = build_tower_pair(args.config, channels=1).patch
    rng = np.random.default_rng(0)
    data = (*patch_pairs(range(0, 24), 4096, patch, rng), *patch_pairs(range(500, 506), 1024, patch, rng))
    print(f"{args.config}, {args.channels} channels, {args.steps} steps of 64 patch pairs (synthetic)")
    runs = [(None, initial) for initial in args.initial] + [(fixed, fixed) for fixed in args.fixed]
    for fixed, initial in runs:
        started = time.perf_counter()
        accuracy, temperature = train(args.config, args.channels, args.steps, fixed, data, initial=initial)
        label = f"learned from {initial:g}" if fixed is None else f"fixed {fixed:g}"
        print(f"  {label:<17} held-out 1-px accuracy {accuracy:.3f}  temperature {temperature:.2f}  "
              f"({time.perf_counter() - started:.0f} s)", flush=True)
    return 0
