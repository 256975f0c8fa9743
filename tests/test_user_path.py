"""What a newcomer types: options with typos, comparison files from other tools, README commands."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from interpolation.bias import BIAS_COLUMNS, STD_COLUMNS
from pipeline.errors import ConfigError, InputFormatError
from pipeline.io import PoseInput
from validation.validate import read_bias_file

T0_NS = 1_400_000_000_000_000_000


def _bias_csv(path: Path, columns: list[str], rows: int = 5) -> np.ndarray:
    t = T0_NS + np.arange(rows, dtype=np.int64) * 50_000_000
    values = np.arange(rows * (len(columns) - 1), dtype=float).reshape(rows, -1) / 100
    lines = [",".join(columns)] + [",".join([str(ti)] + [repr(float(x)) for x in r]) for ti, r in zip(t, values)]
    path.write_text("\n".join(lines) + "\n")
    return values


def test_comparison_bias_without_std_columns_reads_with_zero_sigma(tmp_path: Path) -> None:
    values = _bias_csv(tmp_path / "constant.csv", ["t_ns", *BIAS_COLUMNS])
    track = read_bias_file(tmp_path / "constant.csv")
    np.testing.assert_array_equal(track.bias, values)
    assert track.std.shape == values.shape and np.all(track.std == 0)


def test_bias_with_some_std_columns_missing_is_refused(tmp_path: Path) -> None:
    _bias_csv(tmp_path / "partial.csv", ["t_ns", *BIAS_COLUMNS, *STD_COLUMNS[:3]])
    with pytest.raises(InputFormatError, match="missing columns ba_x_std"):
        read_bias_file(tmp_path / "partial.csv")


def test_misspelt_pose_kind_names_the_allowed_kinds(tmp_path: Path) -> None:
    gt = tmp_path / "gt.txt"
    gt.write_text("1.0 0 0 0 0 0 0 1\n")
    with pytest.raises(ConfigError) as info:
        PoseInput.coerce(f"{gt}:groundtruth")
    message = str(info.value)
    assert "groundtruth" in message and "ground_truth" in message and "mocap" in message
    assert PoseInput.coerce(f"{gt}:ground_truth").kind.value == "ground_truth"
    assert PoseInput.coerce(str(gt)).path == str(gt)
