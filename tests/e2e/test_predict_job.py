"""docker/predict-job.yaml (issue 12, item 5): an Indexed Job whose pods run `adsm predict --shard I/N` and
together cover every pair exactly once."""

from __future__ import annotations

import yaml

from service.cli import build_parser
from service.cli.predict.sources import pairs as run_pairs
from tests.helpers import ROOT

JOB = ROOT / "docker" / "predict-job.yaml"


def test_every_index_runs_a_shard_and_the_shards_partition_the_pairs(tmp_path) -> None:
    job = yaml.safe_load(JOB.read_text())
    spec = job["spec"]
    assert job["kind"] == "Job" and spec["completionMode"] == "Indexed"
    container = spec["template"]["spec"]["containers"][0]
    args = container["args"]
    shard = args[args.index("--shard") + 1]
    assert shard.startswith("$(SHARD_INDEX)/")
    count = int(shard.split("/")[1])
    assert spec["completions"] == count and spec["parallelism"] <= count
    index_source = next(item for item in container["env"] if item["name"] == "SHARD_INDEX")
    assert "job-completion-index" in index_source["valueFrom"]["fieldRef"]["fieldPath"]
    assert container["command"][-1] == "adsm" and args[0] == "predict" and "--skip-existing" in args

    rig = tmp_path / "rig"
    for side in ("left", "right"):
        (rig / side).mkdir(parents=True)
        for number in range(11):
            (rig / side / f"{number:06d}.png").write_bytes(b"")
    seen: list[str] = []
    for index in range(count):
        argv = [arg.replace("$(SHARD_INDEX)", str(index)).replace("/data/rig", str(rig)) for arg in args]
        parsed = build_parser().parse_args(argv)
        pairs, batch = run_pairs(parsed)
        assert batch
        seen += [pair.name for pair in pairs]
        again, _ = run_pairs(build_parser().parse_args(argv))
        assert [pair.name for pair in again] == [pair.name for pair in pairs]  # deterministic
    assert sorted(seen) == [f"{number:06d}" for number in range(11)]  # each pair once, none left out
