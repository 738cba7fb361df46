"""`torchrun --nproc_per_node 2 -m training.train`: two CPU processes on gloo train one model together."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from training.checkpoint import load_checkpoint
from training.networks import build_tower_pair
from training.trainer import BatchSpec, TrainConfig, TrainingData
from training.trainer.objective import Objective


@pytest.mark.slow
def test_two_processes_average_their_losses_and_share_one_model(tmp_path):
    out = tmp_path / "ddp"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
               "-m", "training.train", "--channels", "4", "--crop", "48", "96", "--max-disparity", "24",
               "--batch-size", "2", "--iterations", "2", "--val-every", "2", "--val-pairs", "1",
               "--cones", "", "--threads", "1", "--out", str(out)]
    finished = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert finished.returncode == 0, finished.stderr[-3000:]
    rows = [json.loads(line) for line in (out / "history.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [1, 2]

    # Step 1 from the same initial weights: rank 0 trains on examples 0-1, rank 1 on examples 2-3; the
    # logged loss is their mean, and the logged example count their sum.
    torch.manual_seed(0)
    model = build_tower_pair("37-1deconv5-4conv", channels=4, temperature=TrainConfig().temperature)
    objective = Objective(model, mode="dense")
    data = TrainingData("synthetic", seed=0, spec=BatchSpec(height=48, width=96, max_disparity=24))
    with torch.no_grad():
        per_rank = [objective(*data.crops(indices)) for indices in ([0, 1], [2, 3])]
    assert rows[0]["loss"] == pytest.approx(sum(float(loss) for loss, _ in per_rank) / 2, rel=1e-4)
    assert rows[0]["examples"] == sum(count for _, count in per_rank)
    checkpoint = load_checkpoint(out / "last.pt")
    assert checkpoint.step == 2 and "synthetic-validation" in checkpoint.metrics
