"""Bias recovery refusing what it cannot solve: bad input, degenerate problems, an unconverged optimiser."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.errors import RecoveryError
from pipeline.types import ImuSeries, PoseSeries, PoseSourceKind, Sequence
from recovery.config import RecoveryConfig
from recovery.recover import recover
from recovery_sim import FAST, bias_errors, sim_sequence


# ----------------------------------------------------------------------------- bad input


def _tiny_sequence(imu_t_s, pose_t_s, quat=None) -> Sequence:
    imu_t = (np.asarray(imu_t_s) * 1e9).astype(np.int64) + 10**18
    pose_t = (np.asarray(pose_t_s) * 1e9).astype(np.int64) + 10**18
    n = len(imu_t)
    imu = ImuSeries(imu_t, np.zeros((n, 3)), np.tile([0, 0, 9.81], (n, 1)))
    q = np.tile([1.0, 0, 0, 0], (len(pose_t), 1)) if quat is None else quat
    poses = PoseSeries(pose_t, np.zeros((len(pose_t), 3)), q, "marker", PoseSourceKind.MOCAP)
    return Sequence("tiny", imu=imu, poses={"mocap0": poses})


def test_no_overlap_is_a_recovery_error():
    seq = _tiny_sequence(np.arange(0, 10, 0.005), np.arange(100, 110, 0.01))
    with pytest.raises(RecoveryError, match="overlap"):
        recover(seq, config=RecoveryConfig(time_offset_mode="fixed"))


def test_too_few_poses():
    seq = _tiny_sequence(np.arange(0, 10, 0.005), np.arange(1, 1.1, 0.01))
    with pytest.raises(RecoveryError, match="min_poses"):
        recover(seq, config=RecoveryConfig(time_offset_mode="fixed"))


def test_missing_stream_and_missing_imu():
    seq = _tiny_sequence(np.arange(0, 10, 0.005), np.arange(1, 9, 0.01))
    with pytest.raises(Exception, match="nope"):
        recover(seq, pose_stream="nope")
    seq.imu = None
    with pytest.raises(RecoveryError, match="IMU"):
        recover(seq)


def test_imu_gap_refuse_and_split():
    sim = sim_sequence(30.0, seed=8)
    seq = sim.sequence
    t = seq.imu.t_ns
    keep = (t < t[0] + int(12e9)) | (t > t[0] + int(13e9))
    seq_gap = dataclasses.replace(seq, imu=seq.imu.take(keep))
    with pytest.raises(RecoveryError, match="gap"):
        recover(seq_gap, config=RecoveryConfig(**FAST, time_offset_mode="fixed", imu_gap_policy="refuse"))
    res = recover(seq_gap, config=RecoveryConfig(**FAST, time_offset_mode="fixed", compute_marginals=False))
    assert res.report["imu_pieces"] == 2
    assert any("gap" in w for w in res.warnings)
    inside = (res.t_ns > t[0] + int(12e9)) & (res.t_ns < t[0] + int(13e9))
    assert not inside.any()


def test_no_rotation_excitation_flags_extrinsic_unobservable():
    """Translation-only motion: the extrinsic rotation cannot be estimated -> warn and fall back."""
    sim = sim_sequence(25.0, seed=9, extrinsic_known=False)
    seq = sim.sequence
    ps = seq.poses["mocap0"]
    # the same positions with a constant orientation: IMU gyro = bias + noise only, f = a - g + bias
    t_s = (ps.t_ns - ps.t_ns[0]) / 1e9
    acc_w = np.stack([np.gradient(np.gradient(ps.p_m[:, c], t_s), t_s) for c in range(3)], 1)
    imu_t = seq.imu.t_ns
    tt = (imu_t - ps.t_ns[0]) / 1e9
    acc_i = np.stack([np.interp(tt, t_s, acc_w[:, c]) for c in range(3)], 1) + [0, 0, 9.81]
    rng = np.random.default_rng(0)
    gyro = 0.01 + rng.normal(0, 2e-3, (len(imu_t), 3))
    acc = acc_i + [0.1, -0.1, 0.05] + rng.normal(0, 2e-2, acc_i.shape)
    flat = PoseSeries(ps.t_ns, ps.p_m, np.tile([1.0, 0, 0, 0], (len(ps), 1)), ps.frame, ps.source_kind)
    seq2 = Sequence("flat", imu=ImuSeries(imu_t, gyro, acc), poses={"mocap0": flat})
    res = recover(seq2, config=RecoveryConfig(**FAST, time_offset_mode="fixed", extrinsic_mode="estimate",
                                               compute_marginals=False))
    assert res.report["extrinsic_rotation_observable"] is False
    assert any("unobservable" in w for w in res.warnings)
    assert res.report["T_imu_pose"]["quat_wxyz"] == [1.0, 0.0, 0.0, 0.0]


# ----------------------------------------------------------------------------- degenerate problems


def test_degenerate_problem_is_a_recovery_error(monkeypatch):
    """GTSAM's bare RuntimeError for an indeterminant system becomes a one-line RecoveryError."""
    import recovery.recover as rr
    from pipeline.errors import RecoveryError
    from pipeline.types import Sequence

    def boom(*a, **k):
        raise RuntimeError("\nIndeterminant linear system detected while working near variable\n"
                           "8070450532247928832 (Symbol: p0).\n")

    monkeypatch.setattr(rr, "_recover", boom)
    with pytest.raises(RecoveryError, match=r"degenerate \(Indeterminant linear system detected") as info:
        rr.recover(Sequence(name="flat"))
    assert "\n" not in str(info.value) and "--extrinsic known" in str(info.value)
    assert "--keyframe-rate" not in str(info.value)  # no odometry stream to thin out
    monkeypatch.setattr(rr, "_recover", lambda *a, **k: (_ for _ in ()).throw(RuntimeError("other bug")))
    with pytest.raises(RuntimeError, match="other bug"):
        rr.recover(Sequence(name="x"))


