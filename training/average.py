"""Average the weights of checkpoints of one run (SWA-style: the ends of its cosine phases).

    python -m training.average training/checkpoints/17-8conv-c48-10000/last.pt \
        training/checkpoints/17-8conv-c48-14000/last.pt --out runs/avg/last.pt
    python -m export.to_onnx --checkpoint runs/avg/last.pt --out DIR --int8 --no-measure

Every floating-point tensor of the state dict is averaged, batch-norm running statistics included (an
approximation: the statistics of the averaged weights are not measured again); integer buffers come from
the last checkpoint. Averaging only makes sense for checkpoints of one lineage (each phase warm-started
from the previous one): the towers must share their spec. The output carries the last checkpoint's
deploy settings; its provenance is the command and every source's (``training.averaged_from``). Measured as
an accuracy lever in docs/training.md ("Phase 4 and the averaged phases").
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from training.checkpoint import Checkpoint, load_checkpoint, save_checkpoint


def average_state_dicts(checkpoints: Sequence[Checkpoint]) -> dict[str, torch.Tensor]:
    """The mean of the checkpoints' floating-point tensors (integer buffers: the last one's).

    >>> def checkpoint(weights: list[float]) -> Checkpoint:
    ...     return Checkpoint(spec={"config": "11-5conv"}, state_dict={"w": torch.tensor(weights)}, step=1,
    ...                       metrics={}, training=None, config={}, deploy={})
    >>> a, b = checkpoint([1.0, 2.0]), checkpoint([3.0, 6.0])
    >>> average_state_dicts([a, b])["w"]
    tensor([2., 4.])
    """
    if len(checkpoints) < 2:
        raise ValueError(f"averaging needs at least two checkpoints, got {len(checkpoints)}")
    last = checkpoints[-1]
    for checkpoint in checkpoints[:-1]:
        if checkpoint.spec != last.spec:
            raise ValueError(f"checkpoints of different towers cannot be averaged: {checkpoint.spec} "
                             f"against {last.spec}")
        if checkpoint.state_dict.keys() != last.state_dict.keys():
            raise ValueError("checkpoints with different state-dict keys cannot be averaged")
    averaged = {}
    for key, tensor in last.state_dict.items():
        if tensor.is_floating_point():
            total = sum((c.state_dict[key].double() for c in checkpoints), torch.zeros_like(tensor).double())
            averaged[key] = (total / len(checkpoints)).to(tensor.dtype)
        else:
            averaged[key] = tensor.clone()
    return averaged


def average_checkpoints(paths: Sequence[str | Path], *, out: str | Path, command: str) -> Path:
    """Write the checkpoint whose weights are the mean of ``paths``' (see :func:`average_state_dicts`)."""
    checkpoints = [load_checkpoint(path) for path in paths]
    last = checkpoints[-1]
    model = last.build_model()
    model.load_state_dict(average_state_dicts(checkpoints))
    sources = [_source(path, checkpoint) for path, checkpoint in zip(paths, checkpoints, strict=True)]
    training = {
        "command": command,
        "data": f"none beyond the {len(paths)} averaged checkpoints' (averaged_from)",
        "wall_time_s": 0.0,
        "iterations": last.step,
        "averaged_from": sources,
        "wall_time_total_s": float((last.training or {}).get("wall_time_total_s", 0.0)),
    }
    return save_checkpoint(out, model=model, step=last.step, metrics={}, training=training,
                           config=last.config, deploy=last.deploy, rng=False)


def _source(path: str | Path, checkpoint: Checkpoint) -> dict[str, Any]:
    provenance = checkpoint.training or {}
    kept = ("command", "wall_time_s", "wall_time_total_s")
    return {"checkpoint": str(path), "step": checkpoint.step,
            **{key: provenance[key] for key in kept if key in provenance}}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m training.average", description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+", help="two or more checkpoints of one run, oldest first")
    parser.add_argument("--out", required=True, help="checkpoint to write")
    args = parser.parse_args(argv)
    command = shlex.join(["python", "-m", "training.average", *(argv if argv is not None else sys.argv[1:])])
    try:
        path = average_checkpoints(args.checkpoints, out=args.out, command=command)
    except (OSError, ValueError) as error:
        parser.exit(2, f"error: {error}\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
