"""Choosing the device (``cpu`` / ``cuda``): the setting, its environment variable, the CLI flags and the
error where no GPU is usable. Runs everywhere; the GPU itself is test_kernels.py's and test_pipeline.py's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numba import cuda
from PIL import Image

from bench.__main__ import main as bench_main
from service.api.settings import Settings
from service.cli import build_parser, main
from service.cuda import CudaUnavailableError, check_device
from service.matcher import Matcher


def test_the_device_defaults_to_the_cpu_and_reads_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ADSM_DEVICE", raising=False)
    assert check_device(None) == "cpu"
    monkeypatch.setenv("ADSM_DEVICE", "cuda")
    assert check_device(None) == "cuda"
    assert check_device("cpu") == "cpu"  # an explicit choice wins over the environment


@pytest.mark.parametrize(("device", "environment"), [("gpu", None), (None, "CUDA"), ("", None)])
def test_an_unknown_device_is_refused_naming_its_source(monkeypatch: pytest.MonkeyPatch, device: str | None,
                                                         environment: str | None) -> None:
    if environment is None:
        monkeypatch.delenv("ADSM_DEVICE", raising=False)
    else:
        monkeypatch.setenv("ADSM_DEVICE", environment)
    source = "device" if device is not None else "ADSM_DEVICE"
    with pytest.raises(ValueError, match=f"{source} must be one of cpu, cuda"):
        check_device(device)


def test_the_service_settings_read_adsm_device() -> None:
    assert Settings.from_env({}).device == "cpu"
    assert Settings.from_env({"ADSM_DEVICE": "cuda"}).device == "cuda"
    with pytest.raises(ValueError, match="must be one of cpu, cuda"):
        Settings.from_env({"ADSM_DEVICE": "tpu"})


@pytest.mark.parametrize("command", ["predict", "eval", "serve"])
def test_the_commands_take_a_device_flag(command: str) -> None:
    parser = build_parser()
    extra = {"predict": ["--data", "a.png,b.png"], "eval": ["--data", "cones:x"], "serve": []}[command]
    assert parser.parse_args([command, *extra, "--device", "cuda"]).device == "cuda"
    assert parser.parse_args([command, *extra]).device is None  # None: $ADSM_DEVICE, else the CPU
    with pytest.raises(SystemExit):
        parser.parse_args([command, *extra, "--device", "gpu"])


def test_cuda_without_a_gpu_is_one_clear_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(cuda, "is_available", lambda: False)
    with pytest.raises(CudaUnavailableError, match="none is usable here: run with device 'cpu'"):
        Matcher.from_folder(device="cuda")
    pair = []
    for name in ("left.png", "right.png"):
        Image.fromarray(np.zeros((16, 32, 3), np.uint8)).save(tmp_path / name)
        pair.append(str(tmp_path / name))
    code = main(["predict", *pair, "--output", str(tmp_path / "out.png"), "--device", "cuda"])
    assert code == 1
    assert not (tmp_path / "out.png").exists()
    error = capsys.readouterr().err
    assert error.startswith("adsm: error: device 'cuda' needs an NVIDIA GPU") and "Traceback" not in error
    assert bench_main(["gpu", "--sizes", "cones"]) == 1
    error = capsys.readouterr().err
    assert error.startswith("bench gpu: error: CudaUnavailableError: device 'cuda' needs an NVIDIA GPU")
