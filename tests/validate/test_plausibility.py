"""Plausibility checks: an impossible bias or a frame mismatch FAILs the verdict, with the reason first."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.geometry.pose_transform import poses_in_imu_frame
from pipeline.io import load_sequence
from validation.plausibility import (PlausibilityCheck, bias_range_findings, frame_swap_findings, gravity_findings,
                                     rotation_findings)

ROTATED = np.eye(4)
ROTATED[:3, :3] = Rotation.from_euler("x", 90, degrees=True).as_matrix()  # y and z swapped (one reversed)


@pytest.fixture(scope="module")
def sim60(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 60-s handheld simulation (mocap poses of the IMU itself: T_imu_pose is the identity)."""
    from biasgt.cli.app import main

    out = tmp_path_factory.mktemp("plaus") / "sim"
    assert main(["-q", "simulate", "--duration", "60", "--seed", "1", str(out)]) == 0
    return out


def test_bias_beyond_the_sensor_range_is_impossible_and_sensor_yaml_sets_the_range(sim60: Path, tmp_path: Path) -> None:
    bias = np.zeros((10, 6))
    bias[4, 4] = 12.3  # m/s^2, more than g
    (found,) = bias_range_findings(bias, 0.35, 2.0, "the default")
    assert found.check is PlausibilityCheck.BIAS_RANGE and "12.3 m/s^2 on axis y" in found.text
    assert bias_range_findings(bias, 0.35, 20.0, "sensor.yaml") == []
    bias[2, 2] = -0.5  # rad/s
    assert [f.text.split(" bias reaches")[0] for f in bias_range_findings(bias, 0.35, 2.0, "x")] == [
        "impossible bias: the gyro", "impossible bias: the accelerometer"]
    # the range comes from sensor.yaml when it gives one, and says so
    yaml_path = sim60 / "mav0" / "imu0" / "sensor.yaml"
    text = yaml_path.read_text()
    try:
        yaml_path.write_text(text + "\naccelerometer_bias_max: 20.0\ngyroscope_bias_max: 0.1\n")
        cal = load_sequence(sim60).calibration
    finally:
        yaml_path.write_text(text)
    assert cal.acc_bias_max_mps2 == 20.0 and cal.gyro_bias_max_radps == 0.1
    assert cal.sources["acc_bias_max_mps2"] == str(yaml_path)
    default = load_sequence(sim60).calibration
    assert (default.gyro_bias_max_radps, default.acc_bias_max_mps2) == (0.35, 2.0)


def test_gravity_tilted_in_a_level_frame_or_changing_is_a_frame_mismatch() -> None:
    g = 9.81 * np.array([0.0, math.sin(math.radians(30)), -math.cos(math.radians(30))])
    (tilt,) = gravity_findings({"gravity_world_mps2": g.tolist(), "gravity": {"estimated": True}}, "mocap")
    assert tilt.check is PlausibilityCheck.GRAVITY_TILT and tilt.value == pytest.approx(30.0)
    assert gravity_findings({"gravity_world_mps2": g.tolist()}, "vio") == []  # a VIO frame need not be level
    level = {"gravity_world_mps2": [0.0, 0.0, -9.81], "gravity": {"segment_max_tilt_change_rad": math.radians(39)}}
    (change,) = gravity_findings(level, "vio")
    assert change.value == pytest.approx(39.0) and "changes direction by 39.0 deg" in change.text
    assert gravity_findings({"gravity_world_mps2": [0.05, 0.0, -9.81]}, "mocap") == []


def test_a_swapped_frame_shows_in_the_gyro_coherence_and_the_rotation_residual(sim60: Path) -> None:
    seq = load_sequence(sim60)
    poses = seq.poses["mocap0"]
    assert frame_swap_findings(seq, poses, np.eye(4), 0.0) == []
    (swap,) = frame_swap_findings(seq, poses, ROTATED, 0.0)
    assert swap.check is PlausibilityCheck.FRAME_SWAP and swap.value > 0.9 and "coherence 1.00" in swap.text
    # the IMU trajectory is the poses (T_imu_pose = I); judged against a wrong extrinsic it is 90 deg off
    traj = poses_in_imu_frame(poses)
    assert rotation_findings(traj, poses, np.eye(4), 0.0, relative=False) == []
    (absolute,) = rotation_findings(traj, poses, ROTATED, 0.0, relative=False)
    assert absolute.value == pytest.approx(90.0, abs=0.01)
    (relative,) = rotation_findings(traj, poses, ROTATED, 0.0, relative=True)
    assert relative.value > 1.0 and "over 1 s" in relative.text


def test_wheel_odometry_with_the_identity_extrinsic_fails_with_a_plausibility_reason(shared_data: Path,
                                                                                      tmp_path: Path, capsys) -> None:
    """The Husky bag: IMU against wheel odometry, recovered with the error message's own fix."""
    from biasgt.cli.app import main

    bag = shared_data / "ros_bags" / "robot_localization_test" / "test1.bag"
    # refused by default (the frames disagree), nothing written; kept on request, for the verdict to FAIL it
    assert main(["-q", "recover", str(bag), "--extrinsic", "known", "--out", str(tmp_path / "rec")]) == 2
    assert "disagree about the body frame" in capsys.readouterr().err and not (tmp_path / "rec").exists()
    assert main(["-q", "recover", str(bag), "--extrinsic", "known", "--keep-frame-disagreement",
                 "--out", str(tmp_path / "rec")]) == 0
    capsys.readouterr()
    rc = main(["validate", str(bag), "--recovery", str(tmp_path / "rec"), "--crossval", "off",
               "--out", str(tmp_path / "val")])
    out = capsys.readouterr().out
    assert rc == 1 and "verdict: FAIL" in out
    summary = json.loads((tmp_path / "val" / "validation.json").read_text())
    assert summary["reasons"][0].startswith("impossible bias: the accelerometer bias reaches")
    checks = {x["check"] for x in summary["plausibility"]}
    assert {"bias_range", "gravity_tilt", "frame_swap"} <= checks
    assert main(["report", "--ingest", str(bag), "--recovery", str(tmp_path / "rec"), "--validation",
                 str(tmp_path / "val"), "--out", str(tmp_path / "q.html")]) == 0
    html = (tmp_path / "q.html").read_text()
    assert f"is physically impossible ({len(checks)} plausibility findings: bias range, gravity tilt" in html
    # its 1-s errors are said not to count, not as a second sentence in its favour
    assert "so its 1-s errors do not count for it (it integrates" in html and "; The recovered bias" not in html
    assert f"gyro axes against the poses&#x27; rotation): {len(checks)} findings." in html
    for check in checks:  # the figure or table that triggered each check is framed in red
        assert f'class="implausible" data-check="{check}"' in html


def test_the_report_note_calls_a_swapped_frame_a_frame_mismatch(sim60: Path) -> None:
    from recovery.intrinsics.gyro_consistency import rate_coupling

    seq = load_sequence(sim60)
    sentence = rate_coupling(seq.imu, seq.poses["mocap0"], R_imu_pose=ROTATED[:3, :3]).sentence()
    assert "frame mismatch" in sentence and "scale error" not in sentence
    assert "frame mismatch" not in rate_coupling(seq.imu, seq.poses["mocap0"]).sentence()
