"""A rig's usual faults, each handled or named, on the project's simulator and on the independent generator.

Each fault is written into the files of an ASL recording (:mod:`rig_faults`), then ``biasgt inspect`` and
``biasgt recover`` (or :func:`recovery.recover.recover`) run on it: a mocap clock seconds off the IMU's,
positions in millimetres, a 30-s pose dropout, occluded frames written as the origin with the identity
orientation, frames that disagree (quaternions w-last, swapped or flipped IMU axes), IMU stamps in
milliseconds. A fault ``recover`` handles comes back with the truth's values; one it refuses ends in one
line naming the file or stream, the fault and the fix, exit 2, nothing written; ``inspect`` names every one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import rig_faults as rf
from biasgt.cli.app import main
from pipeline.io import load_sequence
from recovery.config import RecoveryConfig
from recovery.frame.check import frame_disagreement
from recovery.outputs import read_report
from recovery.recover import recover
from recovery_sim import FAST

pytestmark = pytest.mark.xdist_group("rig_faults")


def _inspect(root: Path, capsys) -> dict[str, dict]:
    """``biasgt inspect --json``: the findings by code."""
    import json

    assert main(["inspect", str(root), "--json"]) in (0, 1)
    return {f["code"]: f for f in json.loads(capsys.readouterr().out)["findings"]}


def _refused(args: list[str], out: Path, capsys) -> str:
    """``biasgt`` refusing: exit 2, one error line (returned), no traceback, nothing written."""
    rc = main([*args, "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert not out.exists() and not list(out.parent.glob(out.name + ".*"))
    return lines[0]


# ----------------------------------------------------------------------------- clock offsets


@pytest.mark.parametrize("generator", rf.GENERATORS)
@pytest.mark.parametrize(("offset_s", "duration_s"), [(3.0, 40.0), (30.0, 75.0)])
def test_a_clock_seconds_off_is_found_within_5_ms(generator, offset_s, duration_s, tmp_path, capsys):
    """The whole-overlap search finds the offset, the fine one refines it: within 5 ms of the truth
    (before, the fine search's +-0.5 s missed it and the solve blamed the quaternion order)."""
    truth = rf.write_recording(generator, tmp_path / "rec", duration_s=duration_s, clock_offset_s=offset_s)
    finding = _inspect(tmp_path / "rec", capsys)["CLOCK_OFFSET"]
    assert finding["severity"] == "warning"
    assert f"--time-offset-s {finding['details']['offset_s']:.3f}" in finding["message"]
    assert abs(finding["details"]["offset_s"] - truth.clock_offset_s) < 0.05
    assert main(["recover", str(tmp_path / "rec"), "--out", str(tmp_path / "out")]) == 0
    report = read_report(tmp_path / "out").data
    assert abs(report["pose_time_offset_s"] - truth.clock_offset_s) < 5e-3
    assert report["pose_time_offset_wide_search"]["used"] is True


# ----------------------------------------------------------------------------- positions in millimetres


@pytest.mark.parametrize("generator", rf.GENERATORS)
def test_positions_in_millimetres_are_named_and_repaired(generator, tmp_path, capsys):
    truth = rf.write_recording(generator, tmp_path / "rec", duration_s=30.0)
    rf.positions_scaled(tmp_path / "rec", 1000.0)
    finding = _inspect(tmp_path / "rec", capsys)["POSITION_UNIT"]
    assert finding["severity"] == "repairable" and finding["details"]["factor_to_m"] == 1e-3
    line = _refused(["recover", str(tmp_path / "rec")], tmp_path / "out", capsys)
    assert "positions look like millimetres" in line and "--repair positions-to-m" in line
    assert main(["recover", str(tmp_path / "rec"), "--repair", "positions-to-m", "--out", str(tmp_path / "out")]) == 0
    report = read_report(tmp_path / "out").data
    assert abs(report["pose_time_offset_s"] - truth.clock_offset_s) < 5e-3


def test_positions_in_centimetres_are_named(tmp_path, capsys):
    rf.write_recording("independent", tmp_path / "rec", duration_s=30.0)
    rf.positions_scaled(tmp_path / "rec", 100.0)
    assert _inspect(tmp_path / "rec", capsys)["POSITION_UNIT"]["details"]["unit"] == "centimetres"


def test_a_recording_in_metres_has_no_rig_finding(tmp_path, capsys):
    rf.write_recording("sim", tmp_path / "rec", duration_s=30.0)
    codes = set(_inspect(tmp_path / "rec", capsys))
    assert not codes & {"CLOCK_OFFSET", "POSITION_UNIT", "FRAME_DISAGREEMENT", "POSE_PLACEHOLDERS", "STAMP_UNIT"}


# ----------------------------------------------------------------------------- a long dropout


@pytest.mark.parametrize("generator", rf.GENERATORS)
def test_a_30_s_dropout_in_120_s_recovers_the_rest_with_the_sigma_grown_across_it(generator, tmp_path, capsys):
    truth = rf.write_recording(generator, tmp_path / "rec", duration_s=120.0)
    rf.drop_poses(tmp_path / "rec", 45.0, 30.0)
    gaps = _inspect(tmp_path / "rec", capsys)["GAPS"]
    assert gaps["details"]["gaps"][0]["duration_s"] == pytest.approx(30.0, abs=0.05)
    res = recover(load_sequence(tmp_path / "rec"))
    t_s = (res.t_ns - res.t_ns[0]) / 1e9
    gyro_err, acc_err = truth.bias_errors(res)
    z = np.hstack([gyro_err / res.bias_gyro_std_radps, acc_err / res.bias_acc_std_mps2])
    assert np.sqrt(np.mean(z**2)) < 2.0  # the bias around and across the gap within its sigma
    inside, outside = (t_s > 55) & (t_s < 65), (t_s < 40) | (t_s > 80)
    sigma = np.hstack([res.bias_gyro_std_radps, res.bias_acc_std_mps2])
    assert np.all(np.median(sigma[inside], axis=0) > 1.1 * np.median(sigma[outside], axis=0))  # 1.2-1.6x measured


def test_a_degenerate_solve_names_a_long_pose_gap(monkeypatch, tmp_path):
    """Where the graph is singular after all, the error names the pause with its times."""
    import recovery.recover as rec_module
    from pipeline.errors import RecoveryError

    rf.write_recording("sim", tmp_path / "rec", duration_s=40.0)
    rf.drop_poses(tmp_path / "rec", 10.0, 12.0)

    def singular(*args, **kwargs):
        raise RuntimeError("Indeterminant linear system detected while working near variable 7")

    monkeypatch.setattr(rec_module, "_recover", singular)
    with pytest.raises(RecoveryError) as info:
        recover(load_sequence(tmp_path / "rec"), config=RecoveryConfig(intrinsics="off"))
    assert "pose stream 'mocap0' pauses for 12.0 s (t=10.0..22.0 s after its start)" in str(info.value)


# ----------------------------------------------------------------------------- occluded frames


@pytest.mark.parametrize("generator", rf.GENERATORS)
def test_occlusion_placeholders_are_named_and_rejected_as_outliers(generator, tmp_path, capsys):
    truth = rf.write_recording(generator, tmp_path / "rec", duration_s=30.0)
    rf.placeholders(tmp_path / "rec", 15.0, 1.0)
    finding = _inspect(tmp_path / "rec", capsys)["POSE_PLACEHOLDERS"]
    assert finding["details"]["count"] == 100 and "(t=15.000..15.990 s)" in finding["message"]
    res = recover(load_sequence(tmp_path / "rec"))
    assert res.report["placeholders_rejected"] == 100
    gyro_err, acc_err = truth.bias_errors(res)
    assert np.sqrt(np.mean((acc_err / res.bias_acc_std_mps2) ** 2)) < 2.0
    assert np.sqrt(np.mean((gyro_err / res.bias_gyro_std_radps) ** 2)) < 2.0


# ----------------------------------------------------------------------------- frames that disagree

FRAME_FAULTS = {
    "quaternion_w_last": rf.quaternion_w_last,
    "acc_x_z_swapped": lambda root: rf.swap_imu_columns(root, "acc", 0, 2),
    "gyro_x_y_swapped": lambda root: rf.swap_imu_columns(root, "gyro", 0, 1),
    "acc_z_flipped": lambda root: rf.flip_imu_axis(root, "acc", 2),
}


@pytest.mark.parametrize("generator", rf.GENERATORS)
def test_inspect_flags_every_input_the_solve_refuses_for_its_frames(generator, tmp_path, capsys):
    """On the same inputs: inspect's FRAME_DISAGREEMENT against the solve's own rule
    (:func:`recovery.frame.check.frame_disagreement`, the solve kept past the screen), and recover's refusal."""
    flagged, refused = {}, {}
    for case in ["correct", *FRAME_FAULTS]:
        root = tmp_path / case
        rf.write_recording(generator, root, duration_s=25.0, seed=1)
        if case != "correct":
            FRAME_FAULTS[case](root)
        flagged[case] = "FRAME_DISAGREEMENT" in _inspect(root, capsys)
        kept = recover(load_sequence(root), config=RecoveryConfig(**FAST, keep_frame_disagreement=True))
        refused[case] = frame_disagreement(kept) is not None
    assert not flagged["correct"] and not refused["correct"]
    assert all(flagged[c] for c in refused if refused[c]), (flagged, refused)
    assert all(flagged[c] for c in FRAME_FAULTS), flagged


@pytest.mark.parametrize(("case", "cause"), [("quaternion_w_last", "the pose quaternion order"),
                                             ("acc_x_z_swapped", "the accelerometer's axis order")])
def test_recover_refuses_a_frame_mistake_before_solving(case, cause, tmp_path, capsys):
    rf.write_recording("independent", tmp_path / "rec", duration_s=25.0)
    FRAME_FAULTS[case](tmp_path / "rec")
    line = _refused(["recover", str(tmp_path / "rec")], tmp_path / "out", capsys)
    assert "the IMU and pose stream 'vicon0' disagree about the body frame" in line
    assert line.split("likely cause: ")[1].startswith(cause)


# ----------------------------------------------------------------------------- stamps in milliseconds


@pytest.mark.parametrize("generator", rf.GENERATORS)
def test_imu_stamps_in_milliseconds_are_named_and_repaired(generator, tmp_path, capsys):
    truth = rf.write_recording(generator, tmp_path / "rec", duration_s=30.0)
    rf.imu_stamps_in_ms(tmp_path / "rec")
    findings = _inspect(tmp_path / "rec", capsys)
    assert findings["STAMP_UNIT"]["details"]["unit"] == "milliseconds"
    assert "look like milliseconds (200 Hz)" in findings["STAMP_UNIT"]["message"]
    assert not {"TOO_SHORT", "IMU_RATE_MISMATCH"} & set(findings)
    line = _refused(["recover", str(tmp_path / "rec")], tmp_path / "out", capsys)
    assert "STAMP_UNIT (imu)" in line and "milliseconds" in line and "--repair stamps-to-ns" in line
    assert main(["recover", str(tmp_path / "rec"), "--repair", "stamps-to-ns", "--out", str(tmp_path / "out")]) == 0
    report = read_report(tmp_path / "out").data
    assert abs(report["pose_time_offset_s"] - truth.clock_offset_s) < 5e-3  # the ms rounding of the IMU stamps
