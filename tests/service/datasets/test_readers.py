"""Dataset readers on tiny fixtures written in each public layout, and the SPEC parser."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from service.datasets import extensions, open_dataset
from service.datasets.readers import KITTI_MAX_DISPARITY, detect_kind
from service.io import write_disparity
from training.data import photos
from training.data.motorcycle import open_motorcycle
from training.data.synthetic import (
    open_clean_validation_split,
    open_curved_validation_split,
    open_downsampled_validation_split,
    open_fine_validation_split,
    open_validation_split,
)

HEIGHT, WIDTH = 6, 10


def truth() -> np.ndarray:
    disparity = (np.arange(HEIGHT * WIDTH, dtype=np.float32).reshape(HEIGHT, WIDTH) / 4 + 1.25)
    disparity[0, :3] = np.nan
    return disparity


def write_rgb(path: Path, seed: int) -> np.ndarray:
    path.parent.mkdir(parents=True, exist_ok=True)
    pixels = np.random.default_rng(seed).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(path)
    return pixels


def write_mask(path: Path, values: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(values.astype(np.uint8)).save(path)


def occluded_band(disparity: np.ndarray) -> np.ndarray:
    noc = disparity.copy()
    noc[:, 5:7] = np.nan
    return noc


@pytest.mark.parametrize("kind, names", [
    ("kitti2012", ("colored_0", "colored_1", "disp_occ", "disp_noc")),
    ("kitti2015", ("image_2", "image_3", "disp_occ_0", "disp_noc_0")),
])
def test_kitti_reads_frame_10_pairs_with_png16_truth_and_noc_mask(tmp_path, kind, names):
    root = tmp_path / "training"
    left = write_rgb(root / names[0] / "000000_10.png", 1)
    right = write_rgb(root / names[1] / "000000_10.png", 2)
    write_rgb(root / names[0] / "000000_11.png", 3)  # scene-flow frame: no ground truth, not a pair
    write_rgb(root / names[1] / "000000_11.png", 4)
    (root / names[2]).mkdir()
    write_disparity(root / names[2] / "000000_10.png", truth(), "png16")
    (root / names[3]).mkdir()
    write_disparity(root / names[3] / "000000_10.png", occluded_band(truth()), "png16")
    write_rgb(root / names[0] / "000001_10.png", 5)  # no right image and no truth: skipped

    assert detect_kind(tmp_path) == kind
    for spec in (f"{kind}:{tmp_path}", f"{kind}:{root}", str(tmp_path)):
        dataset = open_dataset(spec)
        assert len(dataset) == 1
    pair = dataset[0]
    assert pair.name == "000000_10" and pair.max_disparity == KITTI_MAX_DISPARITY
    np.testing.assert_array_equal(pair.left, left)
    np.testing.assert_array_equal(pair.right, right)
    np.testing.assert_array_equal(np.isnan(pair.disparity), np.isnan(truth()))
    np.testing.assert_allclose(pair.disparity, truth(), atol=1 / 256)
    expected_visible = np.isfinite(occluded_band(truth()))
    np.testing.assert_array_equal(pair.nonoccluded, expected_visible)


def test_middlebury_reads_scene_folders_with_pfm_truth_mask_and_ndisp(tmp_path):
    scene = tmp_path / "trainingQ" / "Adirondack"
    left, right = write_rgb(scene / "im0.png", 1), write_rgb(scene / "im1.png", 2)
    write_disparity(scene / "disp0GT.pfm", truth(), "pfm")
    mask = np.full((HEIGHT, WIDTH), 255)
    mask[:, 5:7], mask[0, :3] = 128, 0  # 128 occluded, 0 no truth (MiddEval3's mask0nocc.png)
    write_mask(scene / "mask0nocc.png", mask)
    (scene / "calib.txt").write_text("cam0=[1 0 1; 0 1 1; 0 0 1]\nndisp=73\nwidth=10\n")
    write_rgb(tmp_path / "testQ" / "Australia" / "im0.png", 3)  # test scene: no truth, skipped
    write_rgb(tmp_path / "testQ" / "Australia" / "im1.png", 4)

    assert detect_kind(tmp_path) == "middlebury"
    dataset = open_dataset(f"middlebury:{tmp_path}")
    assert len(dataset) == 1 and len(open_dataset(str(scene))) == 1
    pair = dataset[0]
    assert pair.name == "Adirondack" and pair.max_disparity == 73
    np.testing.assert_array_equal(pair.left, left)
    np.testing.assert_array_equal(pair.right, right)
    np.testing.assert_allclose(pair.disparity, truth())  # PFM: exact float, inf -> NaN, rows flipped back
    np.testing.assert_array_equal(pair.nonoccluded, mask == 255)


def test_cones_layout_fixture(tmp_path):
    folder = tmp_path / "pair"
    left, right = write_rgb(folder / "left.png", 1), write_rgb(folder / "right.png", 2)
    write_disparity(folder / "disp_left.png", truth(), "png16")
    write_mask(folder / "nonocc_mask.png", np.where(np.isfinite(occluded_band(truth())), 255, 0))
    assert detect_kind(tmp_path) == "cones"
    pair = open_dataset(f"cones:{tmp_path}")[0]
    np.testing.assert_array_equal(pair.left, left)
    np.testing.assert_array_equal(pair.right, right)
    np.testing.assert_allclose(pair.disparity, truth(), atol=1 / 256)
    np.testing.assert_array_equal(pair.nonoccluded, np.isfinite(occluded_band(truth())))


def test_shared_cones_pair_reads_as_documented(cones_dir):
    pair = open_dataset(str(cones_dir))[0]
    assert pair.left.shape == (375, 450, 3) and pair.max_disparity == 64
    known = pair.disparity[np.isfinite(pair.disparity)]
    assert known.min() >= 5 and known.max() <= 56  # the README: 5.5 .. 55 px
    assert 0.7 < pair.nonoccluded.mean() < 1


@pytest.mark.torch
def test_synthetic_spec_is_the_validation_split():
    assert len(open_dataset("synthetic")) == 20
    dataset = open_dataset("synthetic:2")
    assert len(dataset) == 2 and dataset[1].name == "synthetic-1000000001"


@pytest.mark.torch
def test_synthetic_clean_spec_is_the_same_scenes_without_camera_effects():
    noisy, clean = open_dataset("synthetic:2"), open_dataset("synthetic-clean:2")
    assert len(clean) == 2 and clean.name == "synthetic validation without camera effects (2 pairs)"
    for a, b in zip(noisy, clean, strict=True):
        assert a.name == b.name
        np.testing.assert_array_equal(a.disparity, b.disparity)
        assert not np.array_equal(a.left, b.left)
    # Exact renders: a pixel seen by both views has the same colour in each (up to 8-bit rounding of the
    # resampled paint), which no pair with camera effects keeps.
    pair = clean[0]
    y, x = np.nonzero(pair.nonoccluded & np.isfinite(pair.disparity))
    xr = np.rint(x - pair.disparity[y, x]).astype(int)
    exact = np.abs(pair.disparity[y, x] - np.rint(pair.disparity[y, x])) < 0.05
    difference = np.abs(pair.left[y, x].astype(int) - pair.right[y, xr].astype(int))[exact]
    assert difference.mean() < 1


@pytest.mark.torch
def test_lever_specs_are_the_same_scenes_and_cameras_with_the_lever_at_half():
    plain = open_dataset("synthetic:3")
    curved, fine = open_dataset("synthetic-curved:3"), open_dataset("synthetic-fine:3")
    assert curved.name == "synthetic validation with curved surfaces (share 0.5) (3 pairs)"
    assert fine.name == "synthetic validation with fine textures (share 0.5) (3 pairs)"
    domes = 0
    for a, b, c in zip(plain, curved, fine, strict=True):
        assert a.name == b.name == c.name
        # Fine paint leaves the geometry; curved objects move only where they bulge.
        np.testing.assert_array_equal(a.disparity, c.disparity)
        assert not np.array_equal(a.left, c.left)
        changed = np.mean(a.disparity != b.disparity)
        assert changed < 0.5
        domes += changed > 0
    assert domes


@pytest.mark.torch
def test_downsampled_spec_is_the_split_seeds_photographed_at_twice_the_size():
    pairs = open_dataset("synthetic-downsampled:2")
    assert pairs.name == "synthetic validation photographed at 2x and averaged (2 pairs)"
    split = open_dataset("synthetic:2")
    for small, plain in zip(pairs, split, strict=True):
        assert small.name == plain.name and small.left.shape == plain.left.shape
        assert small.max_disparity == plain.max_disparity
        assert 0.8 < np.isfinite(small.disparity).mean() < 1


@pytest.mark.parametrize("kind, module, function", [
    ("synthetic", "training.data.synthetic", open_validation_split),
    ("synthetic-clean", "training.data.synthetic", open_clean_validation_split),
    ("synthetic-curved", "training.data.synthetic", open_curved_validation_split),
    ("synthetic-fine", "training.data.synthetic", open_fine_validation_split),
    ("synthetic-downsampled", "training.data.synthetic", open_downsampled_validation_split),
    ("motorcycle", "training.data.motorcycle", open_motorcycle)])
def test_train_extra_kinds_are_its_entry_points(kind, module, function):
    entry = extensions.registered()[kind]
    assert entry.value == f"{module}:{function.__name__}"
    assert entry.load() is function
    assert kind in extensions.EXTRA_KINDS


@pytest.mark.parametrize("absence", ["no entry point", "no training package", "no scikit-image"])
def test_train_extra_kinds_without_it_name_the_extra_in_one_line(monkeypatch, absence):
    if absence == "no entry point":  # installed without the entry point's metadata
        monkeypatch.setattr(extensions, "registered", lambda: {})
    elif absence == "no training package":  # the serve-only image: the metadata names a module it lacks
        entry = importlib.metadata.EntryPoint(name="synthetic", value="adsm_no_such_module:open",
                                              group=extensions.ENTRY_POINT_GROUP)
        monkeypatch.setattr(extensions, "registered", lambda: {"synthetic": entry, "motorcycle": entry})
    else:  # `pip install '.[serve]'` from a checkout: training is there, scikit-image's photos are not
        no_skimage = SimpleNamespace(util=SimpleNamespace(find_spec=lambda _: None))
        monkeypatch.setattr(photos, "importlib", no_skimage)
    for spec in ("synthetic:2", "motorcycle"):
        with pytest.raises(ValueError) as raised:
            open_dataset(spec)
        message = str(raised.value)
        assert message.startswith(f"dataset {spec!r} needs the train extra (pip install -e '.[train]'): ")
        assert "\n" not in message
        if absence == "no scikit-image":
            assert "scikit-image is not installed" in message


@pytest.mark.parametrize("spec, message", [
    ("", "empty"),
    ("synthetic:zero", "positive"),
    ("synthetic:0", "positive"),
    ("synthetic-clean:-3", "positive pair count, got '-3'"),
    ("synthetic-fine:0", "positive pair count, got '0'"),
    ("synthetic-curved:x", "positive pair count, got 'x'"),
    ("synthetic-downsampled:0", "positive pair count, got '0'"),
    ("motorcycle:2", "takes no argument, got '2'"),
    ("kitti2015:", "needs the dataset folder"),
    ("sceneflow:/data", "expected synthetic"),
    ("/no/such/folder", "expected synthetic"),
])
def test_bad_specs_are_clear_errors(spec, message):
    with pytest.raises(ValueError, match=message):
        open_dataset(spec)


def test_missing_or_empty_folders_are_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        open_dataset(f"kitti2015:{tmp_path / 'missing'}")
    with pytest.raises(ValueError, match="no stereo pairs"):
        open_dataset(f"middlebury:{tmp_path}")
    with pytest.raises(ValueError, match="not a KITTI"):
        open_dataset(str(tmp_path))
