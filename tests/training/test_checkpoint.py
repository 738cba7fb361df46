"""Checkpoints: a full round trip, exact RNG resume, and a loader that refuses anything but plain data."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
import torch

from service.features.defaults import RUNTIME_DEFAULTS
from training.checkpoint import FORMAT, load_checkpoint, save_checkpoint
from training.networks import build_tower_pair

pytestmark = pytest.mark.torch

PROVENANCE = {"command": "python -m training.train --steps 1", "data": "synthetic", "wall_time_s": 1.5,
              "iterations": 1, "device": "cpu"}


def _trained_pair() -> tuple[torch.nn.Module, torch.optim.Optimizer]:
    torch.manual_seed(0)
    pair = build_tower_pair("29-1deconv3-4conv", channels=3, shared=False)
    optimizer = torch.optim.Adam(pair.parameters(), lr=1e-3)
    loss = pair(torch.rand(2, 3, 29, 29), torch.rand(2, 3, 29, 229)).logsumexp(dim=1).mean()
    loss.backward()
    optimizer.step()
    return pair, optimizer


def test_round_trip_restores_model_optimizer_and_records(tmp_path: Path) -> None:
    pair, optimizer = _trained_pair()
    path = save_checkpoint(tmp_path / "run" / "step1.pt", model=pair, optimizer=optimizer, step=1,
                           metrics={"cones": {"bad2": 40.0}}, training=PROVENANCE, config={"lr": 1e-3},
                           deploy={"p1": 20.0, "trained_range": [0, 64]})
    assert not list(path.parent.glob("*.tmp"))
    checkpoint = load_checkpoint(path)
    assert checkpoint.spec == {"config": "29-1deconv3-4conv", "channels": 3, "shared": False,
                               "standardize_window": 0, "adaptive_support": False, "learn_temperature": True}
    assert (checkpoint.step, checkpoint.metrics, checkpoint.training) == (1, {"cones": {"bad2": 40.0}},
                                                                          PROVENANCE)
    assert checkpoint.config == {"lr": 1e-3} and checkpoint.deploy["trained_range"] == [0, 64]
    # What export and validation read: the recorded settings over the one set of runtime defaults.
    settings = checkpoint.deploy_settings()
    assert settings == {**RUNTIME_DEFAULTS.deploy(), "p1": 20.0, "trained_range": [0, 64]}
    assert (settings["p2"], settings["cost_scale"], settings["default_max"]) == (160.0, 128.0, 128)
    assert settings["input"] == {"color": "rgb", "range": [0.0, 1.0], "mean": [0.0] * 3, "std": [1.0] * 3}
    model = checkpoint.build_model()
    assert not model.training
    for name, value in pair.state_dict().items():
        torch.testing.assert_close(model.state_dict()[name], value)
    resumed = torch.optim.Adam(model.parameters(), lr=1e-3)
    resumed.load_state_dict(checkpoint.optimizer)
    assert resumed.state_dict()["state"][1]["step"] == 1


def test_rng_states_resume_the_same_random_streams(tmp_path: Path) -> None:
    pair = build_tower_pair("29-4conv", channels=2)
    generator = np.random.default_rng(7)
    generator.random(3)
    path = save_checkpoint(tmp_path / "c.pt", model=pair, step=0, generators={"data": generator})
    expected = (random.random(), torch.rand(2), generator.random(2))
    checkpoint = load_checkpoint(path)
    fresh = np.random.default_rng(0)
    checkpoint.restore_rng({"data": fresh})
    again = (random.random(), torch.rand(2), fresh.random(2))
    assert expected[0] == again[0]
    torch.testing.assert_close(expected[1], again[1])
    np.testing.assert_array_equal(expected[2], again[2])
    with pytest.raises(ValueError, match="no state for NumPy generator 'other'"):
        checkpoint.restore_rng({"other": fresh})


def test_shared_towers_stay_shared_after_loading(tmp_path: Path) -> None:
    pair = build_tower_pair("29-4conv", channels=2, shared=True, learn_temperature=False)
    model = load_checkpoint(save_checkpoint(tmp_path / "s.pt", model=pair, step=3, rng=False)).build_model()
    assert model.left is model.right and model.spec()["learn_temperature"] is False


def test_loader_refuses_pickled_objects_and_foreign_files(tmp_path: Path) -> None:
    hostile = tmp_path / "hostile.pt"
    torch.save({"format": FORMAT, "payload": Path("/etc/passwd")}, hostile)  # an arbitrary class instance
    with pytest.raises(ValueError, match="not a readable ADSM checkpoint"):
        load_checkpoint(hostile)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(ValueError, match="format None"):
        load_checkpoint(foreign)
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable"):
        load_checkpoint(garbage)
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")


def test_incomplete_provenance_is_refused(tmp_path: Path) -> None:
    pair = build_tower_pair("29-4conv", channels=2)
    with pytest.raises(ValueError, match="lacks data, wall_time_s"):
        save_checkpoint(tmp_path / "x.pt", model=pair, step=1, training={"command": "x", "iterations": 1})
    with pytest.raises(ValueError, match="step"):
        save_checkpoint(tmp_path / "x.pt", model=pair, step=-1)
