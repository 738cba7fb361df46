"""Named tower configurations of the paper (Tables 1, 2 and 7) and the registry that lists them.

A name reads like the paper's row: ``<patch>-<deconvs>-<convs>``, e.g. ``37-1deconv5-4conv`` is the left
patch size 37 with one 5x5 transposed conv and four convs; the project's anisotropic rows name the patch
``<height>x<width>`` (their kernels are taller than wide). Table 1 and 2 rows keep the printed kernel
sizes; rows that cannot be built as printed carry a ``fix`` note (see docs/networks.md). Table 7 gives no
kernel sizes, so they follow :func:`split_kernels`, the rule that reproduces every 3Conv/4Conv row of
Tables 1 and 2 exactly.
"""

from __future__ import annotations

import dataclasses

DEFAULT_CONFIG = "37-1deconv5-4conv"  # the paper's best row (Table 6) and its recommended network


@dataclasses.dataclass(frozen=True, kw_only=True)
class TowerConfig:
    """Geometry of one feature tower: stride-1 transposed convs (no padding), then valid convs.

    Kernels are square unless ``kernel_widths`` gives their widths (the project's anisotropic towers):
    ``deconv_kernels`` and ``conv_kernels`` are then the heights, and ``patch`` the patch's height.
    """

    name: str
    patch: int                    # side (height) of the left training patch; the tower maps it to 1x1
    deconv_kernels: tuple[int, ...]
    conv_kernels: tuple[int, ...]
    deconv_relu: bool             # Table 2: ReLU after a deconv only in 3Deconv&6Conv
    table: str                    # where the row comes from in the paper
    fix: str = ""                 # how a row that is impossible as printed was made buildable
    kernel_widths: tuple[int, ...] = ()  # widths of the deconvs then the convs; () for square kernels

    def __post_init__(self) -> None:
        heights = self.deconv_kernels + self.conv_kernels
        if not self.conv_kernels or min(heights + self.kernel_widths) < 1:
            raise ValueError(f"{self.name}: needs at least one conv and positive kernel sizes")
        if self.kernel_widths and len(self.kernel_widths) != len(heights):
            raise ValueError(f"{self.name}: {len(self.kernel_widths)} kernel widths for "
                             f"{len(heights)} layers")
        if self.output_size(self.patch) != 1:
            raise ValueError(f"{self.name}: a {self.patch}-pixel-high patch maps to "
                             f"{self.output_size(self.patch)} rows, not 1")

    @property
    def kernel_shapes(self) -> tuple[tuple[int, int], ...]:
        """(height, width) of each layer, the deconvs first."""
        heights = self.deconv_kernels + self.conv_kernels
        return tuple(zip(heights, self.kernel_widths or heights, strict=True))

    @property
    def patch_shape(self) -> tuple[int, int]:
        """(height, width) of the left training patch: the input that the valid tower maps to 1x1."""
        deconvs = len(self.deconv_kernels)
        widths = [width for _, width in self.kernel_shapes]
        return self.patch, 1 + sum(k - 1 for k in widths[deconvs:]) - sum(k - 1 for k in widths[:deconvs])

    @property
    def receptive_field_shape(self) -> tuple[int, int]:
        """(height, width) of the input window that one feature depends on when the tower runs on a whole
        image: the patch grown by each deconv's k - 1 on both sides (see :attr:`receptive_field`)."""
        deconvs = self.kernel_shapes[:len(self.deconv_kernels)]
        height, width = self.patch_shape
        return (height + 2 * sum(h - 1 for h, _ in deconvs), width + 2 * sum(w - 1 for _, w in deconvs))

    @property
    def receptive_field(self) -> int:
        """Side of the input square that one feature depends on when the tower runs on a whole image
        (the larger side of :attr:`receptive_field_shape`: the tiles' halo is square).

        Equal to the patch for conv-only towers. A transposed conv (kernel k) pads its input with k - 1
        zeros on each side, so on an isolated patch the outer deconv outputs see zeros, while on an image
        they see the next k - 1 real pixels: the dense field is patch + 2 * sum(k - 1) (45 for
        37-1deconv5-4conv). The output geometry is still set by the patch (P x P -> 1 x 1).
        """
        return max(self.receptive_field_shape)

    def output_size(self, size: int) -> int:
        """Output height for an input height in training ('valid') mode: eq. (11) then eq. (10), s=1, p=0."""
        grown = size + sum(k - 1 for k in self.deconv_kernels)
        return grown - sum(k - 1 for k in self.conv_kernels)

    def conv_weight_count(self, channels: int = 64) -> int:
        """Conv + deconv weights of one tower (no biases, no BN), the count of Tables 4 and 5."""
        (first_h, first_w), *rest = self.kernel_shapes
        return 3 * first_h * first_w * channels + sum(h * w for h, w in rest) * channels * channels


