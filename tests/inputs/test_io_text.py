"""TUM trajectories, generic CSV with a column mapping, exact stamp parsing and unit guessing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import ConfigError, DataError, InputFormatError
from pipeline.io import CsvMapping, TimeUnit, detect_format, load_sequence, read_csv_generic, read_tum
from pipeline.io._stamps import decimal_to_ns, guess_time_unit, stamp_resolution_ns
from pipeline.io.csv_generic import AccUnit, GyroUnit, QuatOrder
from pipeline.types import STANDARD_GRAVITY_MPS2
from pipeline.io.tum import format_stamps_s, write_tum
from pipeline.types import PoseSeries, PoseSourceKind, Severity

# --------------------------------------------------------------------------------------------------
# exact stamps


def test_decimal_to_ns_is_exact() -> None:
    t, sci = decimal_to_ns(["1.40363657975856E+018", "1.40363676385356e18", " 1403636579758555392 "], TimeUnit.NS)
    assert t.tolist() == [1403636579758560000, 1403636763853560000, 1403636579758555392] and sci
    t, sci = decimal_to_ns(["1403715274.302142976", "1403715274.30214", "-0.000000001", "12", "0.5"], TimeUnit.S)
    assert t.tolist() == [1403715274302142976, 1403715274302140000, -1, 12_000_000_000, 500_000_000] and not sci
    # float64 would lose this one (TUM-VI's first stamp, in seconds): it gives ...360
    assert int(float("1520530308.189679351") * 1e9) != 1520530308189679351
    assert decimal_to_ns(["1520530308.189679351"], TimeUnit.S)[0].tolist() == [1520530308189679351]
    t, _ = decimal_to_ns(["1.5", "2.25", "3"], TimeUnit.MS)
    assert t.tolist() == [1_500_000, 2_250_000, 3_000_000]
    t, _ = decimal_to_ns(["0.0000000015", "0.0000000025", "1.0000000000000000001"], TimeUnit.S)
    assert t.tolist() == [2, 2, 1_000_000_000]  # sub-ns digits: round half to even
    t, _ = decimal_to_ns(["1403715273262142976"], TimeUnit.NS)
    assert t.tolist() == [1403715273262142976]
    with pytest.raises(ValueError):
        decimal_to_ns(["1e30"], TimeUnit.S)
    with pytest.raises(ValueError):
        decimal_to_ns(["99999999999"], TimeUnit.S)


def test_stamp_resolution() -> None:
    assert stamp_resolution_ns(np.array([1403715523912140000, 1403715523917140000])) == 10_000
    assert stamp_resolution_ns(np.array([1403715273262142976, 1403715273267142912])) == 1
    assert stamp_resolution_ns(np.array([5_000_000_000, 6_000_000_000])) == 1_000_000_000
    assert stamp_resolution_ns(np.array([1000])) == 1  # one stamp says nothing


@pytest.mark.parametrize(("t_raw", "unit"), [
    (1.4e9 + np.arange(10) * 0.005, TimeUnit.S),  # epoch seconds
    (1.4e12 + np.arange(10) * 5.0, TimeUnit.MS),
    (1.4e15 + np.arange(10) * 5000.0, TimeUnit.US),
    (1.4e18 + np.arange(10) * 5e6, TimeUnit.NS),
    (np.arange(10) * 0.01 + 0.0298, TimeUnit.S),  # relative seconds at 100 Hz (imu_tk)
    (46534.48 + np.arange(10) * 1.0, TimeUnit.S),  # relative seconds at 1 Hz (KITTI GPS)
    (np.arange(10) * 5.0, TimeUnit.MS),  # relative integer ms at 200 Hz
    (np.arange(10) * 5000.0, TimeUnit.US),
    (np.arange(10) * 5e6, TimeUnit.NS),
])
def test_guess_time_unit(t_raw: np.ndarray, unit: TimeUnit) -> None:
    assert guess_time_unit(np.asarray(t_raw, dtype=float)) is unit


# --------------------------------------------------------------------------------------------------
# TUM


TUM_FILES = {
    "euroc/V1_01_easy/ov_data/V1_01_easy_original.txt": (28712, 1403715274302140000, 1403715417857140000),
    "euroc/MH_01_easy/ov_data/MH_01_easy.txt": (36382, 1403636580838560000, 1403636762743560000),
    "euroc/MH_02_easy/ov_data/MH_02_easy.txt": (29993, 1403636859536670000, 1403637009496670000),
    "euroc/MH_03_medium/ov_data/MH_03_medium.txt": (26302, 1403637132888320000, 1403637264393320000),
}


@pytest.mark.parametrize("rel", sorted(TUM_FILES))
def test_read_tum_real(shared_data: Path, rel: str) -> None:
    rows, first, last = TUM_FILES[rel]
    path = shared_data / rel
    assert detect_format(path) == "tum"
    seq = load_sequence(path)
    assert seq.name == path.stem and list(seq.poses) == [path.stem]
    poses = seq.poses[path.stem]
    assert len(poses) == rows
    assert poses.t_ns[0] == first and poses.t_ns[-1] == last
    assert poses.source_kind is PoseSourceKind.VIO and poses.frame == "imu"
    assert poses.rate_hz == pytest.approx(200.0, rel=1e-3)
    assert [f.code for f in seq.findings] == ["STAMP_PRECISION_LOSS"]  # 5 decimals: 10 us
    assert seq.findings[0].details == {"resolution_ns": 10000, "reason": "rounded", "file": str(path)}


def test_read_tum_quaternion_order(shared_data: Path) -> None:
    seq = read_tum(shared_data / "euroc/V1_01_easy/ov_data/V1_01_easy_original.txt",
                   source_kind=PoseSourceKind.GROUND_TRUTH, frame="body", name="v101")
    poses = seq.poses["V1_01_easy_original"]
    assert seq.name == "v101" and poses.frame == "body" and poses.source_kind is PoseSourceKind.GROUND_TRUTH
    # file: t x y z qx qy qz qw = ... 0.878612 2.142470 0.947262 -0.828459 -0.058956 -0.553641 0.060514
    np.testing.assert_array_equal(poses.p_m[0], [0.878612, 2.142470, 0.947262])
    np.testing.assert_array_equal(poses.quat_wxyz[0], [0.060514, -0.828459, -0.058956, -0.553641])


def _random_poses(n: int = 500, seed: int = 1) -> PoseSeries:
    rng = np.random.default_rng(seed)
    t = 1_403_715_273_262_142_976 + np.cumsum(rng.integers(1, 10_000_000, n))
    p = rng.normal(size=(n, 3)) * rng.choice([1e-9, 1.0, 1e4], size=(n, 3))
    q = rng.normal(size=(n, 4))
    return PoseSeries(t, p, q / np.linalg.norm(q, axis=1, keepdims=True), "imu", PoseSourceKind.VIO)


def test_write_read_tum_round_trip_exact(tmp_path: Path) -> None:
    poses = _random_poses()
    out = write_tum(tmp_path / "traj.txt", poses)
    lines = out.read_text().splitlines()
    assert lines[0].startswith("#") and len(lines) == len(poses) + 1
    first = lines[1].split()
    assert len(first) == 8 and first[0] == format_stamps_s(poses.t_ns[:1])[0]
    assert len(first[0].split(".")[1]) == 9
    back = read_tum(out).poses["traj"]
    np.testing.assert_array_equal(back.t_ns, poses.t_ns)
    np.testing.assert_array_equal(back.p_m, poses.p_m)
    np.testing.assert_array_equal(back.quat_wxyz, poses.quat_wxyz)
    assert not list(tmp_path.glob(".traj*"))  # no temporary left behind


def test_write_tum_real_round_trip(shared_data: Path, tmp_path: Path) -> None:
    seq = read_tum(shared_data / "euroc/MH_01_easy/ov_data/MH_01_easy.txt")
    poses = seq.poses["MH_01_easy"]
    back = read_tum(write_tum(tmp_path / "mh.txt", poses)).poses["mh"]
    np.testing.assert_array_equal(back.t_ns, poses.t_ns)
    np.testing.assert_array_equal(back.p_m, poses.p_m)
    np.testing.assert_array_equal(back.quat_wxyz, poses.quat_wxyz)


def test_format_stamps_s() -> None:
    assert format_stamps_s(np.array([1403715274302142976, 5, -1500000000])).tolist() == [
        "1403715274.302142976", "0.000000005", "-1.500000000"]


def test_write_tum_position_only_is_an_error(tmp_path: Path) -> None:
    poses = PoseSeries(np.arange(3), np.zeros((3, 3)), None, "leica_prism", PoseSourceKind.POSITION_TRACKER)
    with pytest.raises(DataError, match="position only"):
        write_tum(tmp_path / "x.txt", poses)
    assert not (tmp_path / "x.txt").exists()


def test_tum_junk_and_comments(tmp_path: Path) -> None:
    body = [f"{1.0 + i * 0.01:.2f} 1 2 3 0 0 0 1" for i in range(40)]
    body.insert(5, "# a comment in the middle")
    body.insert(12, "oops")
    body.insert(20, "1.5 1 2 3")
    path = tmp_path / "t.tum"
    path.write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(body) + "\n\n")
    seq = read_tum(path)
    assert len(seq.poses["t"]) == 40
    skipped = [f for f in seq.findings if f.code == "PARSE_SKIPPED_LINES"][0]
    assert skipped.stream == "poses/t" and skipped.details["lines"] == [14, 22] and skipped.details["count"] == 2


@pytest.mark.parametrize(("content", "pattern", "line"), [
    ("", "empty", None),
    ("# timestamp tx ty tz qx qy qz qw\n", "no data lines", None),
    ("1 2 3 4 5 6 7\n2 3 4 5 6 7 8\n", "has 7 fields, expected 8", 1),
    ("1 2 3 4 5 6 7 8\nx y z\n1 1 1\n3 4 5 6 7 8 9 1\n", "2 of 4 data lines", 2),
])
def test_tum_malformed(tmp_path: Path, content: str, pattern: str, line: int | None) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(InputFormatError, match=pattern) as exc:
        read_tum(path)
    assert "bad.txt" in str(exc.value)
    assert exc.value.line == line


def test_tum_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match="does not exist") as exc:
        read_tum(tmp_path / "nope.txt")
    assert "nope.txt" in str(exc.value)


# --------------------------------------------------------------------------------------------------
# generic CSV


def test_csv_mapping_from_dict_validates() -> None:
    m = CsvMapping.from_dict({"time_column": 0, "time_unit": "S", "gyro_columns": [1, 2, 3],
                              "acc_columns": ["ax", "ay", "az"], "gyro_unit": "deg/s", "acc_unit": "g",
                              "delimiter": ";"})
    assert m.time_unit is TimeUnit.S and m.gyro_unit is GyroUnit.DEGPS and m.acc_unit is AccUnit.G
    assert m.has_imu and not m.has_poses and m.gyro_columns == (1, 2, 3)
    assert CsvMapping.from_dict(m.to_dict()) == m
    with pytest.raises(ConfigError, match="gyro_colums"):
        CsvMapping.from_dict({"gyro_colums": [1, 2, 3]})
    with pytest.raises(ConfigError, match="time_unit"):
        CsvMapping.from_dict({"time_unit": "fortnight", "position_columns": [1, 2, 3]})
    with pytest.raises(ConfigError, match="quat_columns"):
        CsvMapping.from_dict({"position_columns": [1, 2, 3], "quat_columns": [4, 5, 6]})
    with pytest.raises(ConfigError, match="acc_columns"):
        CsvMapping.from_dict({"gyro_columns": [1, 2, 3]})
    with pytest.raises(ConfigError, match="no data"):
        CsvMapping.from_dict({"time_column": 0})
    with pytest.raises(ConfigError, match="quat_order"):
        CsvMapping.from_dict({"position_columns": [1, 2, 3], "quat_columns": [4, 5, 6, 7], "quat_order": "zyxw"})


def test_csv_mapping_from_file(tmp_path: Path) -> None:
    path = tmp_path / "map.yaml"
    path.write_text("time_column: t\nposition_columns: [x, y, z]\nbogus: 1\n")
    with pytest.raises(ConfigError) as exc:
        CsvMapping.from_file(path)
    assert "map.yaml" in str(exc.value) and "bogus" in str(exc.value)
    path.write_text("time_column: t\nposition_columns: [x, y, z]\n")
    assert CsvMapping.from_file(path).position_columns == ("x", "y", "z")


def test_csv_imu_units_and_order(tmp_path: Path) -> None:
    path = tmp_path / "imu.csv"
    rows = [f"{1000 + 10 * i};{i};0;180;1;0;0;x{i}" for i in range(5)]
    path.write_text("stamp_ms;gx;gy;gz;ax;ay;az;label\n" + "\n".join(rows) + "\n")
    mapping = {"time_column": "STAMP_MS", "time_unit": "ms", "gyro_columns": ["gx", "gy", "gz"],
               "acc_columns": [4, 5, 6], "gyro_unit": "degps", "acc_unit": "g", "delimiter": ";"}
    seq = read_csv_generic(path, mapping, name="x")
    assert seq.name == "x" and seq.poses == {}
    np.testing.assert_array_equal(seq.imu.t_ns, [1_000_000_000 + 10_000_000 * i for i in range(5)])
    np.testing.assert_allclose(seq.imu.gyro_radps[:, 2], np.pi)
    np.testing.assert_allclose(seq.imu.gyro_radps[:, 0], np.deg2rad(np.arange(5)))
    np.testing.assert_array_equal(seq.imu.acc_mps2[:, 0], STANDARD_GRAVITY_MPS2)
    assert [f.code for f in seq.findings] == ["STAMP_PRECISION_LOSS"]  # whole 10 ms
    assert seq.findings[0].details["resolution_ns"] == 10_000_000


def test_csv_pose_xyzw_and_unit_guess(tmp_path: Path) -> None:
    path = tmp_path / "poses.txt"
    path.write_text("".join(f"{0.05 * i:.2f}\t1\t2\t3\t0.1\t0.2\t0.3\t0.9\n" for i in range(20)))
    mapping = CsvMapping(time_column=0, position_columns=(1, 2, 3), quat_columns=(4, 5, 6, 7),
                         quat_order=QuatOrder.XYZW, delimiter="\t")
    seq = read_csv_generic(path, mapping, source_kind=PoseSourceKind.VIO)
    poses = seq.poses["poses"]
    assert poses.source_kind is PoseSourceKind.VIO
    np.testing.assert_array_equal(poses.quat_wxyz[0], [0.9, 0.1, 0.2, 0.3])
    np.testing.assert_array_equal(poses.t_ns[:3], [0, 50_000_000, 100_000_000])
    guessed = [f for f in seq.findings if f.code == "STAMP_UNIT_GUESSED"][0]
    assert guessed.severity is Severity.INFO and guessed.details["unit"] == "s"
    assert guessed.stream == "poses/poses"


def test_csv_errors(tmp_path: Path) -> None:
    path = tmp_path / "g.csv"
    path.write_text("t,x,y,z\n0,1,2,3\n")
    with pytest.raises(InputFormatError) as exc:
        read_csv_generic(path, {"time_column": "t", "position_columns": ["x", "y", "w"]})
    assert "g.csv" in str(exc.value) and "'w'" in str(exc.value) and "position_columns" in str(exc.value)
    with pytest.raises(InputFormatError, match="out of range"):
        read_csv_generic(path, {"time_column": 0, "position_columns": [1, 2, 9]})
    with pytest.raises(InputFormatError, match="does not exist"):
        read_csv_generic(tmp_path / "none.csv", {"position_columns": [1, 2, 3]})
    junk = tmp_path / "junk.csv"
    junk.write_text("t,x,y,z\n" + "0,1,2,3\n" * 5 + "a,b,c,d\n" * 5)
    with pytest.raises(InputFormatError) as exc:
        read_csv_generic(junk, {"time_column": "t", "position_columns": ["x", "y", "z"], "time_unit": "s"})
    assert "junk.csv:7" in str(exc.value) and "5 of 10" in str(exc.value)


# --- extra pose inputs merged into a sequence (IMU from one input, poses from another) ---------


def test_load_sequence_merges_extra_pose_inputs(shared_data):
    from pipeline.io import load_sequence, select_pose_stream
    from pipeline.types import PoseSourceKind

    root = shared_data / "euroc" / "V1_01_easy"
    gt_txt = root / "ov_data" / "V1_01_easy_original.txt"
    seq = load_sequence(root, extra_poses=[f"{gt_txt}:ground_truth"])
    assert len(seq.imu) == 29120
    name, poses = select_pose_stream(seq)
    assert name == "V1_01_easy_original"  # the added stream comes before the folder's own vicon0
    assert list(seq.poses) == ["vicon0", "V1_01_easy_original"]
    assert select_pose_stream(seq, "vicon0")[0] == "vicon0"
    assert poses.source_kind is PoseSourceKind.GROUND_TRUTH
    assert len(poses) == 28712
    assert seq.metadata["extra_inputs"] == [str(gt_txt)]
    # A ground-truth state file given as extra input becomes the sequence's ground truth.
    state = shared_data / "euroc" / "V1_01_easy_proto_excerpt" / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    seq = load_sequence(root, extra_poses=[{"path": str(state)}])
    assert seq.ground_truth is not None and len(seq.ground_truth) == 999


def test_extra_pose_input_errors(tmp_path, shared_data):
    from pipeline.errors import ConfigError, DataError, InputFormatError
    from pipeline.io import PoseInput, load_sequence

    root = shared_data / "euroc" / "V1_01_easy"
    with pytest.raises(InputFormatError, match="missing.txt: does not exist"):
        load_sequence(root, extra_poses=[str(tmp_path / "missing.txt")])
    with pytest.raises(ConfigError, match="unknown pose kind"):
        PoseInput.coerce({"path": "x.txt", "kind": "lidar"})
    with pytest.raises(ConfigError, match="unknown keys"):
        PoseInput.coerce({"path": "x.txt", "colour": "red"})
    gt_txt = root / "ov_data" / "V1_01_easy_original.txt"
    with pytest.raises(DataError, match="already exists"):
        load_sequence(root, extra_poses=[str(gt_txt), str(gt_txt)])
