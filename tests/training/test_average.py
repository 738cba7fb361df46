"""Weight averaging: the mean of one run's checkpoints, refused across different towers."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from training.average import average_checkpoints, average_state_dicts, main
from training.checkpoint import load_checkpoint, save_checkpoint
from training.networks import build_tower_pair

pytestmark = pytest.mark.torch

PROVENANCE = {"command": "python -m training.train --iterations 1", "data": "synthetic", "wall_time_s": 2.0,
              "iterations": 1, "device": "cpu", "wall_time_total_s": 5.0}


def _checkpoint(path: Path, *, seed: int, step: int, channels: int = 3) -> Path:
    torch.manual_seed(seed)
    pair = build_tower_pair("11-5conv", channels=channels, shared=True)
    pair.train()
    pair(torch.rand(2, 3, 11, 11), torch.rand(2, 3, 11, 40))  # moves the batch-norm running statistics
    return save_checkpoint(path, model=pair, step=step, training=PROVENANCE, deploy={"p1": 45.0, "p2": 540.0})


def test_average_is_the_elementwise_mean_of_float_tensors(tmp_path: Path) -> None:
    a = load_checkpoint(_checkpoint(tmp_path / "a.pt", seed=1, step=10))
    b = load_checkpoint(_checkpoint(tmp_path / "b.pt", seed=2, step=20))
    averaged = average_state_dicts([a, b])
    floats = [key for key, tensor in a.state_dict.items() if tensor.is_floating_point()]
    assert any("running_var" in key for key in floats)
    assert any(not torch.equal(a.state_dict[key], b.state_dict[key]) for key in floats)
    for key in floats:
        torch.testing.assert_close(averaged[key], (a.state_dict[key] + b.state_dict[key]) / 2)
    for key, tensor in b.state_dict.items():
        if not tensor.is_floating_point():
            assert torch.equal(averaged[key], tensor)


def test_written_checkpoint_runs_and_records_its_sources(tmp_path: Path) -> None:
    paths = [_checkpoint(tmp_path / f"{n}.pt", seed=n, step=10 * n) for n in (1, 2, 3)]
    out = average_checkpoints(paths, out=tmp_path / "avg" / "last.pt",
                              command="python -m training.average ...")
    checkpoint = load_checkpoint(out)
    assert checkpoint.step == 30 and checkpoint.deploy == {"p1": 45.0, "p2": 540.0}
    assert checkpoint.training["command"] == "python -m training.average ..."
    assert [source["step"] for source in checkpoint.training["averaged_from"]] == [10, 20, 30]
    assert checkpoint.training["wall_time_total_s"] == 5.0 and "device" not in checkpoint.training
    features = checkpoint.build_model().left(torch.rand(1, 3, 16, 24))
    assert torch.isfinite(features).all()


def test_refuses_one_checkpoint_and_different_towers(tmp_path: Path) -> None:
    a = _checkpoint(tmp_path / "a.pt", seed=1, step=1)
    wider = _checkpoint(tmp_path / "w.pt", seed=1, step=1, channels=4)
    with pytest.raises(ValueError, match="at least two"):
        average_checkpoints([a], out=tmp_path / "o.pt", command="c")
    with pytest.raises(ValueError, match="different towers"):
        average_checkpoints([a, wider], out=tmp_path / "o.pt", command="c")


def test_cli_reports_errors_without_a_traceback(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = _checkpoint(tmp_path / "a.pt", seed=1, step=1)
    with pytest.raises(SystemExit) as exit_:
        main([str(a), str(tmp_path / "missing.pt"), "--out", str(tmp_path / "o.pt")])
    assert exit_.value.code == 2 and "error:" in capsys.readouterr().err
    assert main([str(a), str(a), "--out", str(tmp_path / "o.pt")]) == 0
