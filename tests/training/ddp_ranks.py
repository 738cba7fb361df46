"""Run under torchrun by tests/training/test_train_ddp.py: ``training.train`` as the CLI runs it, then each
rank saves its final parameters to OUT/rank{RANK}.pt (the CLI writes rank 0's checkpoint only, and the
test must see every rank's weights to know that DDP kept them one model)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import torch

from training.train import main
from training.trainer import loop

built: list[torch.nn.Module] = []
_build = loop.build_tower_pair


def _capture(*args, **kwargs):
    model = _build(*args, **kwargs)
    built.append(model)
    return model


if __name__ == "__main__":
    loop.build_tower_pair = _capture
    argv = sys.argv[1:]
    code = main(argv)
    if code == 0:
        out = Path(argv[argv.index("--out") + 1])
        weights = {name: value.detach().clone() for name, value in built[0].named_parameters()}
        torch.save(weights, out / f"rank{os.environ['RANK']}.pt")
    sys.exit(code)
