"""``python -m training.validate``: a checkpoint measured through the runtime, and its P1/P2 tuned.

The towers run in PyTorch inside the service's Matcher (training/evaluation.py); P1/P2 are gridded on the
synthetic validation split only, never on a real evaluation pair.

    python -m training.validate --checkpoint CKPT [--pairs 20] [--tune] [--cones PATH]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from service.datasets import open_dataset
from service.evaluation.tuning import P1_GRID, P2_GRID
from training.checkpoint import load_checkpoint, update_checkpoint
from training.data.evaluation_only import CONES_NAME, CONES_SPEC
from training.evaluation import runtime_metrics, tune_sgm


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m training.validate", description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", required=True, help="checkpoint to measure (and update with --tune)")
    parser.add_argument("--pairs", type=int, default=20, help="synthetic validation pairs (default 20)")
    parser.add_argument("--tune", action="store_true",
                        help="grid P1/P2 on the synthetic split, store the best in the checkpoint's deploy")
    parser.add_argument("--p1", type=float, nargs="+", default=P1_GRID, help="P1 grid for --tune")
    parser.add_argument("--p2", type=float, nargs="+", default=P2_GRID, help="P2 grid for --tune")
    parser.add_argument("--cones", default=CONES_SPEC, help="evaluation-only real pair SPEC ('' to skip)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    for name, value in (("pairs", args.pairs), ("threads", args.threads)):
        if value < 1:
            print(f"training.validate: error: --{name} must be >= 1, got {value}", file=sys.stderr)
            return 2
    try:
        return _validate(args)
    except (OSError, ValueError, RuntimeError) as error:
        print(f"training.validate: error: {error}", file=sys.stderr)
        return 1


def _validate(args: argparse.Namespace) -> int:
    torch.set_num_threads(args.threads)
    checkpoint = load_checkpoint(args.checkpoint)
    try:
        model = checkpoint.build_model()
    except (KeyError, RuntimeError) as error:
        raise ValueError(f"{args.checkpoint}: its weights do not fit its own spec ({error})") from None
    deploy = checkpoint.deploy_settings()
    synthetic = open_dataset(f"synthetic:{args.pairs}")
    cones = open_dataset(args.cones) if args.cones else None  # a bad SPEC fails before any measurement
    if args.tune:
        best, rows = tune_sgm(model, synthetic, deploy=deploy, p1_grid=args.p1, p2_grid=args.p2, log=print)
        grid = Path(f"{args.checkpoint}.sgm-grid.json")
        grid.write_text(json.dumps(rows, indent=1) + "\n")
        deploy |= best | {"sgm_tuned_on": f"grid P1 {list(args.p1)} x P2 {list(args.p2)}, lowest bad-2 on "
                                           f"the synthetic validation split ({args.pairs} pairs)"}
    metrics = dict(checkpoint.metrics)
    metrics["synthetic-validation"] = runtime_metrics(model, synthetic, deploy=deploy)
    if cones is not None:
        metrics[CONES_NAME] = runtime_metrics(model, cones, deploy=deploy)
    print(json.dumps({"deploy": {k: deploy[k] for k in ("p1", "p2", "cost_scale")}, "metrics": metrics},
                     indent=1))
    if args.tune:
        # Only deploy and metrics change: the optimizer and RNG states stay, so a tuned last.pt still resumes.
        update_checkpoint(args.checkpoint, metrics=metrics, deploy=deploy)
        print(f"updated {args.checkpoint}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
