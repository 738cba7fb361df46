"""The network zoo: weight counts of Tables 4 and 5, patch geometry, layer structure, dense inference."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from training.networks import (
    CONFIGS,
    FeatureTower,
    TowerConfig,
    build_tower_pair,
    dense_features,
    get_config,
    list_configs,
    split_kernels,
)
from training.trainer.objective import Objective

pytestmark = pytest.mark.torch

# Tables 4 and 5 of the paper: conv weights of one 64-channel tower (the rows that are buildable as printed).
PAPER_COUNTS = {
    "37-3conv": 1_416_896,
    "37-4conv": 1_248_000,
    "37-6conv": 953_536,
    "37-7conv": 918_720,
    "37-1deconv5-4conv": 1_987_264,
    "37-1deconv3-4conv": 1_812_160,
    "37-2deconv-6conv": 1_701_568,
}
TABLE7 = {
    29: ["3conv", "4conv", "5conv", "7conv", "1deconv3-4conv", "1deconv2-4conv"],
    33: ["4conv", "8conv", "1deconv3-4conv", "1deconv5-4conv"],
    41: ["4conv", "5conv", "8conv", "10conv", "1deconv3-4conv", "1deconv5-4conv"],
    45: ["4conv", "5conv", "8conv", "1deconv3-4conv"],
}


@pytest.mark.parametrize(("name", "count"), PAPER_COUNTS.items())
def test_conv_weight_counts_match_tables_4_and_5(name: str, count: int) -> None:
    tower = FeatureTower(get_config(name), channels=64)
    assert tower.conv_weight_count() == count
    assert get_config(name).conv_weight_count(64) == count


def test_every_table_row_is_a_named_config() -> None:
    names = set(list_configs())
    table1_2 = {"37-3conv", "37-4conv", "37-6conv", "37-7conv", "37-9conv", "37-11conv", "37-1deconv5-4conv",
                "37-1deconv3-4conv", "37-2deconv-6conv", "37-3deconv-6conv"}
    table7 = {f"{patch}-{row}" for patch, rows in TABLE7.items() for row in rows}
    extension = {name for name, config in CONFIGS.items() if config.table == "project extension"}
    assert extension == {"9-4conv", "11-5conv", "9-1deconv3-4conv", "13-1deconv3-4conv", "7-5conv", "5-5conv",
                         "11-7conv", "13-6conv", "15-7conv", "17-8conv", "21-10conv", "21x5-1deconv3-4conv"}
    # The receptive-field ablation rows differ from 11-5conv in their field only.
    for name, field in (("11-5conv", 11), ("7-5conv", 7), ("5-5conv", 5)):
        assert get_config(name).receptive_field == field and len(get_config(name).conv_kernels) == 5
    # The depth row is 11-5conv with two 1x1 convs after it.
    assert get_config("11-7conv").conv_kernels == (*get_config("11-5conv").conv_kernels, 1, 1)
    # The 3x3 row reaches the default tower's field with eight layers and fewer weights.
    deep, default = get_config("17-8conv"), get_config("13-1deconv3-4conv")
    assert deep.conv_kernels == (3,) * 8 and deep.receptive_field == default.receptive_field == 17
    assert deep.conv_weight_count(32) < default.conv_weight_count(32)
    # The other 3x3 builds: one more conv, two more pixels of field.
    for name, convs in (("11-5conv", 5), ("13-6conv", 6), ("15-7conv", 7), ("21-10conv", 10)):
        config = get_config(name)
        assert config.conv_kernels == (3,) * convs and config.receptive_field == 2 * convs + 1
    assert table1_2 | table7 | extension == names and not (table1_2 | table7) & extension


def test_impossible_rows_carry_a_documented_fix() -> None:
    fixed = {name for name, config in CONFIGS.items() if config.fix}
    assert fixed == {"37-9conv", "37-11conv", "37-3deconv-6conv"}
    # 9Conv's printed count is that of eight 5x5 convs, which is exactly the 33-8conv tower.
    assert get_config("33-8conv").conv_weight_count(64) == 721_600
    # 3Deconv&6Conv: the printed kernels (9,9,9,7,7) leave 13x13; the fix reaches 1x1.
    assert get_config("37-3deconv-6conv").conv_kernels == (11, 11, 9, 9, 7, 7)


@pytest.mark.parametrize("name", list(CONFIGS))
def test_patch_maps_to_one_pixel_and_strip_to_201_candidates(name: str) -> None:
    config = get_config(name)
    tower = FeatureTower(config, channels=2).eval()
    height, width = config.patch_shape
    with torch.no_grad():
        assert tower(torch.rand(1, 3, height, width)).shape == (1, 2, 1, 1)
        assert tower(torch.rand(1, 3, height, width + 200)).shape == (1, 2, 1, 201)


def test_paper_kernel_rule_reproduces_the_printed_even_split_rows() -> None:
    assert split_kernels(36, 3) == (13, 13, 13)
    assert split_kernels(36, 4) == (10, 10, 10, 10)
    assert split_kernels(40, 4) == (11, 11, 11, 11)  # 1Deconv(5)&4Conv: 37 + 4
    assert split_kernels(38, 4) == (11, 11, 10, 10)  # 1Deconv(3)&4Conv: 37 + 2
    assert get_config("41-1deconv3-4conv").conv_kernels == (12, 12, 11, 11)
    with pytest.raises(ValueError, match="cannot shrink"):
        split_kernels(3, 4)


def _layer_kinds(tower: FeatureTower) -> list[str]:
    names = {nn.Conv2d: "conv", nn.ConvTranspose2d: "deconv", nn.BatchNorm2d: "bn", nn.ReLU: "relu"}
    return [names[type(m)] for m in tower.layers]


def test_layer_structure_follows_table_2() -> None:
    assert _layer_kinds(FeatureTower(get_config("37-1deconv5-4conv"), channels=4)) == [
        "deconv", "bn", "conv", "bn", "relu", "conv", "bn", "relu", "conv", "bn", "relu", "conv"]
    kinds = _layer_kinds(FeatureTower(get_config("37-3deconv-6conv"), channels=4))
    assert kinds[:3] == ["deconv", "bn", "relu"] and kinds[-1] == "conv"
    tower = FeatureTower(get_config("37-4conv"), channels=4)
    assert all(m.bias is None for m in tower.modules() if isinstance(m, nn.Conv2d | nn.ConvTranspose2d))


def test_features_are_unit_vectors() -> None:
    tower = FeatureTower(get_config("29-4conv"), channels=5).eval()
    with torch.no_grad():
        features = tower(torch.rand(2, 3, 35, 40))
    torch.testing.assert_close(features.norm(dim=1), torch.ones(2, 7, 12))


def test_shared_and_separate_towers() -> None:
    shared = build_tower_pair("29-4conv", channels=3, shared=True)
    separate = build_tower_pair("29-4conv", channels=3, shared=False)
    assert shared.left is shared.right
    assert separate.left is not separate.right
    assert sum(p.numel() for p in shared.parameters()) < sum(p.numel() for p in separate.parameters())


def test_pair_logits_are_temperature_times_cosine() -> None:
    torch.manual_seed(0)
    pair = build_tower_pair("29-1deconv3-4conv", channels=4, temperature=7.0).eval()
    left, right = torch.rand(3, 3, 29, 29), torch.rand(3, 3, 29, 229)
    with torch.no_grad():
        logits = pair(left, right)
        expected = 7.0 * (pair.left(left) * pair.right(right)).sum(dim=1)[:, 0, :]
    assert logits.shape == (3, 201)
    torch.testing.assert_close(logits, expected)
    assert isinstance(pair.log_temperature, nn.Parameter)
    fixed = build_tower_pair("29-4conv", channels=2, learn_temperature=False)
    assert not any(p is fixed.log_temperature for p in fixed.parameters())
    with pytest.raises(ValueError, match="left patch"):
        pair(left, torch.rand(3, 3, 31, 229))


@pytest.mark.parametrize(("name", "field"), [("29-4conv", 29), ("29-1deconv2-4conv", 31),
                                             ("37-1deconv5-4conv", 45), ("37-2deconv-6conv", 49)])
def test_dense_features_keep_size_and_equal_the_valid_tower_on_the_receptive_field(name: str,
                                                                                     field: int) -> None:
    torch.manual_seed(1)
    tower = FeatureTower(get_config(name), channels=3).eval()
    assert tower.receptive_field == field
    image = torch.rand(1, 3, 60, 67)
    y, x, r = 30, 33, field // 2  # an interior pixel: its receptive field lies inside the image
    with torch.no_grad():
        dense = dense_features(tower, image)
        assert dense.shape == (1, 3, 60, 67)
        around = tower(image[:, :, y - r:y + r + 1, x - r:x + r + 1])
        centre = around.shape[-1] // 2
        torch.testing.assert_close(dense[:, :, y, x], around[:, :, centre, centre])
        if field > tower.patch:  # a deconv sees zeros around an isolated patch, real pixels in an image
            p = tower.patch // 2
            alone = tower(image[:, :, y - p:y + p + 1, x - p:x + p + 1])[:, :, 0, 0]
            assert (alone - dense[:, :, y, x]).abs().max() > 1e-4


def test_an_anisotropic_tower_sees_a_tall_narrow_window() -> None:
    config = get_config("21x5-1deconv3-4conv")
    assert config.kernel_shapes == ((3, 3), (7, 3), (7, 3), (6, 2), (6, 2))
    assert config.patch_shape == (21, 5) and config.receptive_field_shape == (25, 9)
    assert config.receptive_field == 25  # the square halo the service's tiles need
    assert config.conv_weight_count(32) == 3 * 9 * 32 + (21 + 21 + 12 + 12) * 32 * 32
    # One changed pixel moves the dense features of exactly the 25 x 9 window around it.
    torch.manual_seed(0)
    tower = FeatureTower(config, channels=3).eval()
    image = torch.rand(1, 3, 41, 31)
    changed = image.clone()
    changed[0, :, 20, 15] += 1
    with torch.no_grad():
        moved = (dense_features(tower, changed) - dense_features(tower, image)).abs().amax(dim=1)[0] > 0
    rows, columns = torch.nonzero(moved, as_tuple=True)
    assert (rows.min(), rows.max(), columns.min(), columns.max()) == (8, 32, 11, 19)
    with pytest.raises(ValueError, match="smaller than the 21x5 patch"):
        tower(torch.rand(1, 3, 21, 4))
    with pytest.raises(ValueError, match="patch mode cuts square patches"):
        Objective(build_tower_pair(config.name, channels=2), mode="patch")
    with pytest.raises(ValueError, match="3 kernel widths for 2 layers"):
        TowerConfig(name="x", patch=5, deconv_kernels=(), conv_kernels=(3, 3), kernel_widths=(3, 3, 3),
                    deconv_relu=False, table="test")


def test_bad_names_and_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match=r"unknown network config 'nope'.*37-1deconv5-4conv"):
        get_config("nope")
    tower = FeatureTower(get_config("29-4conv"), channels=2)
    with pytest.raises(ValueError, match="smaller than the 29x29 patch"):
        tower(torch.rand(1, 3, 20, 40))
    with pytest.raises(ValueError, match=r"\[N, 3, H, W\]"):
        tower(torch.rand(1, 1, 40, 40))
    with pytest.raises(ValueError, match="channels"):
        FeatureTower(get_config("29-4conv"), channels=0)
