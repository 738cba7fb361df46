"""The paper's result tables (3, 6, 7, 8, 9, 10): its printed figures and the network config of each row.

A row with a ``config`` is one the project trains and measures (a name of ``training.networks``); a row
without one (MC-CNN, SGM, Displets ...) is another method, printed with the paper's figures only. Figures
are the 2/3/4/5-pixel errors in %, exactly as printed (bold marks dropped); Tables 9 and 10 add the
runtime in seconds per pair.
"""

from __future__ import annotations

import dataclasses

from training.networks import get_config

THRESHOLDS = (2, 3, 4, 5)


@dataclasses.dataclass(frozen=True)
class Row:
    label: str                                   # the row as the paper names it
    figures: tuple[float, float, float, float]   # paper's 2/3/4/5-pixel error, %
    config: str | None = None                    # network config trained for the row; None: paper only
    runtime_s: float | None = None               # Tables 9, 10: seconds per pair


@dataclasses.dataclass(frozen=True)
class Table:
    number: int
    title: str
    dataset: str          # the KITTI copy the paper measured on: "kitti2015" or "kitti2012"
    measures: str         # what the table compares (docs/reproduce.md)
    rows: tuple[Row, ...]

    @property
    def configs(self) -> list[str]:
        """The configs to train, in the table's order (one run, one Kubernetes index each)."""
        return [row.config for row in self.rows if row.config is not None]

    @property
    def has_runtime(self) -> bool:
        return any(row.runtime_s is not None for row in self.rows)


def _rows(patch: int, entries: list[tuple[str, str, tuple[float, float, float, float]]]) -> list[Row]:
    return [Row(f"{patch}x{patch} {label}", figures, config) for label, config, figures in entries]


OURS = "37-1deconv5-4conv"   # "Ours" in Tables 8-10: the paper's recommended network (section 5)