@pytest.mark.parametrize(("rate_hz", "changes", "expected", "absent"), [
    (50.0, {}, ["--keyframe-rate 10", "--extrinsic known", "--time-offset-s"], []),
    (10.0, {}, ["--extrinsic known", "--time-offset-s"], ["--keyframe-rate"]),  # 10-Hz odometry: already 10 Hz
    (10.0, {"extrinsic_mode": "known", "time_offset_mode": "fixed"}, ["varied motion", "motion capture"],
     ["--keyframe-rate", "--extrinsic known", "--time-offset-s"]),
])
def test_degenerate_hint_suggests_only_fixes_that_apply(rate_hz, changes, expected, absent) -> None:
    from pipeline.types import PoseSeries, PoseSourceKind, Sequence
    from recovery.config import RecoveryConfig
    from recovery.recover import degenerate_hint

    n = 50
    t_ns = 1_000_000_000 + np.arange(n, dtype=np.int64) * int(1e9 / rate_hz)
    odom = PoseSeries(t_ns, np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), "base_link", PoseSourceKind.VIO)
    hint = degenerate_hint(Sequence(name="odom", poses={"/odom": odom}), None, RecoveryConfig(**changes))
    for text in expected:
        assert text in hint, hint
    for text in absent:
        assert text not in hint, hint


# ----------------------------------------------------------------------------- optimiser