def split_kernels(reduction: int, layers: int) -> tuple[int, ...]:
    """Kernel sizes of ``layers`` valid convs that shrink a side by ``reduction`` pixels.

    The shrink is shared as evenly as possible, larger kernels first. This is the paper's own choice for
    3Conv (13,13,13), 4Conv (10,10,10,10), 1Deconv(5)&4Conv (11,11,11,11) and 1Deconv(3)&4Conv
    (11,11,10,10), and the rule used for the Table 7 rows, whose kernels the paper does not print.
    """
    if layers < 1 or reduction < layers:
        raise ValueError(f"cannot shrink by {reduction} pixels with {layers} convs of kernel >= 2")
    base, extra = divmod(reduction, layers)
    return tuple(base + 1 + (1 if index < extra else 0) for index in range(layers))


def _ruled(patch: int, deconvs: tuple[int, ...], convs: int, table: str = "Table 7") -> TowerConfig:
    """A Table 7 row: kernels from :func:`split_kernels`, no ReLU after a single deconv (as Table 2)."""
    reduction = patch - 1 + sum(k - 1 for k in deconvs)
    deconv_part = f"{len(deconvs)}deconv{deconvs[0]}-" if deconvs else ""
    return TowerConfig(name=f"{patch}-{deconv_part}{convs}conv", patch=patch, deconv_kernels=deconvs,
                       conv_kernels=split_kernels(reduction, convs), deconv_relu=False, table=table)


_PRINTED = (
    # Table 1: convs only, left patch 37 (Table 4 counts).
    TowerConfig(name="37-3conv", patch=37, deconv_kernels=(), conv_kernels=(13, 13, 13),
                deconv_relu=False, table="Table 1"),
    TowerConfig(name="37-4conv", patch=37, deconv_kernels=(), conv_kernels=(10, 10, 10, 10),
                deconv_relu=False, table="Table 1"),
    TowerConfig(name="37-6conv", patch=37, deconv_kernels=(), conv_kernels=(9, 9, 7, 7, 5, 5),
                deconv_relu=False, table="Table 1"),
    TowerConfig(name="37-7conv", patch=37, deconv_kernels=(), conv_kernels=(7, 7, 7, 7, 5, 5, 5),
                deconv_relu=False, table="Table 1"),
    TowerConfig(name="37-9conv", patch=37, deconv_kernels=(), conv_kernels=(5,) * 9, deconv_relu=False,
                table="Table 1", fix="Table 4 prints 721,600 weights, the count of 8 convs (37->5); "
                "the 9 printed 5x5 convs are kept (37->1, 824,000 weights)"),
    TowerConfig(name="37-11conv", patch=37, deconv_kernels=(), conv_kernels=(5,) * 7 + (3,) * 4,
                deconv_relu=False, table="Table 1", fix="Table 4 prints 627,932 weights, not a multiple of "
                "64 so no bias-free 64-channel tower has it; the printed kernels are kept (766,656)"),
    # Table 2: deconvs then convs, left patch 37 (Table 5 counts).
    TowerConfig(name="37-1deconv5-4conv", patch=37, deconv_kernels=(5,), conv_kernels=(11, 11, 11, 11),
                deconv_relu=False, table="Table 2"),
    TowerConfig(name="37-1deconv3-4conv", patch=37, deconv_kernels=(3,), conv_kernels=(11, 11, 10, 10),
                deconv_relu=False, table="Table 2"),
    TowerConfig(name="37-2deconv-6conv", patch=37, deconv_kernels=(3, 5), conv_kernels=(9, 9, 9, 7, 7, 7),
                deconv_relu=False, table="Table 2"),
    TowerConfig(name="37-3deconv-6conv", patch=37, deconv_kernels=(3, 5, 7),
                conv_kernels=(11, 11, 9, 9, 7, 7), deconv_relu=True, table="Table 2",
                fix="printed with 5 convs (9,9,9,7,7: 37->49->13) and a count of 1,902,182 that matches "
                "6 convs 9,9,9,7,7,7 (1,902,272, ending at 7x7); the first two convs grow by the 6 pixels "
                "the Deconv7 adds (11,11,9,9,7,7: 49->1, 2,361,024 weights)"),
)

