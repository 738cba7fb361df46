"""Batches prepared ahead of the optimizer by worker processes, in step order.

Generating a synthetic pair costs tens of milliseconds of single-core NumPy; on a GPU the step itself
costs a few. Because a batch is a pure function of the step (``batches``), workers can build steps
``s, s + 1, ...`` in any process and the loop still sees exactly the examples of a single-process run:
resume and DDP are unchanged, and ``workers=0`` builds each batch in the loop's own process.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import torch
from torch.utils.data import DataLoader, Dataset

from training.trainer.batches import TrainingData


class StepBatches(Dataset):
    """Item ``k`` is the batch of step ``first + k`` for process ``rank`` of ``world``."""

    def __init__(self, data: TrainingData, *, mode: str, first: int, end: int, world: int, rank: int,
                 examples_per_step: int) -> None:
        self.data, self.mode, self.first, self.end = data, mode, first, end
        self.world, self.rank, self.examples_per_step = world, rank, examples_per_step

    def __len__(self) -> int:
        return max(0, self.end - self.first)

    def __getitem__(self, index: int) -> tuple[Any, ...]:
        step = self.first + index
        start = (step * self.world + self.rank) * self.examples_per_step
        indices = range(start, start + self.examples_per_step)
        if self.mode == "patch":
            pairs = self.data.patches(indices)
            return pairs.left, pairs.right, pairs.inside
        return self.data.crops(indices)


def step_batches(batches: StepBatches, *, workers: int, device: torch.device) -> Iterator[tuple[Any, ...]]:
    """The batches in step order, on ``device``; ``workers`` processes build them ahead (0: inline)."""
    if workers == 0:
        for index in range(len(batches)):
            yield tuple(t.to(device) for t in batches[index])
        return
    # One thread per worker: NumPy/torch inside each would otherwise oversubscribe the cores.
    loader = DataLoader(batches, batch_size=None, shuffle=False, num_workers=workers, prefetch_factor=4,
                        pin_memory=device.type == "cuda", worker_init_fn=_one_thread)
    for batch in loader:
        yield tuple(t.to(device, non_blocking=True) for t in batch)


def _one_thread(_: int) -> None:
    torch.set_num_threads(1)
