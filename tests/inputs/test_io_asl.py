"""ASL folder / CSV readers, sensor.yaml, dispatcher and pose-stream selection, on the real EuRoC and TUM-VI files.

Expected counts and spans are those of shared/data/SOURCES.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import AmbiguousInputError, ConfigError, DataError, InputFormatError, UnsupportedInputError
from pipeline.io import (
    CsvMapping,
    detect_format,
    list_pose_streams,
    load_sequence,
    parse_format,
    read_asl,
    read_asl_pose_csv,
    read_csv_generic,
    select_pose_stream,
)
from pipeline.io.asl import AslTable, classify_header, read_asl_state_csv
from pipeline.io.sensor_yaml import load_sensor_yaml, read_imu_calibration
from pipeline.store import read_store, write_store
from pipeline.types import ImuCalibration, PoseSeries, PoseSourceKind, Sequence, Severity, StateSeries

IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")


def codes(seq: Sequence) -> list[str]:
    return [f.code for f in seq.findings]


def finding(seq: Sequence, code: str, stream: str):
    hits = [f for f in seq.findings if f.code == code and f.stream == stream]
    assert len(hits) == 1, (code, stream, seq.findings)
    return hits[0]


# --------------------------------------------------------------------------------------------------
# EuRoC folders


@pytest.fixture(scope="module")
def v1_01(shared_data: Path) -> Sequence:
    return read_asl(shared_data / "euroc/V1_01_easy")


@pytest.fixture(scope="module")
def mh_01(shared_data: Path) -> Sequence:
    return read_asl(shared_data / "euroc/MH_01_easy")


def test_v1_01_full_imu(v1_01: Sequence) -> None:
    imu = v1_01.imu
    assert v1_01.name == "V1_01_easy"
    assert len(imu) == 29120
    assert imu.t_ns.dtype == np.int64
    assert imu.t_ns[0] == 1403715273262142976
    assert imu.t_ns[-1] == 1403715418857143040
    np.testing.assert_array_equal(imu.gyro_radps[0],
                                  [-0.0020943951023931952, 0.017453292519943295, 0.07749261878854824])
    np.testing.assert_array_equal(imu.acc_mps2[0], [9.0874956666666655, 0.13075533333333333, -3.6938381666666662])
    np.testing.assert_array_equal(imu.acc_mps2[-1], [9.1610455416666667, 0.26151066666666667, -3.2035056666666666])
    assert imu.rate_hz == pytest.approx(200.0, rel=1e-3)
    assert v1_01.ground_truth is None
    assert v1_01.findings == []  # clean files (the Vicon file's CRLF line ends included), full sensor.yaml
    assert v1_01.metadata["source_format"] == "asl"


def test_v1_01_raw_vicon_stream(v1_01: Sequence) -> None:
    """vicon0: 6-DoF poses of the Vicon body, CRLF line ends, 14629 rows (SOURCES.md)."""
    assert list(v1_01.poses) == ["vicon0"]
    vicon = v1_01.poses["vicon0"]
    assert len(vicon) == 14629 and vicon.t_ns.dtype == np.int64
    assert vicon.t_ns[0] == 1403715271705179904 and vicon.t_ns[-1] == 1403715417988117504
    assert vicon.source_kind is PoseSourceKind.MOCAP and vicon.frame == "vicon_marker"
    assert vicon.rate_hz == pytest.approx(100.0, rel=1e-2)
    np.testing.assert_allclose(np.linalg.norm(vicon.quat_wxyz, axis=1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(vicon.p_m[0], [0.78680237507119299, 2.1766263084402229, 1.0620383602617547])
    np.testing.assert_array_equal(vicon.quat_wxyz[0], [0.9932172094084879, -0.0092907273683985395,
                                                       0.022668607879467291, 0.11366350133877155])


def test_v1_01_sensor_yaml_with_yaml_directive(shared_data: Path, v1_01: Sequence) -> None:
    path = shared_data / "euroc/V1_01_easy/mav0/imu0/sensor.yaml"
    assert path.read_text().startswith("%YAML:1.0")
    data = load_sensor_yaml(path)
    assert data["rate_hz"] == 200 and data["T_BS"]["rows"] == 4
    calib = read_imu_calibration(path)
    assert calib.gyro_noise_density == 1.6968e-04
    assert calib.gyro_random_walk == 1.9393e-05
    assert calib.acc_noise_density == 2.0e-3
    assert calib.acc_random_walk == 3.0e-3
    assert calib.rate_hz == 200.0
    np.testing.assert_array_equal(calib.T_body_imu, np.eye(4))
    assert v1_01.calibration.rate_hz == 200.0
    # the Vicon body's pose in the IMU frame: vicon0/sensor.yaml's T_BS (imu0's own T_BS is identity)
    assert list(v1_01.calibration.T_imu_frames) == ["vicon_marker"]
    np.testing.assert_array_equal(v1_01.calibration.T_imu_frames["vicon_marker"][:3],
                                  [[0.33638, -0.01749, 0.94156, 0.06901], [-0.02078, -0.99972, -0.01114, -0.02781],
                                   [0.94150, -0.01582, -0.33665, -0.12395]])


def test_mh_01_spreadsheet_imu(mh_01: Sequence, shared_data: Path) -> None:
    imu = mh_01.imu
    assert len(imu) == 36820
    assert imu.t_ns[0] == 1403636579758560000  # 1.40363657975856E+018, exactly
    assert imu.t_ns[1] == 1403636579763560000
    assert imu.t_ns[-1] == 1403636763853560000
    np.testing.assert_array_equal(imu.gyro_radps[0], [-0.0991347015, 0.1473057889, 0.0272271363])
    np.testing.assert_array_equal(imu.acc_mps2[-1], [9.1365289167, -0.760015375, -2.770378625])
    skipped = finding(mh_01, "PARSE_SKIPPED_LINES", "imu")
    assert skipped.severity is Severity.WARNING
    assert skipped.details["count"] == 7
    assert skipped.details["lines"] == [36822, 36823, 36824, 36825, 36826, 36827, 36828]
    assert skipped.details["file"] == str(shared_data / "euroc/MH_01_easy/mav0/imu0/data.csv")
    assert "36822" in skipped.message and "7" in skipped.message
    loss = finding(mh_01, "STAMP_PRECISION_LOSS", "imu")
    assert loss.severity is Severity.WARNING
    assert loss.details["resolution_ns"] == 10000
    assert loss.details["reason"] == "scientific notation"


def test_mh_01_leica_position_only(mh_01: Sequence) -> None:
    assert list(mh_01.poses) == ["leica0"]
    leica = mh_01.poses["leica0"]
    assert len(leica) == 3099
    assert leica.quat_wxyz is None and not leica.has_orientation
    assert leica.source_kind is PoseSourceKind.POSITION_TRACKER
    assert leica.frame == "leica_prism"
    assert leica.t_ns[0] == 1403636578922881280 and leica.t_ns[-1] == 1403636766678881280
    np.testing.assert_array_equal(leica.p_m[0], [4.7822997174796811, -1.8155736277079491, 0.84462707370341705])
    T = mh_01.calibration.T_imu_frames["leica_prism"]
    np.testing.assert_allclose(T[:3, 3], [0.0749, -0.0185, -0.1202], atol=1e-4)
    np.testing.assert_array_equal(T[:3, 3], [7.48903e-02, -1.84772e-02, -1.20209e-01])
    np.testing.assert_array_equal(T[:3, :3], np.eye(3))
    assert not [f for f in mh_01.findings if f.stream == "poses/leica0"]
    assert mh_01.ground_truth is None  # MH_01 has only the GT sensor.yaml here


def test_kimera_excerpt_rounded_stamps(shared_data: Path) -> None:
    seq = read_asl(shared_data / "euroc/V1_02_medium_kimera_excerpt/mav0")  # the mav0 folder itself
    assert seq.name == "V1_02_medium_kimera_excerpt"
    assert len(seq.imu) == 7999
    assert seq.imu.t_ns[0] == 1403715523912140000 and seq.imu.t_ns[-1] == 1403715563902140000
    gt = seq.ground_truth
    assert len(gt) == 3340
    assert gt.t_ns[0] == 1403715524922140000 and gt.t_ns[-1] == 1403715608397140000
    assert gt.rate_hz == pytest.approx(40.0, rel=1e-3)
    for stream in ("imu", "ground_truth"):
        loss = finding(seq, "STAMP_PRECISION_LOSS", stream)
        assert loss.details["resolution_ns"] == 10000 and loss.details["reason"] == "rounded"
    defaulted = finding(seq, "CALIBRATION_DEFAULTED", "imu")
    assert defaulted.severity is Severity.WARNING
    assert seq.calibration.to_dict() == ImuCalibration().to_dict()
    assert "PARSE_SKIPPED_LINES" not in codes(seq)


GT_FILES = {
    "MH_04_difficult": (19753, 1403638128940097024, 1403638227700097024),
    "MH_05_difficult": (22212, 1403638519492829440, 1403638630547829504),
    "V1_02_medium": (16702, 1403715524907143168, 1403715608412143104),
    "V1_03_difficult": (20932, 1403715888379057920, 1403715993034057984),
    "V2_01_easy": (22401, 1413393213480760576, 1413393325480760576),
    "V2_02_medium": (23091, 1413393887225760512, 1413394002675760384),
    "V2_03_difficult": (22970, 1413394882790760448, 1413394997635760640),
}
# SOURCES.md: IMU rows, raw stream and its rows (MH_04 has neither a raw stream nor a sensor.yaml)
RAW_FILES = {
    "MH_04_difficult": (20320, None, 0),
    "MH_05_difficult": (22721, "leica0", 1665),
    "V1_02_medium": (17100, "vicon0", 9418),
    "V1_03_difficult": (21500, "vicon0", 10807),
    "V2_01_easy": (22800, "vicon0", 11395),
    "V2_02_medium": (23490, "vicon0", 11740),
    "V2_03_difficult": (23370, "vicon0", 11683),
}


@pytest.mark.parametrize("seq_name", sorted(GT_FILES))
def test_euroc_ground_truth_states(shared_data: Path, seq_name: str) -> None:
    rows, first, last = GT_FILES[seq_name]
    imu_rows, stream, stream_rows = RAW_FILES[seq_name]
    seq = read_asl(shared_data / "euroc" / seq_name)
    gt = seq.ground_truth
    assert len(seq.imu) == imu_rows and seq.imu.rate_hz == pytest.approx(200.0, rel=1e-3)
    assert {k: len(v) for k, v in seq.poses.items()} == ({stream: stream_rows} if stream else {})
    # the ground truth lies inside the IMU's span (EuRoC's estimate starts after the IMU)
    assert seq.imu.t_ns[0] <= gt.t_ns[0] and gt.t_ns[-1] <= seq.imu.t_ns[-1]
    assert len(gt) == rows
    assert gt.t_ns[0] == first and gt.t_ns[-1] == last
    assert gt.rate_hz == pytest.approx(200.0, rel=1e-3)
    for arr in (gt.p_m, gt.quat_wxyz, gt.v_mps, gt.bias_gyro_radps, gt.bias_acc_mps2):
        assert np.isfinite(arr).all()
    np.testing.assert_allclose(np.linalg.norm(gt.quat_wxyz, axis=1), 1.0, atol=1e-3)  # 6 decimals
    assert np.abs(gt.bias_gyro_radps).max() < 0.2 and np.abs(gt.bias_acc_mps2).max() < 1.0
    assert [f.code for f in seq.findings] == (["CALIBRATION_DEFAULTED"] if stream is None else [])


def test_proto_excerpt_original_v1_01_bias(shared_data: Path) -> None:
    gt, findings = read_asl_state_csv(
        shared_data / "euroc/V1_01_easy_proto_excerpt/mav0/state_groundtruth_estimate0/data.csv")
    assert findings == []
    assert len(gt) == 999
    assert gt.t_ns[0] == 1403715274302142976 and gt.t_ns[-1] == 1403715279292143104
    np.testing.assert_array_equal(gt.p_m[0], [0.878612, 2.142470, 0.947262])
    np.testing.assert_array_equal(gt.quat_wxyz[0], [0.060514, -0.828459, -0.058956, -0.553641])
    np.testing.assert_array_equal(gt.v_mps[0], [0.009474, -0.014009, -0.002145])
    np.testing.assert_array_equal(gt.bias_gyro_radps[0], [-0.002229, 0.020700, 0.076350])
    np.testing.assert_array_equal(gt.bias_acc_mps2[0], [-0.012492, 0.547666, 0.069073])
    assert gt.bias_acc_mps2[0, 1] == pytest.approx(0.548, abs=1e-3)


# --------------------------------------------------------------------------------------------------
# standalone CSVs: TUM-VI mocap, OpenVINS state


TUM_VI = {
    1: (16541, 1520530308189679351, 1520530449214678351),
    2: (15477, 1520530731382632018, 1520530875449299018),
    3: (15200, 1520530962744806490, 1520531103761473490),
    4: (13075, 1520531124177875537, 1520531235544541537),
    5: (16999, 1520531467575275014, 1520531609891941014),
    6: (15244, 1520621015527175707, 1520621146352175707),
}


@pytest.mark.parametrize("room", sorted(TUM_VI))
def test_tum_vi_mocap_csv(shared_data: Path, room: int) -> None:
    rows, first, last = TUM_VI[room]
    stem = f"dataset-room{room}_512_16"
    path = shared_data / "tum_vi" / stem / "ov_data" / f"{stem}.csv"
    seq = read_asl_pose_csv(path, source_kind=PoseSourceKind.MOCAP)
    assert seq.name == stem and list(seq.poses) == [stem]
    poses = seq.poses[stem]
    assert len(poses) == rows
    assert poses.t_ns[0] == first and poses.t_ns[-1] == last
    assert poses.source_kind is PoseSourceKind.MOCAP and poses.has_orientation
    assert poses.rate_hz == pytest.approx(120.0, rel=1e-3)
    np.testing.assert_allclose(np.linalg.norm(poses.quat_wxyz, axis=1), 1.0, atol=1e-6)
    assert seq.findings == []


def test_tum_vi_csv_through_load_sequence(shared_data: Path) -> None:
    path = shared_data / "tum_vi/dataset-room1_512_16/ov_data/dataset-room1_512_16.csv"
    assert detect_format(path) == "asl"
    seq = load_sequence(path)
    poses = seq.poses["dataset-room1_512_16"]
    np.testing.assert_array_equal(poses.p_m[0], [0.8417820384, -0.2193354118, 1.2499749141])
    np.testing.assert_array_equal(poses.quat_wxyz[0], [0.9996498117, 0.0037373093, 0.0097169635, -0.0243283190])
    assert select_pose_stream(seq) == ("dataset-room1_512_16", poses)


def test_openvins_state_csv_via_mapping_and_autodetect(shared_data: Path) -> None:
    path = shared_data / "euroc/V1_01_easy/ov_data/V1_01_easy.csv"
    mapping = CsvMapping.from_dict({
        "time_column": "time(ns)", "time_unit": "ns",
        "position_columns": ["px", "py", "pz"], "quat_columns": ["qw", "qx", "qy", "qz"], "quat_order": "wxyz",
    })
    seq = read_csv_generic(path, mapping, source_kind=PoseSourceKind.GROUND_TRUTH)
    poses = seq.poses["V1_01_easy"]
    assert len(poses) == 2895
    assert poses.t_ns[0] == 1403715273262142976 and poses.t_ns[-1] == 1403715417962142976
    np.testing.assert_array_equal(poses.quat_wxyz[0], [0.069433, -0.824237, -0.106942, -0.551702])
    assert poses.source_kind is PoseSourceKind.GROUND_TRUTH
    assert seq.imu is None and seq.findings == []
    # Without a mapping its header is recognised as the EuRoC state layout.
    auto = load_sequence(path)
    assert len(auto.ground_truth) == 2895
    np.testing.assert_array_equal(auto.ground_truth.t_ns, poses.t_ns)
    np.testing.assert_array_equal(auto.ground_truth.bias_acc_mps2[-1], [-0.011888, 0.107387, 0.0314441])
    assert load_sequence(path, csv_mapping=mapping).poses.keys() == {"V1_01_easy"}


def test_classify_header() -> None:
    assert classify_header(IMU_HEADER.strip().split(",")) is AslTable.IMU
    assert classify_header(["#timestamp [ns]", " p_RS_R_x [m]", " p_RS_R_y [m]", " p_RS_R_z [m]"]) is AslTable.POSITION
    assert classify_header(["#timestamp", "x", "y", "z"]) is None
    assert classify_header(None, 8) is AslTable.POSE
    with_temperature = IMU_HEADER.strip().split(",") + ["temperature [degC]"]
    assert classify_header(with_temperature) is AslTable.IMU_TEMPERATURE
    assert classify_header(with_temperature[:7] + ["counter"]) is None  # an 8th column is read by its name only


def test_imu_temperature_column(tmp_path: Path) -> None:
    """An eighth 'temperature [degC]' column lands in ImuSeries.temperature_degc and in the store."""
    path = tmp_path / "seq" / "mav0" / "imu0" / "data.csv"
    path.parent.mkdir(parents=True)
    rows = [f"{1_000_000_000 + i * 5_000_000},0.1,0.2,0.3,0.0,0.0,9.81,{25.0 + 0.125 * i}\n" for i in range(40)]
    path.write_text(IMU_HEADER.strip() + ",temperature [degC]\n" + "".join(rows))
    seq = read_asl(tmp_path / "seq")
    np.testing.assert_array_equal(seq.imu.temperature_degc, 25.0 + 0.125 * np.arange(40))
    np.testing.assert_array_equal(seq.imu.acc_mps2[:, 2], 9.81)
    back = read_store(write_store(seq, tmp_path / "store"))
    np.testing.assert_array_equal(back.imu.temperature_degc, seq.imu.temperature_degc)
    path.write_text(IMU_HEADER + "".join(r.rsplit(",", 1)[0] + "\n" for r in rows))
    assert read_asl(tmp_path / "seq").imu.temperature_degc is None
    path.write_text("".join(rows))  # eight unnamed columns: not an IMU file
    with pytest.raises(InputFormatError, match="not a ASL IMU CSV"):
        read_asl(tmp_path / "seq")


# --------------------------------------------------------------------------------------------------
# synthetic ASL folders


def _write_imu(path: Path, n: int = 50, t0: int = 1_000_000_000, junk: dict[int, str] | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [IMU_HEADER]
    for i in range(n):
        lines.append(f"{t0 + i * 5_000_000},0.1,0.2,0.3,0.0,0.0,9.81\n")
    for at, text in sorted((junk or {}).items()):
        lines.insert(at - 1, text + "\n")  # 'at' is the 1-based line number it will have
    path.write_text("".join(lines))


def test_extra_pose_stream_and_quaternion_order(tmp_path: Path) -> None:
    mav0 = tmp_path / "seq" / "mav0"
    _write_imu(mav0 / "imu0" / "data.csv")
    (mav0 / "optitrack0").mkdir()
    (mav0 / "optitrack0" / "data.csv").write_text(
        "#timestamp [ns], p_x [m], p_y [m], p_z [m], q_x [], q_y [], q_z [], q_w []\n"
        "1000000000, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0\n"
        "1010000000, 1.5, 2.5, 3.5, 0.5, 0.5, 0.5, 0.5\n")
    (mav0 / "cam0").mkdir()
    (mav0 / "cam0" / "data.csv").write_text("#timestamp [ns],filename\n1000000000,1000000000.png\n")
    (mav0 / "vicon0").mkdir()
    (mav0 / "vicon0" / "data.csv").write_text(
        "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n"
        "1000000000,0,0,0,1,0,0,0\n1005000000,0,0,0,1,0,0,0\n")
    (mav0 / "vicon0" / "sensor.yaml").write_text(
        "%YAML:1.0\nT_BS:\n  cols: 4\n  rows: 4\n  data: [0.0, -1.0, 0.0, 0.1,\n"
        "         1.0, 0.0, 0.0, 0.2,\n         0.0, 0.0, 1.0, 0.3,\n         0.0, 0.0, 0.0, 1.0]\n")
    (mav0 / "imu0" / "sensor.yaml").write_text(
        "T_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.05, "
        "0.0, 0.0, 0.0, 1.0]\nrate_hz: 200\ngyroscope_noise_density: 1.0e-4\ngyroscope_random_walk: 1.0e-5\n"
        "accelerometer_noise_density: 1.0e-3\naccelerometer_random_walk: 1.0e-4\n")
    seq = read_asl(tmp_path / "seq", name="custom")
    assert seq.name == "custom"
    assert sorted(seq.poses) == ["optitrack0", "vicon0"]
    opti = seq.poses["optitrack0"]
    assert opti.frame == "optitrack0" and opti.source_kind is PoseSourceKind.MOCAP
    np.testing.assert_array_equal(opti.quat_wxyz, [[1.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.5]])
    assert seq.poses["vicon0"].frame == "vicon_marker"
    T = seq.calibration.T_imu_frames["vicon_marker"]
    expected = np.linalg.inv(seq.calibration.T_body_imu) @ np.array(
        [[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.3], [0, 0, 0, 1.0]])
    np.testing.assert_allclose(T, expected)
    np.testing.assert_allclose(T[:3, 3], [0.1, 0.2, 0.25])
    assert seq.calibration.gyro_noise_density == 1.0e-4
    assert "CALIBRATION_DEFAULTED" not in codes(seq)
    assert list_pose_streams(seq) == ["vicon0", "optitrack0"]


def test_imu_junk_lines_are_skipped_and_listed(tmp_path: Path) -> None:
    path = tmp_path / "mav0" / "imu0" / "data.csv"
    _write_imu(path, n=100, junk={10: ",,,,,,", 20: "Step: 0.005 = 1/200,,,,,,", 30: "1.5,,,,,,", 40: "   "})
    seq = read_asl(tmp_path)
    assert len(seq.imu) == 100
    skipped = finding(seq, "PARSE_SKIPPED_LINES", "imu")
    assert skipped.details["count"] == 3  # the blank line is not counted
    assert skipped.details["lines"] == [10, 20, 30]
    assert np.all(np.diff(seq.imu.t_ns) == 5_000_000)


def test_faithful_parse_keeps_nan_order_and_duplicates(tmp_path: Path) -> None:
    path = tmp_path / "mav0" / "imu0" / "data.csv"
    path.parent.mkdir(parents=True)
    path.write_text(IMU_HEADER + "30,1,2,3,4,5,6\n10,nan,2,3,4,5,6\n10,1,2,3,4,5,NaN\n20,1,2,3,4,5,6\n")
    seq = read_asl(tmp_path)
    np.testing.assert_array_equal(seq.imu.t_ns, [30, 10, 10, 20])
    assert np.isnan(seq.imu.gyro_radps[1, 0]) and np.isnan(seq.imu.acc_mps2[2, 2])
    assert "PARSE_SKIPPED_LINES" not in codes(seq)


def test_too_much_junk_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "mav0" / "imu0" / "data.csv"
    _write_imu(path, n=20, junk={5: "garbage", 6: "1,2,3", 7: "x,y,z,1,2,3,4"})
    with pytest.raises(InputFormatError) as exc:
        read_asl(tmp_path)
    msg = str(exc.value)
    assert "data.csv:5" in msg and "3 of 23" in msg
    assert exc.value.line == 5 and exc.value.path == str(path)


def test_wrong_column_count_header(tmp_path: Path) -> None:
    path = tmp_path / "mav0" / "imu0" / "data.csv"
    path.parent.mkdir(parents=True)
    path.write_text("#timestamp [ns],w_x,w_y,w_z\n1,2,3,4\n")
    with pytest.raises(InputFormatError) as exc:
        read_asl(tmp_path)
    assert "data.csv:1" in str(exc.value) and "4 columns" in str(exc.value)


def test_wrong_column_count_rows(tmp_path: Path) -> None:
    path = tmp_path / "mav0" / "imu0" / "data.csv"
    path.parent.mkdir(parents=True)
    path.write_text(IMU_HEADER + "".join(f"{i},1,2,3,4\n" for i in range(10)))
    with pytest.raises(InputFormatError) as exc:
        read_asl(tmp_path)
    assert "data.csv:2" in str(exc.value) and "has 5 fields, expected 7" in str(exc.value)


def test_garbage_header(tmp_path: Path) -> None:
    path = tmp_path / "mav0" / "imu0" / "data.csv"
    path.parent.mkdir(parents=True)
    path.write_text("hello, this is not a header\n1,2,3,4,5,6,7\n")
    with pytest.raises(InputFormatError) as exc:
        read_asl(tmp_path)
    assert str(path) in str(exc.value) and ":1:" in str(exc.value)


@pytest.mark.parametrize("content", ["", "\n\n", IMU_HEADER])
def test_empty_imu_file(tmp_path: Path, content: str) -> None:
    path = tmp_path / "mav0" / "imu0" / "data.csv"
    path.parent.mkdir(parents=True)
    path.write_text(content)
    with pytest.raises(InputFormatError) as exc:
        read_asl(tmp_path)
    assert str(path) in str(exc.value)
    assert "empty" in str(exc.value) or "no data lines" in str(exc.value)


def test_malformed_sensor_yaml(tmp_path: Path) -> None:
    _write_imu(tmp_path / "mav0" / "imu0" / "data.csv")
    yaml_path = tmp_path / "mav0" / "imu0" / "sensor.yaml"
    yaml_path.write_text("%YAML:1.0\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0]\n")
    with pytest.raises(InputFormatError) as exc:
        read_asl(tmp_path)
    assert "sensor.yaml" in str(exc.value) and "T_BS" in str(exc.value)
    yaml_path.write_text("gyroscope_noise_density: abc\n")
    with pytest.raises(InputFormatError) as exc:
        read_asl(tmp_path)
    assert "gyroscope_noise_density" in str(exc.value)
    yaml_path.write_text("T_BS: [1, 2\nrate_hz: 200\n")
    with pytest.raises(InputFormatError, match="sensor.yaml"):
        read_asl(tmp_path)


def test_partial_sensor_yaml_reports_defaults(tmp_path: Path) -> None:
    _write_imu(tmp_path / "mav0" / "imu0" / "data.csv")
    (tmp_path / "mav0" / "imu0" / "sensor.yaml").write_text("rate_hz: 100\n")
    seq = read_asl(tmp_path)
    assert seq.calibration.rate_hz == 100.0
    f = finding(seq, "CALIBRATION_DEFAULTED", "imu")
    assert f.details["missing_keys"] == ["gyroscope_noise_density", "gyroscope_random_walk",
                                         "accelerometer_noise_density", "accelerometer_random_walk"]


# --------------------------------------------------------------------------------------------------
# store round trip


@pytest.mark.parametrize("which", ["v1_01", "mh_01"])
def test_store_round_trip(which: str, request: pytest.FixtureRequest, tmp_path: Path) -> None:
    seq: Sequence = request.getfixturevalue(which)
    write_store(seq, tmp_path / "store")
    assert detect_format(tmp_path / "store") == "store"
    back = read_store(tmp_path / "store")
    assert load_sequence(tmp_path / "store").imu.t_ns[-1] == seq.imu.t_ns[-1]
    assert back.name == seq.name
    assert back.imu.t_ns.dtype == np.int64
    np.testing.assert_array_equal(back.imu.t_ns, seq.imu.t_ns)
    np.testing.assert_array_equal(back.imu.gyro_radps, seq.imu.gyro_radps)
    np.testing.assert_array_equal(back.imu.acc_mps2, seq.imu.acc_mps2)
    assert back.poses.keys() == seq.poses.keys()
    for k, p in seq.poses.items():
        np.testing.assert_array_equal(back.poses[k].t_ns, p.t_ns)
        np.testing.assert_array_equal(back.poses[k].p_m, p.p_m)
        assert back.poses[k].frame == p.frame and back.poses[k].source_kind is p.source_kind
    assert back.findings == seq.findings
    assert back.calibration.to_dict() == seq.calibration.to_dict()


# --------------------------------------------------------------------------------------------------
# dispatcher


def test_detect_format(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data
    assert detect_format(d / "euroc/V1_01_easy") == "asl"
    assert detect_format(d / "euroc/V1_01_easy/mav0") == "asl"
    assert detect_format(d / "euroc/MH_01_easy/ov_data/MH_01_easy.txt") == "tum"
    assert detect_format(d / "ros_bags/evo_test_data/ROS_example.bag") == "bag"
    assert detect_format(d / "ros_bags/evo_test_data/nav2_turtlebot.mcap") == "bag"
    assert detect_format(d / "ros_bags/evo_test_data/tf_example") == "bag"
    assert detect_format(d / "kitti_gtsam/examples_Data/KittiGps_converted.txt") == "csv"
    with pytest.raises(InputFormatError, match="does not exist"):
        detect_format(tmp_path / "nope")
    with pytest.raises(UnsupportedInputError, match="supported inputs"):
        detect_format(tmp_path)
    assert parse_format("rosbag") == "bag" and parse_format("ASL") == "asl"
    with pytest.raises(ConfigError, match="unknown input format"):
        parse_format("xls")


def test_load_sequence_errors(shared_data: Path, tmp_path: Path) -> None:
    with pytest.raises(InputFormatError) as exc:
        load_sequence(tmp_path / "missing.csv")
    assert "missing.csv" in str(exc.value) and "does not exist" in str(exc.value)
    kitti = shared_data / "kitti_gtsam/examples_Data/KittiGps_converted.txt"
    with pytest.raises(UnsupportedInputError, match="column mapping"):
        load_sequence(kitti)
    with pytest.raises(UnsupportedInputError) as exc:
        load_sequence(tmp_path)
    assert "ROS bag" in str(exc.value) and "TUM" in str(exc.value)
    with pytest.raises(ConfigError, match="imu_topic"):
        load_sequence(shared_data / "euroc/V1_01_easy_proto_excerpt", imu_topic="/imu")
    seq = load_sequence(kitti, csv_mapping={"time_column": "Time", "position_columns": ["X", "Y", "Z"]})
    poses = seq.poses["KittiGps_converted"]
    assert len(poses) == 470 and poses.source_kind is PoseSourceKind.POSITION_TRACKER
    assert [f.code for f in seq.findings] == ["STAMP_UNIT_GUESSED"]
    assert seq.findings[0].details["unit"] == "s"


def test_load_standalone_asl_imu_csv(shared_data: Path) -> None:
    path = shared_data / "euroc/V1_02_medium_kimera_excerpt/mav0/imu0/data.csv"
    assert detect_format(path) == "asl"
    seq = load_sequence(path, name="v102")
    assert seq.name == "v102" and len(seq.imu) == 7999 and seq.poses == {}
    np.testing.assert_array_equal(seq.imu.acc_mps2[0], [9.218251, 0.3023717083, -3.1544724167])
    # a lone data.csv has no sensor.yaml: its noise values are defaults, and the findings say so
    assert [f.code for f in seq.findings] == ["STAMP_PRECISION_LOSS", "CALIBRATION_DEFAULTED"]


def test_load_sequence_dispatches_bags(shared_data: Path) -> None:
    pytest.importorskip("pipeline.io.rosbag.reader")
    seq = load_sequence(shared_data / "ros_bags/evo_test_data/ROS_example.bag", pose_topic="groundtruth")
    assert len(seq.poses["groundtruth"]) == 12765
    seq = load_sequence(shared_data / "ros_bags/evo_test_data/ROS_example.bag", fmt="rosbag",
                        pose_topic="groundtruth", name="evo")
    assert seq.name == "evo"


def _pose(kind: PoseSourceKind, n: int = 3) -> PoseSeries:
    return PoseSeries(np.arange(n) * 10, np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), "f", kind)


def test_select_pose_stream_priority() -> None:
    gt = StateSeries(np.arange(3), np.zeros((3, 3)), np.tile([1.0, 0, 0, 0], (3, 1)), np.zeros((3, 3)),
                     np.zeros((3, 3)), np.zeros((3, 3)))
    streams = {
        "vio": _pose(PoseSourceKind.VIO), "gps": _pose(PoseSourceKind.POSITION_TRACKER),
        "opti": _pose(PoseSourceKind.MOCAP), "leica0": _pose(PoseSourceKind.POSITION_TRACKER),
        "mocap0": _pose(PoseSourceKind.MOCAP), "vicon0": _pose(PoseSourceKind.MOCAP),
    }
    seq = Sequence("s", poses=dict(streams), ground_truth=gt)
    assert list_pose_streams(seq) == ["vicon0", "mocap0", "leica0", "opti", "gps", "vio", "ground_truth"]
    order = []
    while seq.poses:
        name, poses = select_pose_stream(seq)
        assert poses is seq.poses[name]
        order.append(name)
        del seq.poses[name]
    assert order == ["vicon0", "mocap0", "leica0", "opti", "gps", "vio"]
    name, poses = select_pose_stream(seq)
    assert name == "ground_truth" and poses.source_kind is PoseSourceKind.GROUND_TRUTH and len(poses) == 3
    seq.poses["vio"] = streams["vio"]
    assert select_pose_stream(seq, "ground_truth")[0] == "ground_truth"
    with pytest.raises(AmbiguousInputError) as exc:
        select_pose_stream(seq, "vicon0")
    assert "--poses NAME" in str(exc.value) and "vio, ground_truth" in str(exc.value)
    with pytest.raises(DataError):
        select_pose_stream(Sequence("empty"))


def test_int64_overflowing_stamp_is_a_clear_error(tmp_path):
    """19-digit stamps take the fast int64 path; one beyond int64 falls back and is reported."""
    d = tmp_path / "mav0" / "imu0"
    d.mkdir(parents=True)
    header = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
    (d / "data.csv").write_text(header + "9999999999999999999,0,0,0,0,0,9.8\n1,0,0,0,0,0,9.8\n")
    with pytest.raises(InputFormatError, match=r"data.csv:2: .*does not fit int64"):
        read_asl(tmp_path)