_TABLE7 = (
    _ruled(29, (), 3), _ruled(29, (), 4), _ruled(29, (), 5), _ruled(29, (), 7),
    _ruled(29, (3,), 4), _ruled(29, (2,), 4),
    _ruled(33, (), 4), _ruled(33, (), 8), _ruled(33, (3,), 4), _ruled(33, (5,), 4),
    _ruled(41, (), 4), _ruled(41, (), 5), _ruled(41, (), 8), _ruled(41, (), 10),
    _ruled(41, (3,), 4), _ruled(41, (5,), 4),
    _ruled(45, (), 4), _ruled(45, (), 5), _ruled(45, (), 8), _ruled(45, (3,), 4),
)

# The project's extension beside the paper's 29-45 px rows: small receptive fields that keep depth edges
# sharp (a 3x3 NCC beats the 37-px towers at Cones' discontinuities: docs/training.md). 9-4conv is
# MC-CNN-fast's geometry (four 3x3 convs); the deconv rows follow the paper's 1Deconv&4Conv pattern.
# 7-5conv and 5-5conv are 11-5conv with its last 3x3 convs made 1x1: the same depth and width, so a
# receptive-field ablation changes nothing else (down to a 3x3 NCC's 5 px of context and less).
# 11-7conv is 11-5conv with two 1x1 convs after it: depth at the same receptive field (docs/training.md,
# "Depth at the 11-px field"). 17-8conv reaches 13-1deconv3-4conv's 17-px field with eight 3x3 convs, as
# MC-CNN-acrt builds its towers: more non-linear layers for fewer weights (docs/training.md, "Eight 3x3
# convs at the 17-px field"); 21-10conv is the same at a 21-px field, at about 13-1deconv3-4conv's work;
# 13-6conv and 15-7conv fill the 3x3 builds' fields between the 11-px and the 17-px tower (docs/training.md,
# "The 3x3 builds between 11 and 17 px").
_SMALL = (
    *(_ruled(patch, deconvs, convs, table="project extension")
      for patch, deconvs, convs in ((9, (), 4), (11, (), 5), (9, (3,), 4), (13, (3,), 4), (13, (), 6),
                                    (15, (), 7), (17, (), 8), (21, (), 10))),
    *(TowerConfig(name=f"{patch}-{len(kernels)}conv", patch=patch, deconv_kernels=(), conv_kernels=kernels,
                  deconv_relu=False, table="project extension")
      for patch, kernels in ((7, (3, 3, 3, 1, 1)), (5, (3, 3, 1, 1, 1)), (11, (3, 3, 3, 3, 3, 1, 1)))),
)

# Foreground fattening runs along the scanline, while averaging the sensor's noise needs pixels, not width:
# a receptive field narrow along x and tall along y keeps 13-1deconv3-4conv's depth, channels and about
# its work (docs/training.md, "An anisotropic tower"). 21x5-1deconv3-4conv sees 25 rows by 9 columns.
_ANISOTROPIC = (
    TowerConfig(name="21x5-1deconv3-4conv", patch=21, deconv_kernels=(3,), conv_kernels=(7, 7, 6, 6),
                kernel_widths=(3, 3, 3, 2, 2), deconv_relu=False, table="project extension"),
)

CONFIGS: dict[str, TowerConfig] = {config.name: config
                                   for config in _PRINTED + _TABLE7 + _SMALL + _ANISOTROPIC}


def list_configs() -> list[str]:
    """Every named configuration, in the paper's table order."""
    return list(CONFIGS)


def get_config(name: str) -> TowerConfig:
    """The configuration called ``name``; a clear error lists the known names."""
    try:
        return CONFIGS[name]
    except KeyError:
        raise ValueError(f"unknown network config {name!r}; known: {', '.join(CONFIGS)}") from None