TABLES: dict[int, Table] = {t.number: t for t in (
    Table(3, "The percentage of missing matching pixels with threshold of 2, 3, 4, 5 in the 2015 KITTI "
          "test set", "kitti2015", "conv-only towers of Table 1, left patch 37", (
              Row("37-3Conv", (12.21, 8.55, 6.95, 6.05), "37-3conv"),
              Row("37-4Conv", (11.11, 8.12, 6.82, 6.01), "37-4conv"),
              Row("37-6Conv", (11.79, 8.73, 8.35, 6.53), "37-6conv"),
              Row("37-7Conv", (11.96, 8.87, 7.53, 6.73), "37-7conv"),
              Row("37-9Conv", (10.86, 8.07, 6.82, 6.07), "37-9conv"),
              Row("37-11Conv", (14.95, 10.36, 8.82, 7.92), "37-11conv"),
          )),
    Table(6, "The results with deconvolution structure and other network for input left patch size 37",
          "kitti2015", "deconvolution towers of Table 2, left patch 37, against MC-CNN and Efficient-Net", (
              Row("37-1Deconv(5)&4Conv", (10.31, 7.60, 6.38, 5.74), "37-1deconv5-4conv"),
              Row("37-1Deconv(3)&4Conv", (10.36, 7.67, 6.49, 5.78), "37-1deconv3-4conv"),
              Row("37-2Deconv&6Conv", (13.63, 10.56, 9.27, 8.53), "37-2deconv-6conv"),
              Row("37-3Deconv&6Conv", (15.65, 12.46, 11.17, 10.45), "37-3deconv-6conv"),
              Row("MC-CNN-acrt[19]", (15.02, 12.99, 12.04, 11.38)),
              Row("MC-CNN-fast[19]", (18.47, 14.96, 13.18, 12.02)),
              Row("Efficient-Net[18]", (11.67, 8.97, 7.62, 6.78)),
          )),
    Table(7, "The percentage of missing matching pixels with threshold of 2, 3, 4, 5 in the 2015 KITTI "
          "test set for input left patch size 29, 33, 41, 45", "kitti2015",
          "patch sizes 29-45 with and without a deconvolution (kernels by split_kernels: docs/networks.md)", (
              *_rows(29, [("3Conv", "29-3conv", (13.49, 10.29, 8.79, 7.92)),
                          ("4Conv", "29-4conv", (12.76, 9.98, 8.63, 7.84)),
                          ("5Conv", "29-5conv", (12.8, 10.1, 8.78, 8.03)),
                          ("7Conv", "29-7conv", (13.21, 10.44, 9.13, 8.36)),
                          ("1Deconv(3)-4Conv", "29-1deconv3-4conv", (12.47, 9.89, 8.71, 8.02)),
                          ("1Deconv(2)-4Conv", "29-1deconv2-4conv", (12.96, 10.28, 9.04, 8.32))]),
              *_rows(33, [("4Conv", "33-4conv", (12.34, 9.59, 8.25, 7.45)),
                          ("8Conv", "33-8conv", (13.11, 10.31, 8.63, 7.84)),
                          ("1Deconv(3)-4Conv", "33-1deconv3-4conv", (12.20, 9.70, 8.55, 7.88)),
                          ("1Deconv(5)-4Conv", "33-1deconv5-4conv", (12.80, 10.20, 9.03, 8.35))]),
              *_rows(41, [("4Conv", "41-4conv", (10.61, 7.69, 6.41, 5.66)),
                          ("5Conv", "41-5conv", (10.39, 7.64, 6.43, 5.69)),
                          ("8Conv", "41-8conv", (11.03, 8.21, 6.96, 6.21)),
                          ("10Conv", "41-10conv", (11.47, 8.51, 7.21, 6.45)),
                          ("1Deconv(3)-4Conv", "41-1deconv3-4conv", (9.94, 7.31, 6.15, 5.47)),
                          ("1Deconv(5)-4Conv", "41-1deconv5-4conv", (10.26, 7.51, 6.29, 5.56))]),
              *_rows(45, [("4Conv", "45-4conv", (10.48, 7.55, 6.24, 5.47)),
                          ("5Conv", "45-5conv", (10.54, 7.69, 6.44, 5.69)),
                          ("8Conv", "45-8conv", (10.78, 7.88, 6.62, 5.85)),
                          ("1Deconv(3)-4Conv", "45-1deconv3-4conv", (9.45, 6.86, 5.72, 5.03))]),
          )),
    Table(8, "The percentage of missing matching pixels with threshold of 2, 3, 4, 5 in the 2012 KITTI "
          "validation set", "kitti2012",
          "the recommended network on KITTI 2012 against MC-CNN and Efficient-Net", (
              Row("MC-CNN-acrt[21]", (16.92, 14.93, 13.98, 13.32)),
              Row("MC-CNN-fast[21]", (19.56, 17.41, 16.31, 15.51)),
              Row("Efficient-Net[15]", (12.86, 10.64, 9.65, 9.03)),
              Row("Ours", (8.42, 7.07, 6.43, 6.02), OURS),
          )),
    Table(9, "Error comparison of disparity with different algorithms (KITTI2012) %", "kitti2012",
          "the whole method (towers + SGM + check + fill) and its runtime against published methods", (
              Row("StereoSLIC[33]", (7.20, 5.11, 4.04, 3.33), runtime_s=2.3),
              Row("PCBP-SS[32]", (6.75, 4.72, 3.75, 3.15), runtime_s=300),
              Row("SPSS[32]", (6.28, 4.41, 3.52, 3.00), runtime_s=2),
              Row("MC-CNN-acrt[19]", (5.45, 3.63, 2.85, 2.39), runtime_s=67),
              Row("Displets v2[34]", (4.46, 3.09, 2.52, 2.17), runtime_s=265),
              Row("Efficient-CNN[18]", (6.51, 4.29, 3.36, 2.82), runtime_s=0.7),
              Row("Ours", (5.62, 4.01, 3.02, 2.65), OURS, runtime_s=2.4),
          )),
    Table(10, "Error comparison of disparity with different algorithms (KITTI2015) %", "kitti2015",
          "the whole method (towers + SGM + check + fill) and its runtime against published methods", (
              Row("Elas[28]", (24.09, 19.21, 17.59, 16.82), runtime_s=0.669),
              Row("SGM[20]", (10.03, 6.93, 5.47, 4.48), runtime_s=1.8),
              Row("SPSS[32]", (7.15, 4.58, 3.46, 2.93), runtime_s=3),
              Row("Efficient-CNN[18]", (6.78, 4.38, 2.56, 2.03), runtime_s=1),
              Row("MC-CNN-fast[19]", (7.53, 4.01, 2.84, 2.33), runtime_s=0.2),
              Row("MC-CNN-slow[19]", (6.38, 3.27, 2.37, 1.97), runtime_s=35),
              Row("Ours", (4.27, 3.85, 2.57, 2.00), OURS, runtime_s=2.5),
          )),
)}


def get_table(number: int) -> Table:
    try:
        return TABLES[number]
    except KeyError:
        raise ValueError(f"no table {number}: the paper's result tables are "
                         f"{', '.join(map(str, TABLES))}") from None


def check_configs() -> None:
    """Every config a table names exists in the zoo (raises ValueError otherwise)."""
    for table in TABLES.values():
        for name in table.configs:
            get_config(name)