def test_an_optimiser_that_gives_up_far_from_an_optimum_is_refused():
    """Levenberg-Marquardt stopped where a Gauss-Newton step still predicts a large decrease is no optimum:
    refused with the cost and the decrease; at the optimum of the same graph (a prior's own value, whose
    cost is 0 in closed form) nothing is raised."""
    import gtsam

    from gtsam.symbol_shorthand import X

    from recovery.solver.factors import BuiltWindow
    from recovery.solver.graph import refuse_unconverged

    graph = gtsam.NonlinearFactorGraph()
    target = gtsam.Pose3(gtsam.Rot3.Rz(0.3), gtsam.Point3(1.0, 2.0, 3.0))
    graph.add(gtsam.PriorFactorPose3(X(0), target, gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    far = gtsam.Values()
    far.insert(X(0), gtsam.Pose3())
    built = BuiltWindow(graph, far, [], [], 0.0)
    order = gtsam.Ordering()
    order.push_back(X(0))
    with pytest.raises(RecoveryError, match="did not converge"):
        refuse_unconverged(built, far, order, graph.error(far))
    at = gtsam.Values()
    at.insert(X(0), target)
    assert graph.error(at) == pytest.approx(0.0, abs=1e-12)
    refuse_unconverged(built, at, order, graph.error(at))


# ----------------------------------------------------------------------------- frames that disagree


def _frame_cases() -> dict[str, Sequence]:
    """A correct 20-s simulation with pose outliers and dropouts, and two frame mistakes built from it."""
    seq = sim_sequence(20.0, seed=5, outliers=10, outlier_offset_m=0.1, dropouts=2, dropout_max_s=0.5).sequence
    swapped = dataclasses.replace(seq.imu, acc_mps2=seq.imu.acc_mps2[:, [2, 1, 0]])  # accelerometer x <-> z
    name, poses = next(iter(seq.poses.items()))
    w_last = dataclasses.replace(poses, quat_wxyz=poses.quat_wxyz[:, [1, 2, 3, 0]])  # xyzw read as wxyz
    return {"correct": seq, "acc_x_z_swapped": dataclasses.replace(seq, imu=swapped),
            "quaternion_w_last": dataclasses.replace(seq, poses={**seq.poses, name: w_last})}


@pytest.fixture(scope="module")
def frame_cases() -> dict[str, Sequence]:
    return _frame_cases()


@pytest.mark.parametrize(("case", "cause"), [("acc_x_z_swapped", "the accelerometer's axis order"),
                                             ("quaternion_w_last", "the pose quaternion order")])
def test_frames_that_disagree_are_refused_before_the_solve(frame_cases, case, cause):
    """The rig screen's fits (the gyro's rates against the poses', the specific force against the poses'
    attitude and acceleration) refuse a frame mistake before any solve, naming the likely cause first."""
    seq = frame_cases[case]
    with pytest.raises(RecoveryError) as info:
        recover(seq, config=RecoveryConfig(**FAST))
    text = str(info.value)
    assert "disagree about the body frame" in text and "\n" not in text
    assert text.split("likely cause: ")[1].startswith(cause)


@pytest.mark.parametrize(("case", "first_cause"), [("acc_x_z_swapped", "axis order"),
                                                   ("quaternion_w_last", "quaternion order")])
def test_the_solved_bias_shows_the_frame_mistake_too(frame_cases, case, first_cause):
    """Kept past the screen (``keep_frame_disagreement``), the solve itself shows the mistake: the true
    accelerometer bias of the simulation stays far below 0.3 g, the recovered one reaches a sizeable fraction
    of gravity, and :func:`recovery.frame.check.frame_disagreement` names the likely causes."""
    from recovery.frame.check import frame_disagreement

    seq = frame_cases[case]
    assert np.abs(seq.ground_truth.bias_acc_mps2).max() < 0.1 * 9.81  # the truth: a plausible bias
    text = frame_disagreement(recover(seq, config=RecoveryConfig(**FAST, keep_frame_disagreement=True)))
    assert "disagree about the body frame" in text and "accelerometer bias reaches" in text
    likely = text.split("likely cause: ")[1]
    assert "axis order" in likely and "quaternion order" in likely
    assert likely.index(first_cause) < likely.index("or the")  # the one the evidence points at comes first


def test_a_correct_recording_with_outliers_and_dropouts_passes_the_frame_check(frame_cases):
    res = recover(frame_cases["correct"], config=RecoveryConfig(**FAST))
    truth = frame_cases["correct"].ground_truth
    _, acc_err = bias_errors(res, truth)
    assert np.abs(acc_err).max() < 0.5  # recovered near the truth, and not refused


def test_the_frame_check_through_the_cli_writes_nothing(frame_cases, tmp_path, capsys):
    """``biasgt recover`` on an ASL folder whose accelerometer x and z columns are swapped: exit 2, one
    line, no output folder."""
    import pandas as pd

    from biasgt.cli.app import main
    from pipeline.sim.writer import write_simulation

    sim = sim_sequence(20.0, seed=5)
    write_simulation(sim, tmp_path / "rec")
    csv = tmp_path / "rec" / "mav0" / "imu0" / "data.csv"
    table = pd.read_csv(csv)
    ax, az = table.columns[4], table.columns[6]
    assert "a_RS_S_x" in ax and "a_RS_S_z" in az
    table[[ax, az]] = table[[az, ax]].to_numpy()
    table.to_csv(csv, index=False, float_format="%.17g")
    rc = main(["recover", str(tmp_path / "rec"), "--out", str(tmp_path / "out"), "--noise", "fixed"])
    err = capsys.readouterr().err
    assert rc == 2
    errors = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(errors) == 1 and "axis order" in errors[0] and "quaternion order" in errors[0], err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()
