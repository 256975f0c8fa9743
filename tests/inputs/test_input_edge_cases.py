"""Malformed text inputs that used to pass silently: stamps in the wrong unit, rows with extra fields.

Every file here is written by the test, so the expected values are known exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import InputFormatError
from pipeline.io.asl import read_asl_imu_csv
from pipeline.io.tum import read_tum_poses
from pipeline.types import Severity

HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
          "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
T0_NS = 1403715273262142976
STEP_NS = 5_000_000


def _stamps_ns(n: int) -> np.ndarray:
    return T0_NS + STEP_NS * np.arange(n, dtype=np.int64)


def _write_imu(path: Path, stamps: list[str], extra: dict[int, str] | None = None) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = [f"{s},0.01,-0.02,0.03,0.1,0.2,9.81" + (extra or {}).get(i, "") for i, s in enumerate(stamps)]
    path.write_text(HEADER + "\n" + "\n".join(rows) + "\n")
    return path


def _as_seconds(t_ns: int) -> str:
    return f"{t_ns // 1_000_000_000}.{t_ns % 1_000_000_000:09d}"


def test_float_second_stamps_under_an_ns_header_are_read_exactly(tmp_path: Path) -> None:
    truth = _stamps_ns(400)
    path = _write_imu(tmp_path / "imu0" / "data.csv", [_as_seconds(int(t)) for t in truth])
    imu, findings = read_asl_imu_csv(path)
    np.testing.assert_array_equal(imu.t_ns, truth)  # every digit kept, nothing truncated
    (f,) = [f for f in findings if f.code == "STAMP_UNIT_GUESSED"]
    assert f.severity is Severity.WARNING
    assert f.details["declared"] == "ns" and f.details["unit"] == "s"


def test_stamps_finer_than_a_nanosecond_in_every_unit_are_refused(tmp_path: Path) -> None:
    stamps = [f"{t}.5" for t in _stamps_ns(50)]  # ns with a half-ns fraction: no unit reads it exactly
    path = _write_imu(tmp_path / "imu0" / "data.csv", stamps)
    with pytest.raises(InputFormatError, match="finer than 1 ns") as info:
        read_asl_imu_csv(path)
    assert "data.csv" in str(info.value) and "integer nanoseconds" in str(info.value)


def test_integer_ns_stamps_raise_no_unit_finding(tmp_path: Path) -> None:
    truth = _stamps_ns(50)
    imu, findings = read_asl_imu_csv(_write_imu(tmp_path / "imu0" / "data.csv", [str(t) for t in truth]))
    np.testing.assert_array_equal(imu.t_ns, truth)
    assert not [f for f in findings if f.code == "STAMP_UNIT_GUESSED"]


@pytest.mark.parametrize("extra", [",1.0", ",1.0,2.0"])
def test_a_row_with_too_many_fields_is_skipped_and_named(tmp_path: Path, extra: str) -> None:
    truth = _stamps_ns(300)
    path = _write_imu(tmp_path / "imu0" / "data.csv", [str(t) for t in truth], extra={120: extra})
    imu, findings = read_asl_imu_csv(path)
    (f,) = [f for f in findings if f.code == "PARSE_SKIPPED_LINES"]
    assert f.details["lines"] == [122]  # header is line 1, row 120 (0-based) is line 122
    np.testing.assert_array_equal(imu.t_ns, np.delete(truth, 120))


def test_a_trailing_delimiter_is_not_an_extra_field(tmp_path: Path) -> None:
    truth = _stamps_ns(100)
    path = _write_imu(tmp_path / "imu0" / "data.csv", [str(t) for t in truth], extra={i: "," for i in range(100)})
    imu, findings = read_asl_imu_csv(path)
    assert not [f for f in findings if f.code == "PARSE_SKIPPED_LINES"]
    np.testing.assert_array_equal(imu.t_ns, truth)


def test_tum_row_with_an_extra_field_is_skipped(tmp_path: Path) -> None:
    lines = [f"{_as_seconds(int(t))} 1 2 3 0 0 0 1" for t in _stamps_ns(200)]
    lines[50] += " 7"
    path = tmp_path / "traj.txt"
    path.write_text("\n".join(lines) + "\n")
    poses, findings = read_tum_poses(path)
    (f,) = [f for f in findings if f.code == "PARSE_SKIPPED_LINES"]
    assert f.details["lines"] == [51]
    assert len(poses.t_ns) == 199
