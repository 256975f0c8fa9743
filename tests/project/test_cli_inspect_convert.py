"""``biasgt inspect`` / ``biasgt convert`` and :func:`pipeline.ingest.ingest`, through ``biasgt.cli.app.main``."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from synth import T0_NS, make_imu, make_poses, make_sequence

import pipeline.ingest
import pipeline.io
from pipeline.checks.options import CheckOptions, Repair
from pipeline.checks.run import STREAM_SUMMARY_KEYS
from pipeline.checks.stream_checks import detect_acc_in_g, detect_gyro_degps
from biasgt.cli.app import main
from biasgt.cli.commands.inspect import JSON_KEYS
from pipeline.errors import FatalCheckError, InputFormatError
from pipeline.ingest import ingest
from pipeline.store import read_store
from pipeline.types import Finding, ImuSeries, Sequence, Severity

FINDING_KEYS = {"code", "severity", "stream", "message", "details"}


class FakeLoader:
    """Stands in for :func:`pipeline.io.load_sequence`: returns a given sequence, records the call."""

    def __init__(self, seq: Sequence | Exception) -> None:
        self.seq = seq
        self.calls: list[tuple[Path, dict]] = []

    def __call__(self, path, **kwargs):
        self.calls.append((Path(path), kwargs))
        if isinstance(self.seq, Exception):
            raise self.seq
        return self.seq


@pytest.fixture
def fake(monkeypatch):
    def install(seq):
        loader = FakeLoader(seq)
        monkeypatch.setattr(pipeline.ingest, "load_sequence", loader)
        return loader
    return install


def unsorted_sequence() -> Sequence:
    seq = make_sequence()
    imu = seq.imu
    idx = np.arange(len(imu))
    idx[[10, 11]] = idx[[11, 10]]
    idx = np.insert(idx, 30, 30)  # one duplicate row
    return replace(seq, imu=ImuSeries(imu.t_ns[idx], imu.gyro_radps[idx], imu.acc_mps2[idx]))


# ------------------------------------------------------------------------------------------ inspect


def test_inspect_json_schema_is_stable(fake, capsys):
    loader = fake(make_sequence())
    assert main(["inspect", "some/input", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert tuple(report) == JSON_KEYS
    assert set(report) == {"schema_version", "input", "format", "streams", "findings", "verdict"}
    assert report["schema_version"] == 1
    assert report["input"] == "some/input"
    assert report["format"] == "synthetic"  # from metadata["source_format"]
    assert report["verdict"] == "ok"
    assert [tuple(s) for s in report["streams"]] == [STREAM_SUMMARY_KEYS] * 2
    assert report["streams"][0]["count"] == 2000 and report["streams"][0]["t0_ns"] == T0_NS
    assert report["findings"] and all(set(f) == FINDING_KEYS for f in report["findings"])
    assert [(f["code"], f["severity"]) for f in report["findings"]] == [("RATE", "info"), ("RATE", "info")]
    assert loader.calls[0][0] == Path("some/input")


def test_inspect_text_lists_streams_findings_and_verdict(fake, capsys):
    fake(unsorted_sequence())
    assert main(["inspect", "x"]) == 0  # repairable is not fatal
    out = capsys.readouterr().out
    lines = out.splitlines()
    pose_row = next(line for line in lines if line.startswith("poses/vicon0 "))
    assert pose_row.split()[1:3] == ["poses", "1000"]
    imu_row = next(line for line in lines if line.startswith("imu "))
    assert imu_row.split()[2] == "2001"
    assert any("REPAIRABLE" in line and "NON_MONOTONIC" in line and "--repair sort" in line for line in lines)
    assert any("DUPLICATE_STAMPS" in line for line in lines)
    assert lines[-1].startswith("verdict: repairable (2 repairable)")


def test_inspect_fatal_exit_code_1(fake, capsys):
    fake(make_sequence(duration_s=1.0))
    assert main(["inspect", "x", "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["verdict"] == "fatal"
    assert [f["code"] for f in report["findings"] if f["severity"] == "fatal"] == ["TOO_SHORT"]
    assert main(["inspect", "x", "--json", "--min-duration", "0.5"]) == 0


def test_inspect_reader_error_exit_code_2(fake, capsys):
    fake(InputFormatError("cannot parse", path="x/data.csv", line=3, hint="fix it"))
    assert main(["inspect", "x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "biasgt inspect: error: x/data.csv:3: cannot parse; fix it"


def test_inspect_passes_reader_options_and_csv_mapping(fake, tmp_path, capsys):
    loader = fake(make_sequence())
    mapping = tmp_path / "map.yaml"
    mapping.write_text("t: time\ngyro_x: wx\n", encoding="utf-8")
    assert main(["inspect", "in.bag", "--imu-topic", "/imu", "--pose-topic", "/odom", "--tf-parent", "world",
                 "--tf-child", "base", "--csv-mapping", str(mapping), "--format", "rosbag"]) == 0
    _, kwargs = loader.calls[0]
    assert kwargs == {"fmt": "rosbag", "csv_mapping": {"t": "time", "gyro_x": "wx"}, "imu_topic": "/imu",
                      "pose_topic": "/odom", "tf_parent": "world", "tf_child": "base", "extra_poses": [],
                      "all_pose_topics": True}
    bad = tmp_path / "bad.yaml"
    bad.write_text("- a list\n", encoding="utf-8")
    assert main(["inspect", "in.csv", "--csv-mapping", str(bad)]) == 2
    assert "CSV mapping must be a YAML mapping" in capsys.readouterr().err


def test_inspect_ignore_and_allow_pose_only(fake, capsys):
    seq = make_sequence()
    fake(replace(seq, imu=None))
    assert main(["inspect", "x", "--json"]) == 1
    assert main(["inspect", "x", "--json", "--allow-pose-only"]) == 0
    capsys.readouterr()
    fake(replace(seq, imu=ImuSeries(seq.imu.t_ns, np.degrees(seq.imu.gyro_radps), seq.imu.acc_mps2)))
    assert main(["inspect", "x", "--json", "--ignore", "GYRO_DEGPS"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["verdict"] == "ok"
    g = next(f for f in report["findings"] if f["code"] == "GYRO_DEGPS")
    assert g["severity"] == "info" and g["details"]["ignored"] is True


# ------------------------------------------------------------------------------------------ convert


def test_convert_refuses_unrepaired_problem_and_writes_nothing(fake, tmp_path, capsys):
    fake(unsorted_sequence())
    out = tmp_path / "stores" / "seq"
    assert main(["convert", "x", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "refusing to convert" in err[0] and "NON_MONOTONIC (imu)" in err[0] and "DUPLICATE_STAMPS (imu)" in err[0]
    assert "--repair drop-duplicates,sort" in err[0]
    assert not out.exists() and not out.parent.exists()
    # a partial repair is still refused
    assert main(["convert", "x", "--out", str(out), "--repair", "sort"]) == 2
    assert "--repair drop-duplicates" in capsys.readouterr().err
    assert not out.exists()


def test_convert_refuses_fatal_even_with_all_repairs(fake, tmp_path, capsys):
    late = make_poses(t0_ns=T0_NS + 1000 * 10**9)
    fake(Sequence("x", imu=make_imu(), poses={"vicon0": late}))
    out = tmp_path / "seq"
    assert main(["convert", "x", "--out", str(out), "--repair", "all"]) == 2
    err = capsys.readouterr().err
    assert "NO_TIME_OVERLAP (poses/vicon0)" in err and "choose a pose stream recorded at the same time" in err
    assert not out.exists()


def test_convert_repairs_and_round_trips(fake, tmp_path, capsys):
    seq = unsorted_sequence()
    seq.findings = [Finding("PARSE_SKIPPED_LINES", Severity.WARNING, "imu", "skipped 1 line",
                            {"count": 1, "lines": [5], "file": "data.csv"})]
    fake(seq)
    out = tmp_path / "seq"
    assert main(["convert", "x", "--out", str(out), "--name", "renamed", "--repair", "sort,drop-duplicates"]) == 0
    stdout = capsys.readouterr().out
    assert stdout.startswith(f"wrote {out} (synth: imu 2000 rows")
    assert "repaired: imu: sorted 2001 rows by time (1 backward steps)" in stdout
    assert "repaired: imu: dropped 1 rows with repeated stamps (kept the first)" in stdout
    assert "warning: PARSE_SKIPPED_LINES" in stdout
    back = read_store(out)
    clean = make_sequence()
    np.testing.assert_array_equal(back.imu.t_ns, clean.imu.t_ns)
    np.testing.assert_array_equal(back.imu.gyro_radps, clean.imu.gyro_radps)
    np.testing.assert_array_equal(back.poses["vicon0"].quat_wxyz, clean.poses["vicon0"].quat_wxyz)
    assert back.metadata["repairs"] == ["imu: sorted 2001 rows by time (1 backward steps)",
                                        "imu: dropped 1 rows with repeated stamps (kept the first)"]
    before = {f["code"] for f in back.metadata["findings_before_repair"]}
    assert {"NON_MONOTONIC", "DUPLICATE_STAMPS"} <= before
    codes = [f.code for f in back.findings]
    assert codes[0] == "PARSE_SKIPPED_LINES" and "NON_MONOTONIC" not in codes and "RATE" in codes
    assert back.findings[0].details["count"] == 1


def test_convert_pose_only_needs_flag(fake, tmp_path, capsys):
    fake(Sequence("p", poses={"vicon0": make_poses()}))
    out = tmp_path / "p"
    assert main(["convert", "x", "--out", str(out)]) == 2
    assert "--allow-pose-only" in capsys.readouterr().err
    assert not out.exists()
    assert main(["convert", "x", "--out", str(out), "--allow-pose-only"]) == 0
    back = read_store(out)
    assert back.imu is None and len(back.poses["vicon0"]) == 1000


def test_convert_unknown_repair_is_an_error(fake, tmp_path, capsys):
    fake(make_sequence())
    assert main(["convert", "x", "--out", str(tmp_path / "s"), "--repair", "sorted"]) == 2
    assert "unknown repair 'sorted'" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_ingest_library_function(fake, tmp_path):
    fake(unsorted_sequence())
    with pytest.raises(FatalCheckError, match=r"DUPLICATE_STAMPS \(imu\): imu has 1 repeated stamps .*; rerun with --repair drop-duplicates"):
        ingest("x", tmp_path / "a", repairs=[Repair.SORT], reader_kwargs={"name": "n"}, check_options=CheckOptions())
    assert not (tmp_path / "a").exists()
    seq = ingest("x", tmp_path / "a", repairs={"sort", Repair.DROP_DUPLICATES}, reader_kwargs={"name": "n"})
    assert len(seq.imu) == 2000
    assert read_store(tmp_path / "a").metadata["source_path"] == "x"


# ------------------------------------------------------------------------------------------ real readers


def _write_asl_imu(root: Path, t_ns: np.ndarray, gyro: np.ndarray, acc: np.ndarray) -> Path:
    d = root / "mav0" / "imu0"
    d.mkdir(parents=True)
    lines = ["#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
             "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"]
    lines += [f"{t}," + ",".join(repr(float(v)) for v in (*g, *a)) for t, g, a in zip(t_ns, gyro, acc)]
    (d / "data.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return root


def test_asl_file_with_unsorted_degps_rows_inspected_and_converted(tmp_path, capsys):
    imu = make_imu(duration_s=5.0)
    idx = np.arange(len(imu))
    idx[[100, 101]] = idx[[101, 100]]
    idx = np.insert(idx, 50, 50)
    root = _write_asl_imu(tmp_path / "in", imu.t_ns[idx], np.degrees(imu.gyro_radps[idx]), imu.acc_mps2[idx])
    assert main(["inspect", str(root), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    codes = {f["code"]: f for f in report["findings"]}
    assert codes["NON_MONOTONIC"]["details"]["count"] == 1
    assert codes["DUPLICATE_STAMPS"]["details"]["count"] == 1
    assert codes["GYRO_DEGPS"]["details"]["rule"] == "p99_magnitude"
    assert report["verdict"] == "repairable"
    out = tmp_path / "store"
    assert main(["convert", str(root), "--out", str(out)]) == 2
    assert "--repair drop-duplicates,gyro-deg-to-rad,sort" in capsys.readouterr().err
    assert not out.exists()
    assert main(["convert", str(root), "--out", str(out), "--repair", "all"]) == 0
    back = read_store(out)
    np.testing.assert_array_equal(back.imu.t_ns, imu.t_ns)
    np.testing.assert_allclose(back.imu.gyro_radps, imu.gyro_radps, rtol=1e-12)
    np.testing.assert_array_equal(back.imu.acc_mps2, imu.acc_mps2)


@pytest.mark.parametrize("folder, keep_poses, rule, stream, ratio", [
    ("V1_01_easy", False, "p99_magnitude", None, None),  # the IMU alone
    ("V1_01_easy", True, "pose_rate_ratio", "poses/vicon0", (15, 70)),  # raw Vicon: differencing noise lowers it
    ("V1_02_medium_kimera_excerpt", True, "pose_rate_ratio", "ground_truth", (45, 70)),  # 180/pi = 57.3
])
def test_unit_heuristics_on_real_data(shared_data, folder, keep_poses, rule, stream, ratio):
    seq = pipeline.io.load_sequence(shared_data / "euroc" / folder)
    if not keep_poses:
        seq = replace(seq, poses={})
    assert detect_gyro_degps(seq) is None
    imu = seq.imu
    deg = replace(seq, imu=ImuSeries(imu.t_ns, np.degrees(imu.gyro_radps), imu.acc_mps2))
    hit = detect_gyro_degps(deg)
    assert hit is not None and hit["rule"] == rule
    if rule == "pose_rate_ratio":
        assert hit["pose_stream"] == stream
        assert ratio[0] < hit["ratio"] < ratio[1]
    assert detect_acc_in_g(imu.acc_mps2) is None
    assert detect_acc_in_g(imu.acc_mps2 / 9.80665) is not None


def test_inspect_mh01_reports_skipped_lines(shared_data, capsys):
    assert main(["inspect", str(shared_data / "euroc" / "MH_01_easy"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    skipped = [f for f in report["findings"] if f["code"] == "PARSE_SKIPPED_LINES"]
    assert len(skipped) == 1 and skipped[0]["details"]["count"] == 7
    assert skipped[0]["severity"] == "warning"
    imu = next(s for s in report["streams"] if s["stream"] == "imu")
    assert imu["count"] == 36820
    assert imu["rate_hz"] == pytest.approx(200.0)
    assert report["verdict"] == "ok"
    assert not any(f["code"] in ("GYRO_DEGPS", "ACC_IN_G", "SATURATION", "CLOCK_MISMATCH", "NO_TIME_OVERLAP")
                   for f in report["findings"])


def test_inspect_and_convert_v101(shared_data, tmp_path, capsys):
    src = shared_data / "euroc" / "V1_01_easy"
    assert main(["inspect", str(src)]) == 0
    out = capsys.readouterr().out
    imu_row = next(line for line in out.splitlines() if line.startswith("imu "))
    assert imu_row.split()[2] == "29120"
    assert "verdict: ok" in out
    store = tmp_path / "v101"
    assert main(["convert", str(src), "--out", str(store)]) == 0
    back = read_store(store)
    assert len(back.imu) == 29120
    assert back.imu.t_ns[0] == 1403715273262142976 and back.imu.t_ns[-1] == 1403715418857143040
    assert back.metadata["repairs"] == []


# ------------------------------------------------------------------------------------------ CLI


def test_commands_registered_are_the_modules_that_exist():
    import biasgt.cli.commands
    from biasgt.cli.app import COMMANDS, build_parser

    commands_dir = Path(biasgt.cli.commands.__file__).parent
    modules = {p.stem for p in commands_dir.glob("*.py") if not p.stem.startswith("_")}  # _args: shared flags
    assert {c.__name__.rsplit(".", 1)[1] for c in COMMANDS} == modules
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == modules


@pytest.mark.parametrize("flag, debug, info", [("", False, True), ("-v", True, True), ("-q", False, False)])
def test_verbose_and_quiet_change_the_log_level(tmp_path, flag, debug, info):
    """-v shows debug messages, -q hides the progress (info) messages (a real process: real stderr)."""
    poses = tmp_path / "poses.txt"
    poses.write_text("".join(f"{i * 0.01:.2f} 0 0 0 0 0 0 1\n" for i in range(50)), encoding="utf-8")
    cmd = [sys.executable, "-m", "biasgt.cli", *([flag] if flag else []), "inspect", str(poses)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(Path(pipeline.ingest.__file__).parents[1])})
    assert ("DEBUG pipeline.io: loading" in proc.stderr) is debug, proc.stderr
    assert ("INFO pipeline.io.tum: read TUM" in proc.stderr) is info, proc.stderr
