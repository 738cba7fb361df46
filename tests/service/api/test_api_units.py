"""Service building blocks without a server: settings from the environment, geometry, format choice,
and `adsm serve` refusing bad input with one line."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.api import Settings
from service.api.routes.encoding import negotiate_format, server_timing
from service.api.routes.geometry import depth_from_disparity, depth_png16, point_cloud_ply
from service.cli import main
from tests.helpers import ROOT


def test_settings_from_env() -> None:
    settings = Settings.from_env({
        "ADSM_MODEL_DIR": "/models/x", "ADSM_THREADS": "3", "ADSM_QUEUE_SIZE": "0",
        "ADSM_MAX_BODY_BYTES": "1_000_000", "ADSM_MAX_PIXELS": "", "ADSM_WARMUP": "off",
        "ADSM_BODY_TIMEOUT_S": "2.5",
    })
    assert settings.model_dir == Path("/models/x") and settings.threads == 3 and settings.queue_size == 0
    assert settings.max_body_bytes == 1_000_000 and settings.max_pixels == Settings().max_pixels
    assert settings.warmup is False and settings.body_timeout_s == 2.5
    assert Settings().body_timeout_s == 30.0


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"ADSM_QUEUE_SIZE": "many"}, "ADSM_QUEUE_SIZE must be an integer"),
        ({"ADSM_WARMUP": "perhaps"}, "ADSM_WARMUP must be true or false"),
        ({"ADSM_MAX_PIXELS": "0"}, "max_pixels must be >= 1"),
        ({"ADSM_QUEUE_SIZE": "-1"}, "queue_size must be >= 0"),
        ({"ADSM_THREADS": "0"}, r"threads must be in 1\.\.256"),
        ({"ADSM_BODY_TIMEOUT_S": "soon"}, "ADSM_BODY_TIMEOUT_S must be a number"),
        ({"ADSM_BODY_TIMEOUT_S": "0"}, "body_timeout_s must be a positive, finite number of seconds"),
        ({"ADSM_BODY_TIMEOUT_S": "-5"}, "body_timeout_s must be a positive, finite number of seconds"),
        ({"ADSM_BODY_TIMEOUT_S": "nan"}, "body_timeout_s must be a positive, finite number of seconds"),
        ({"ADSM_BODY_TIMEOUT_S": "inf"}, "body_timeout_s must be a positive, finite number of seconds"),
    ],
)
def test_settings_reject_bad_values(env: dict[str, str], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Settings.from_env(env)


@pytest.mark.parametrize("value", [0, -0.5, float("nan"), float("inf"), "30", None, True])
def test_body_timeout_must_be_a_positive_finite_number(value: object) -> None:
    with pytest.raises(ValueError, match="body_timeout_s must be a positive, finite number of seconds"):
        Settings(body_timeout_s=value)


def test_depth_is_baseline_times_focal_over_disparity() -> None:
    disparity = np.array([[4.0, 0.0, np.nan, -1.0, 0.001]], np.float32)
    depth = depth_from_disparity(disparity, focal_px=200.0, baseline_m=0.1)
    assert depth[0, 0] == pytest.approx(5.0)
    assert np.isnan(depth[0, 1:4]).all()  # no depth without a positive disparity
    millimetres = np.asarray(Image.open(io.BytesIO(depth_png16(depth))))
    assert millimetres.dtype == np.uint16
    assert millimetres.tolist() == [[5000, 0, 0, 0, 0]]  # 20 km does not fit in uint16 mm: 0, not clipped
    with pytest.raises(ValueError, match="positive"):
        depth_from_disparity(disparity, focal_px=0.0, baseline_m=0.1)


def test_point_cloud_back_projects_with_the_principal_point() -> None:
    depth = np.array([[2.0, np.nan], [4.0, 1.0]], np.float32)
    colours = np.arange(12, dtype=np.uint8).reshape(2, 2, 3)
    body, count = point_cloud_ply(depth, colours, focal_px=2.0, cx=1.0, cy=0.0)
    header, _, data = body.partition(b"end_header\n")
    assert count == 3 and b"element vertex 3\n" in header
    vertices = np.frombuffer(data, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "u1", 3)])
    np.testing.assert_allclose(vertices["x"], [(0 - 1) * 2 / 2, (0 - 1) * 4 / 2, (1 - 1) * 1 / 2])
    np.testing.assert_allclose(vertices["y"], [0.0, 1 * 4 / 2, 1 * 1 / 2])
    np.testing.assert_array_equal(vertices["rgb"], colours.reshape(-1, 3)[[0, 2, 3]])


def test_format_negotiation_and_server_timing() -> None:
    offered = ("png16", "npy", "pfm", "color")
    assert negotiate_format("color", "application/x-npy", offered=offered) == "color"
    assert negotiate_format(None, None, offered=offered) == "png16"
    assert negotiate_format(None, "image/png;q=0.1, application/x-npy;q=0.9", offered=offered) == "npy"
    assert negotiate_format(None, "image/x-portable-floatmap", offered=("npy", "png16")) == "npy"
    assert negotiate_format(None, "application/x-npy;q=0", offered=offered) == "png16"
    assert server_timing({"towers": 0.0125, "sgm": 1.5}) == "towers;dur=12.50, sgm;dur=1500.00"


@pytest.fixture(autouse=True)
def _restore_serve_environment(monkeypatch) -> None:
    # `adsm serve` writes its options into os.environ for its workers; undo that after each test.
    for name in ("ADSM_MODEL_DIR", "ADSM_THREADS", "ADSM_PORT", "ADSM_HOST"):
        monkeypatch.setenv(name, "")


def test_serve_refuses_a_bad_model_folder_in_one_line(tmp_path: Path, capsys) -> None:
    assert main(["serve", "--model", str(tmp_path)]) == 1
    error = capsys.readouterr().err
    assert error.startswith("adsm: error: ") and error.count("\n") == 1


def test_serve_refuses_bad_options(capsys, monkeypatch) -> None:
    assert main(["serve", "--workers", "0"]) == 1
    assert "--workers must be >= 1" in capsys.readouterr().err
    monkeypatch.setenv("ADSM_PORT", "http")
    assert main(["serve"]) == 1
    assert "ADSM_PORT must be an integer" in capsys.readouterr().err
    monkeypatch.setenv("ADSM_PORT", "")
    monkeypatch.setenv("ADSM_BODY_TIMEOUT_S", "nan")
    assert main(["serve"]) == 1
    error = capsys.readouterr().err
    assert error.startswith("adsm: error: body_timeout_s must be a positive") and error.count("\n") == 1


def test_model_manifest_hides_absolute_paths() -> None:
    from service.api.routes.ops import public_manifest

    manifest = {"training": {"command": "python -m training.train --out /home/alice/runs/x --init-from "
                             "runs/fast/best.pt --data kitti2015:/data/kitti/training"},
                "notes": ["C:\\Users\\bob\\m.pt", "~/models/q/", "x - d < 0 -> +scale, 1/4 w/o"],
                "channels": 16}
    public = public_manifest(manifest)
    text = str(public)
    for secret in ("/home/alice", "/data/kitti", "Users\\\\bob", "~/models"):
        assert secret not in text, text
    assert "<path>/x" in text and "runs/fast/best.pt" in text and public["notes"][2] == manifest["notes"][2]
    assert public["channels"] == 16


def test_kubernetes_memory_limit_covers_the_documented_bound() -> None:
    import yaml

    from service.features import default_model_dir, load_manifest
    from service.memory import memory_bound

    deployment = next(yaml.safe_load_all((ROOT / "docker" / "k8s.yaml").read_text()))
    container = deployment["spec"]["template"]["spec"]["containers"][0]
    limit = container["resources"]["limits"]["memory"]
    units = {"Mi": 2**20, "Gi": 2**30}
    limit_bytes = int(limit[:-2]) * units[limit[-2:]]
    env = {item["name"]: item["value"] for item in container["env"]}
    settings = Settings.from_env(env)
    idle = 250 * 2**20  # RSS of the served default model after warm-up (docs/service.md#memory)
    bound = memory_bound(load_manifest(default_model_dir()), max_pixels=settings.max_pixels,
                         max_cost_cells=settings.max_cost_cells)
    assert limit_bytes >= idle + bound, (limit, (idle + bound) / 2**20)


def test_domain_errors_map_to_one_status_each() -> None:
    from service.api.errors import domain_error_response, status_of
    from service.api.queue import ClientDisconnected, QueueFull
    from service.api.refusals import Backlogged, BadRequest, Draining, NotReady
    from service.io import ImageDecodeError, ImageTooLargeError
    from service.limits import DisparityRangeError, LimitError
    from service.matcher import MemoryLimitError

    expected = [(BadRequest("x"), 400), (DisparityRangeError("x"), 400), (LimitError("x"), 413),
                (MemoryLimitError("x"), 413), (ImageTooLargeError("x"), 413), (ImageDecodeError("x"), 415),
                (ClientDisconnected("x"), 499), (QueueFull(7), 503), (NotReady("x"), 503),
                (Draining("x"), 503), (Backlogged("x"), 503)]
    assert [status_of(error) for error, _ in expected] == [status for _, status in expected]
    assert status_of(ValueError("a bug")) is None  # anything unlisted stays a server error
    full = domain_error_response(QueueFull(7))
    assert full.status_code == 503 and full.headers["retry-after"] == "7" and "connection" not in full.headers
    assert full.body == b'{"detail":"the inference queue is full; retry in 7 s"}'
    leaving = domain_error_response(Draining("shutting down"))
    assert leaving.headers["retry-after"] == "5" and leaving.headers["connection"] == "close"
    assert "retry-after" not in domain_error_response(LimitError("too big")).headers


def test_the_service_object_raises_no_http_errors() -> None:
    # The service object and its queue speak in domain errors; only service/api/errors.py knows statuses.
    import service.api.inference
    import service.api.queue
    import service.api.refusals

    for module in (service.api.inference, service.api.queue, service.api.refusals):
        source = Path(module.__file__).read_text(encoding="utf-8")
        assert "HTTPException" not in source and "status_code" not in source, module.__name__
