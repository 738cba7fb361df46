"""Train the per-pixel NCC share of a trained model folder (training.networks.gate), on its frozen features.

    python -m training.gate --learned service/models/adsm-rf11 --edge-weight 4 --out runs/gate/rf11
    python -m export.hybrid --learned service/models/adsm-rf11 --gate runs/gate/rf11/gate.json --out DIR

Only the gate's 1x1 conv learns (training/trainer/gate.py): minutes on a CPU, the folder is not
retrained. OUT/gate.json is the gate at the last step (the schedule's end) with its provenance and its
validations (synthetic split, the folder's penalties, through the runtime); OUT/validation.jsonl the
validations as they come.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from service.features.manifest import ModelError
from training.trainer.gate import GateRun, train_gate


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m training.gate", description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--learned", type=Path, required=True, metavar="DIR", help="a trained model folder")
    parser.add_argument("--window", type=int, default=3, help="the NCC window (odd; default 3)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--lr", type=float, default=5e-3, help="peak Adam learning rate (cosine schedule)")
    parser.add_argument("--edge-weight", type=float, default=0.0, metavar="W",
                        help="pixels within 3 px of a depth edge weigh 1 + W in the loss (default 0)")
    parser.add_argument("--seed", type=int, default=41, help="0..99: picks the training crops")
    parser.add_argument("--crop", type=int, nargs=2, default=(128, 256), metavar=("H", "W"))
    parser.add_argument("--max-disparity", type=int, default=96, help="synthetic scenes' nearest disparity")
    parser.add_argument("--val-every", type=int, default=250)
    parser.add_argument("--val-pairs", type=int, default=20, help="synthetic validation pairs")
    parser.add_argument("--threads", type=int, default=1, help="torch and ONNX Runtime threads")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    command = shlex.join(["python", "-m", "training.gate", *(sys.argv[1:] if argv is None else argv)])
    run = GateRun(**{key: tuple(value) if key == "crop" else value for key, value in vars(args).items()})
    try:
        result = train_gate(run, command=command)
    except (OSError, ValueError, ModelError) as error:
        print(f"training.gate: error: {error}", file=sys.stderr)
        return 1
    path = run.out / "gate.json"
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
