"""python -m training.reproduce: the whole command on a tiny KITTI 2015 fixture (two configs, a few
iterations), the seeded 75/25 split, resume, the table's shape, and the Kubernetes Indexed Job."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from service.datasets import open_dataset
from service.io import write_disparity
from service.matcher import MatchOptions
from tests.helpers import ROOT
from training.reproduce.__main__ import main, selected_index
from training.reproduce.run import Execution, Protocol, training_command
from training.reproduce.split import split_names
from training.reproduce.tables import TABLES, THRESHOLDS, get_table

pytestmark = pytest.mark.torch

PAIRS, HEIGHT, WIDTH = 8, 40, 128
CONFIGS = ["37-1deconv5-4conv", "37-1deconv3-4conv"]
# The committed manifest is this command's output (test_committed_job_is_the_generator_output).
JOB_COMMAND = ["--table", "6", "--data", "kitti2015:/shared/kitti2015", "--out", "/shared/reproduce/table6",
               "--device", "cuda", "--workers", "14"]


def write_kitti2015(root: Path) -> list[str]:
    """KITTI 2015 layout under root/training: textured left views, right views shifted by a per-band
    disparity, png16 truth (disp_occ_0) and a non-occluded map (disp_noc_0) without the left strip."""
    names = []
    for index in range(PAIRS):
        rng = np.random.default_rng(index)
        left = rng.integers(0, 256, (HEIGHT, WIDTH + 16, 3), dtype=np.uint8)
        disparity = np.repeat(3.0 + np.arange(HEIGHT)[:, None] // 10, WIDTH, axis=1).astype(np.float32)
        right = np.empty((HEIGHT, WIDTH, 3), np.uint8)
        for y in range(HEIGHT):
            shift = int(disparity[y, 0])
            right[y] = left[y, 8 - shift : 8 - shift + WIDTH]
        left = left[:, 8 : 8 + WIDTH]
        name = f"{index:06d}_10.png"
        folders = {n: root / "training" / n for n in ("image_2", "image_3", "disp_occ_0", "disp_noc_0")}
        for folder in folders.values():
            folder.mkdir(parents=True, exist_ok=True)
        Image.fromarray(left).save(folders["image_2"] / name)
        Image.fromarray(right).save(folders["image_3"] / name)
        write_disparity(folders["disp_occ_0"] / name, disparity, "png16")
        visible = disparity.copy()
        visible[:, :6] = np.nan
        write_disparity(folders["disp_noc_0"] / name, visible, "png16")
        names.append(name[:-4])
    return names


def test_split_is_a_seeded_75_25_draw():
    names = [f"{i:06d}_10" for i in range(200)]
    train, test = split_names(names, seed=7)
    assert (len(train), len(test)) == (150, 50) and not set(train) & set(test)
    assert sorted(train + test) == names
    assert split_names(list(reversed(names)), seed=7) == (train, test)   # order of discovery is irrelevant
    assert split_names(names, seed=8) != (train, test)


@pytest.mark.slow
def test_whole_command_on_a_kitti_fixture(tmp_path, capsys):
    names = write_kitti2015(tmp_path / "kitti")
    out = tmp_path / "out"
    argv = ["--table", "6", "--data", f"kitti2015:{tmp_path / 'kitti'}", "--out", str(out),
            "--configs", *CONFIGS, "--iterations", "2", "--batch-size", "8", "--channels", "4",
            "--threads", "1", "--split-seed", "3"]
    assert main(argv) == 0
    printed = capsys.readouterr().out

    # The split: 6 / 2 pairs, recorded with its seed, drawn again from it, and the folders hold exactly it.
    split = json.loads((out / "split.json").read_text())
    assert split["seed"] == 3 and split["pairs"] == PAIRS
    assert (split["train"], split["test"]) == split_names(names, seed=3)
    assert (len(split["train"]), len(split["test"])) == (6, 2)
    assert [s.name for s in open_dataset(split["train_spec"])] == split["train"]
    assert [s.name for s in open_dataset(split["test_spec"])] == split["test"]

    # Each config was trained on the training part only, exported to ONNX and measured on the test part.
    for config in CONFIGS:
        result = json.loads((out / "results" / f"{config}.json").read_text())
        assert result["training"]["steps"] == 2 and result["mode"] == "patch"
        assert f"--data kitti2015:{out / 'split' / 'train'}" in result["training"]["command"]
        words = set(result["training"]["command"].split())
        assert {"--mode", "patch", "--label", "paper", "--shared"} <= words
        assert (out / "models" / config / "left.onnx").is_file()
        switches = {k for k, v in result["pipeline"]["options"].items() if isinstance(v, bool)}
        assert {"sgm", "subpixel", "lr_check", "fill"} <= switches
        assert not any(result["network"]["options"][k] for k in switches)
        # The pipeline row runs the runtime's defaults: every step on; output flags (confidence) stay off.
        defaults = {field.name: field.default for field in dataclasses.fields(MatchOptions)}
        assert all(result["pipeline"]["options"][k] == defaults[k] for k in switches)
        assert all(result["pipeline"]["options"][k] for k in switches - {"confidence"})
        assert result["network"]["pairs"] == result["pipeline"]["pairs"] == 2

    # The table: Table 6's rows in the paper's order, 2/3/4/5-pixel errors, ours beside the paper's.
    table = json.loads((out / "table.json").read_text())
    paper = get_table(6)
    assert [row["label"] for row in table["rows"]] == [row.label for row in paper.rows]
    for row, printed_row in zip(table["rows"], paper.rows, strict=True):
        assert tuple(row["paper"].values()) == printed_row.figures
        for section in ("network", "pipeline"):
            if row["config"] in CONFIGS:
                assert all(0.0 <= row[section][f"bad{t}"] <= 100.0 for t in THRESHOLDS)
                assert row[section]["seconds_per_pair"] > 0
            else:
                assert row[section] is None
    markdown = (out / "table.md").read_text()
    assert markdown in printed
    header = "| ConvNet / method | 2-pixel-error | 3-pixel-error | 4-pixel-error | 5-pixel-error |"
    assert markdown.count(header) == 2                       # network alone, full pipeline
    assert markdown.count("| 37-1Deconv(5)&4Conv | ") == 2
    assert "/ 10.31 (" in markdown                           # the paper's figure with the difference

    # Resume: nothing is redone; a second run without --resume is refused; another seed needs another OUT.
    before = (out / "results" / f"{CONFIGS[0]}.json").stat().st_mtime_ns
    assert main([*argv, "--resume"]) == 0
    assert "done earlier" in capsys.readouterr().out
    assert (out / "results" / f"{CONFIGS[0]}.json").stat().st_mtime_ns == before
    assert main(argv) == 2
    assert main([*argv[:-1], "4", "--resume"]) == 1
    assert main(["--table", "6", "--data", f"kitti2015:{tmp_path / 'kitti'}", "--out", str(out),
                 "--split-seed", "3", "--report"]) == 0
    assert capsys.readouterr().out.count("not run / 13.63") == 2   # the two configs not selected


def test_kubernetes_job_has_one_index_per_config(tmp_path, monkeypatch):
    path = tmp_path / "job.yaml"
    assert main([*JOB_COMMAND, "--kubernetes-job", str(path)]) == 0
    job = yaml.safe_load(path.read_text())
    configs = TABLES[6].configs
    assert job["kind"] == "Job" and job["spec"]["completionMode"] == "Indexed"
    assert job["spec"]["completions"] == job["spec"]["parallelism"] == len(configs) == 4
    container = job["spec"]["template"]["spec"]["containers"][0]
    assert container["resources"]["limits"]["nvidia.com/gpu"] == 1
    args = container["args"]
    listed = args[args.index("--configs") + 1 : args.index("--configs") + 1 + len(configs)]
    assert listed == configs
    assert args[args.index("--index") + 1] == "env" and "--resume" in args
    assert args[args.index("--device") + 1] == "cuda"
    for index, config in enumerate(configs):                 # pod i trains config i, and only it
        monkeypatch.setenv("JOB_COMPLETION_INDEX", str(index))
        assert listed[selected_index("env", len(listed))] == config
    assert job["spec"]["template"]["spec"]["volumes"][0]["persistentVolumeClaim"]["claimName"]


def test_committed_job_is_the_generator_output(tmp_path):
    path = tmp_path / "reproduce-job.yaml"
    assert main([*JOB_COMMAND, "--kubernetes-job", str(path)]) == 0
    committed = (ROOT / "docker" / "reproduce-job.yaml").read_text().splitlines()
    assert path.read_text().splitlines()[1:] == committed[1:]   # line 1 names the file it was written to


def test_trainer_commands_follow_the_protocol(tmp_path):
    protocol = Protocol(table=7, data="synthetic")
    local = training_command(protocol, Execution(), "41-1deconv3-4conv", "synthetic", tmp_path)
    assert local[1:3] == ["-m", "training.train"]
    assert local[local.index("--mode") + 1] == "dense" and "--batch-size" not in local   # not a 37 patch
    ddp = training_command(protocol, Execution(launcher="torchrun", nproc_per_node=4), "37-1deconv5-4conv",
                           "synthetic", tmp_path)
    assert ddp[1:6] == ["-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "4"]
    assert ddp[ddp.index("--mode") + 1] == "patch" and ddp[ddp.index("--batch-size") + 1] == "32"
    assert ddp[ddp.index("--iterations") + 1] == "40000" and ddp[ddp.index("--channels") + 1] == "64"
    with pytest.raises(ValueError, match="groups of 4"):
        training_command(protocol, Execution(launcher="torchrun", nproc_per_node=3), "37-4conv", "x",
                         tmp_path)


def test_bad_arguments_are_refused(tmp_path, capsys):
    assert main(["--table", "6", "--data", "synthetic", "--out", str(tmp_path), "--configs", "37-4conv"]) == 2
    assert "not configs of Table 6" in capsys.readouterr().err
    assert main(["--table", "6", "--data", "synthetic", "--out", str(tmp_path), "--iterations", "0"]) == 2
    with pytest.raises(SystemExit):
        main(["--table", "5", "--data", "synthetic", "--out", str(tmp_path)])
