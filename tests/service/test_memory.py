"""Issue 15: the memory model of one request (service/memory.py), its enforcement before any allocation in
the service and the CLI, and the bound it gives for every aspect ratio at the default limits."""

from __future__ import annotations

import io
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from PIL import Image

from service.api import Settings, create_app
from service.cli import main
from service.features import default_model_dir, load_manifest
from service.features.manifest import MODELS_DIR
from service.features.scale import MAX_TOWER_SCALE
from service.features.tiles import TOWER_WORK_BYTES, halo_of, tower_plan, work_bytes_per_pixel
from service.memory import memory_bound, plan_request, tower_work_limit
from tests.helpers import InstantMatcher, ready_client

MODELS = sorted(path.parent.name for path in MODELS_DIR.glob("*/manifest.json"))  # every shipped folder
DEFAULTS = Settings()
# Every aspect ratio at the default pixel limit, from one row to one column.
SHAPES = [(1, 2_100_000), (2, 1_050_000), (8, 262_144), (45, 46_666), (375, 1242), (1080, 1920),
          (1449, 1449), (46_666, 45), (2_100_000, 1)]


def _manifest(name: str) -> dict:
    return load_manifest(default_model_dir().parent / name)


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize(("height", "width"), SHAPES)
def test_plan_is_bounded_for_every_aspect_ratio(name, height, width):
    manifest = _manifest(name)
    disparities = min(DEFAULTS.max_cost_cells // (height * width), width, DEFAULTS.max_disparity)
    plan = plan_request(height, width, disparities, manifest)
    # One tower run's work area is capped whatever the shape (thin images were ~45x H x W before).
    assert plan.tower_work <= TOWER_WORK_BYTES
    assert plan.peak_bytes <= memory_bound(manifest, max_pixels=DEFAULTS.max_pixels,
                                           max_cost_cells=DEFAULTS.max_cost_cells)
    # Compact images pass the work limit; one or two rows (45x or 23x the work with a 45 px receptive
    # field) do not, whatever the model.
    work_ok = plan.work_pixels <= tower_work_limit(manifest, max_pixels=DEFAULTS.max_pixels)
    if min(height, width) >= 45:
        assert work_ok, plan.describe()
    if min(height, width) <= 2:
        assert not work_ok, plan.describe()


@pytest.mark.parametrize("scale", [2, MAX_TOWER_SCALE])
@pytest.mark.parametrize(("height", "width"), SHAPES)
def test_plan_at_a_tower_scale_stays_within_the_process_bound(height, width, scale):
    # The upsampled runs are tiled to the same work budget, so memory_bound holds at every scale.
    for name in MODELS:
        manifest = _manifest(name)
        disparities = min(DEFAULTS.max_cost_cells // (height * width), width, DEFAULTS.max_disparity)
        plan = plan_request(height, width, disparities, manifest, scale=scale)
        assert plan.tower_work <= TOWER_WORK_BYTES
        bound = memory_bound(manifest, max_pixels=DEFAULTS.max_pixels, max_cost_cells=DEFAULTS.max_cost_cells)
        assert plan.peak_bytes <= bound, (name, plan.describe())


def test_default_request_limit_admits_every_shipped_model_at_1080p():
    for name in MODELS:
        plan = plan_request(1080, 1920, DEFAULTS.max_cost_cells // (1080 * 1920), _manifest(name))
        assert plan.peak_bytes <= DEFAULTS.max_request_bytes, (name, plan.describe())


def _png(height: int, width: int) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(np.zeros((height, width, 3), np.uint8)).save(buffer, format="PNG")
    return buffer.getvalue()


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"


@pytest.mark.anyio
async def test_memory_limit_is_413_with_the_plan_and_nothing_is_decoded(monkeypatch):
    from service.api import inference as inference_module

    def no_decoding(*args, **kwargs):
        raise AssertionError("decoded before the memory check")

    matcher = InstantMatcher()
    app = create_app(Settings(max_request_bytes=64 * 2**20), matcher=matcher)
    monkeypatch.setattr(inference_module, "read_image", no_decoding)
    pair = {"left": ("l.png", _png(600, 800), "image/png"), "right": ("r.png", _png(600, 800), "image/png")}
    async with ready_client(app) as client:
        response = await client.post("/disparity", params={"max_disparity": 64}, files=pair)
    assert response.status_code == 413, response.text
    detail = response.json()["detail"]
    for fragment in ("ADSM_MAX_REQUEST_BYTES", "tower_work", "volumes", "800 x 600"):
        assert fragment in detail, detail
    assert matcher.calls == 0


def test_cli_refuses_a_pair_over_the_memory_limit_in_one_line(tmp_path, capsys):
    left, right = tmp_path / "l.png", tmp_path / "r.png"
    left.write_bytes(_png(100, 200))
    right.write_bytes(_png(100, 200))
    status = main(["predict", str(left), str(right), "-o", str(tmp_path / "d.png"), "--max-memory-mib", "8"])
    assert status == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("adsm: error: "), err
    assert "limit of 8 MiB per request" in err and "Traceback" not in err
    assert not (tmp_path / "d.png").exists()


@pytest.mark.parametrize(("raw", "ok"), [("1", True), ("256", True), ("257", False), ("100000", False)])
def test_threads_are_bounded(raw, ok):
    if ok:
        assert Settings.from_env({"ADSM_THREADS": raw}).threads == int(raw)
    else:
        with pytest.raises(ValueError, match=r"threads must be in 1\.\.256"):
            Settings.from_env({"ADSM_THREADS": raw})


def test_request_limit_is_a_setting():
    assert Settings.from_env({"ADSM_MAX_REQUEST_BYTES": "1_000_000"}).max_request_bytes == 1_000_000
    with pytest.raises(ValueError, match="max_request_bytes"):
        Settings(max_request_bytes=0)


_MEASURE = textwrap.dedent("""
    import json, sys
    import numpy as np
    from service.features.tiles import tiled_features
    from service.matcher import Matcher, MatchOptions
    height, width, disparities, folder = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    matcher = Matcher.from_folder(folder or None, threads=2)
    matcher.warmup()
    image = np.random.default_rng(0).integers(0, 256, (height, width, 3), dtype=np.uint8)
    rss = int(open("/proc/self/statm").read().split()[1]) * 4096
    # Reset the high-water mark: Numba's compilation in warmup (no cache in a fresh process) peaks far
    # above what a call needs, and ru_maxrss would keep that peak.
    open("/proc/self/clear_refs", "w").write("5")
    towers_only, scale = sys.argv[5] == "towers", int(sys.argv[6])
    if towers_only:
        tiled_features(matcher.towers, image, image, scale=scale)
    else:
        matcher(image, image, MatchOptions(max_disparity=disparities, tower_scale=scale))
    status = open("/proc/self/status").read().split("VmHWM:")[1]
    peak = int(status.split()[0]) * 1024
    print(json.dumps({"growth": peak - rss}))
""")


def _growth(height: int, width: int, disparities: int, folder: str = "", what: str = "match",
            scale: int = 1) -> int:
    out = subprocess.run(
        [sys.executable, "-c", _MEASURE, str(height), str(width), str(disparities), folder, what, str(scale)],
        capture_output=True, text=True, check=True, timeout=600,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])["growth"]


@pytest.mark.slow
@pytest.mark.parametrize(("height", "width"), [(8, 32768), (2, 65536), (32768, 8)])
def test_thin_image_peak_stays_within_its_plan(height, width):
    # Before tiles, 8 x 32768 alone took 1.5 GiB in the towers (8 x 262144: 12.5 GiB in the service).
    plan = plan_request(height, width, 1, load_manifest(default_model_dir()))
    growth = _growth(height, width, 1)
    assert growth <= plan.peak_bytes, (growth / 2**20, plan.describe())


@pytest.mark.slow
@pytest.mark.parametrize(("height", "width", "tiled"), [(200, 600, False), (1080, 1920, True)])
def test_peak_at_tower_scale_two_stays_within_its_plan(height, width, tiled):
    # The upsampled runs (one whole run, or tiles at 1080p) and their outputs are in the plan.
    plan = plan_request(height, width, 64, load_manifest(default_model_dir()), scale=2)
    assert (len(plan.tiles) > 1) == tiled
    growth = _growth(height, width, 64, scale=2)
    assert growth <= plan.peak_bytes, (growth / 2**20, plan.describe())


def _tower_work_cases() -> list[tuple[str, int, int]]:
    # A 64 x 4096 strip (one tile at the budget, or two) for every model, and KITTI size where its towers
    # run in tiles: there adsm-paper-int8's run measured 1433 of its 1536 bytes per padded pixel
    # (thirty-ninth session), the tightest plan of all.
    cases = [(name, 64, 4096) for name in MODELS]
    return cases + [(name, 375, 1242) for name in MODELS if len(tower_plan(375, 1242, _manifest(name))) > 1]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "height", "width"), _tower_work_cases())
def test_tower_work_model_bounds_every_shipped_model(name, height, width):
    # Per run, not per image: above the plan's features (both whole maps, one run's inputs and outputs) the
    # arena grows by at most the model's coefficient times the largest run's padded pixels.
    manifest = _manifest(name)
    plan = plan_request(height, width, 1, manifest)
    growth = _growth(height, width, 1, str(default_model_dir().parent / name), "towers")
    largest = max(tile.padded_pixels(halo_of(manifest)) for tile in plan.tiles)
    assert plan.tower_work == work_bytes_per_pixel(manifest) * largest
    assert growth - plan.features <= plan.tower_work, ((growth - plan.features) / largest, plan.describe())
