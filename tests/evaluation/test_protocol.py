"""The evaluation's protocol choices (the paper's): the random-walk oracle, the window alignment to the
ground-truth state's stamps, the dataset's own bias row and the stated gravity, each checked against an
independent computation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from independent import rk4_integrate
from pipeline.errors import ConfigError, InputFormatError
from pipeline.store import read_store
from training.rows.baselines import random_walk_oracle, random_walk_paper, state_bias
from training.config import EvalGravity, OracleWalk
from training.evaluation.evaluate import EvaluationConfig, evaluate_reference, load_test_windows
from training.data.windows import state_bias_at
from window_data import GRAVITY, RW, make_window_dataset

PAPER = EvaluationConfig(gravity="nominal", oracle_random_walk="sensor")
NOMINAL_GRAVITY_MPS2 = np.array([0.0, 0.0, -9.81])


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_window_dataset(tmp_path_factory.mktemp("protocol"), splits={"train": 1, "test": 2}, duration_s=6.0)


def _store(data: Path, name: str):
    return read_store(data.parent / "stores" / name)


def test_windows_are_aligned_to_the_ground_truth_state_stamps(data):
    """Each window's start / end states and state bias are the ground-truth state's at the window's own
    first / last IMU stamp (the simulator's state is stamped on the IMU clock)."""
    w = load_test_windows(data, PAPER)
    for name in w.sequences():
        gt = _store(data, name).ground_truth
        items = w.items(np.flatnonzero(w.sequence == name))
        dt_ns = np.round(items["dt_s"].numpy() * 1e9).astype(np.int64)
        t = items["t0_ns"].numpy()[:, None] + np.concatenate([np.zeros((len(dt_ns), 1), np.int64),
                                                               np.cumsum(dt_ns, axis=1)], axis=1)
        assert np.all(t[:, -1] - t[:, 0] == 1_000_000_000)  # 1-s windows, stamps span exactly window_s
        k = np.searchsorted(gt.t_ns, t)
        np.testing.assert_array_equal(gt.t_ns[k], t)  # every window stamp is a ground-truth stamp
        k0, k1 = k[:, 0], k[:, -1]
        np.testing.assert_allclose(items["start_p"].numpy(), gt.p_m[k0], atol=1e-9)
        np.testing.assert_allclose(items["end_p"].numpy(), gt.p_m[k1], atol=1e-9)
        np.testing.assert_allclose(items["start_v"].numpy(), gt.v_mps[k0], atol=1e-6)
        R0 = Rotation.from_quat(gt.quat_wxyz[k0][:, [1, 2, 3, 0]]).as_matrix()
        np.testing.assert_allclose(items["start_R"].numpy(), R0, atol=1e-9)
        state = np.concatenate([gt.bias_gyro_radps[k], gt.bias_acc_mps2[k]], axis=-1)
        np.testing.assert_allclose(items["state_bias"].numpy(), state, atol=1e-12)


def test_state_bias_between_and_outside_the_ground_truth_stamps(data):
    seq = _store(data, "test0")
    gt = seq.ground_truth
    mid = (gt.t_ns[10:12].sum() // 2, gt.t_ns[0] - 1, gt.t_ns[-1] + 1)
    b = state_bias_at(seq, np.asarray(mid))
    expect = 0.5 * (np.r_[gt.bias_gyro_radps[10], gt.bias_acc_mps2[10]] + np.r_[gt.bias_gyro_radps[11],
                                                                                gt.bias_acc_mps2[11]])
    np.testing.assert_allclose(b[0], expect, rtol=1e-12)
    assert np.all(np.isnan(b[1:]))


def test_state_bias_row_is_the_ground_truth_state_bias(data):
    row = evaluate_reference("state_bias", data, config=PAPER)
    label = evaluate_reference("ground_truth", data, config=PAPER)
    assert row.summary.kind == "oracle"
    # the labels are the simulator's truth at keyframes every 10 samples: both rows are near-perfect
    assert row.summary.row().average.prmse_m == pytest.approx(label.summary.row().average.prmse_m, abs=2e-3)


def test_oracle_paths_and_selection_equal_an_independent_computation(data):
    """The paper's oracle: the ground-truth state's bias at each window start, the sensor's own random
    walks, 50 candidate walks, the one with the smallest end-position error kept."""
    w = load_test_windows(data, PAPER)
    name = "test0"
    sensor = _store(data, name).calibration
    np.testing.assert_allclose(w.random_walk[name], [sensor.gyro_random_walk] * 3 + [sensor.acc_random_walk] * 3)
    assert not np.allclose(w.random_walk[name], [RW[0]] * 3 + [RW[1]] * 3)  # not the recovery's
    items = w.items(np.flatnonzero(w.sequence == name)[:3])
    items["state_bias"] = items["state_bias"] + 0.02  # a start bias the labels do not have
    B, T, _ = items["bias"].shape
    rw = np.tile(w.random_walk[name], (B, 1))
    K, seed = 50, 5
    out = random_walk_oracle(items, random_walk=rw, state_bias=items["state_bias"],
                             gravity_mps2=w.gravity_mps2[name], rng=np.random.default_rng(seed), candidates=K)
    np.testing.assert_array_equal(w.gravity_mps2[name], NOMINAL_GRAVITY_MPS2)
    # independent: the walks step by step from the same standard normals, each integrated by RK4
    normals = np.random.default_rng(seed).standard_normal((B, K, T - 1, 6))
    dt = items["dt_s"].numpy()
    start = items["state_bias"].numpy()[:, 0]
    imu = items["imu"].numpy()
    q0 = Rotation.from_matrix(items["start_R"].numpy()).as_quat(scalar_first=True)
    for b in range(B):
        paths = np.empty((K, T, 6))
        paths[:, 0] = start[b]
        for j in range(T - 1):
            paths[:, j + 1] = paths[:, j] + rw[b] * np.sqrt(dt[b, j]) * normals[b, :, j]
        corrected = imu[b][None] - paths
        _, _, p = rk4_integrate(corrected[..., :3], corrected[..., 3:], float(dt[b].mean()), np.repeat(q0[b:b + 1], K, 0),
                                np.repeat(items["start_v"].numpy()[b:b + 1], K, 0),
                                np.repeat(items["start_p"].numpy()[b:b + 1], K, 0), gravity_mps2=NOMINAL_GRAVITY_MPS2)
        err = np.linalg.norm(p - items["end_p"].numpy()[b], axis=1)
        chosen = int(np.argmin(np.abs(paths - out[b, 0][None]).max(axis=(1, 2))))
        np.testing.assert_allclose(out[b, 0], paths[chosen], rtol=0, atol=1e-12)  # one of the 50 walks
        assert err[chosen] <= err.min() + 1e-6  # the best of them (up to the two integrators' difference)


def test_oracle_with_the_recoverys_walks_and_the_label_start_when_no_state_bias(data):
    w = load_test_windows(data, EvaluationConfig(oracle_random_walk="recovery"))
    np.testing.assert_allclose(w.random_walk["test0"], [RW[0]] * 3 + [RW[1]] * 3)
    items = w.items(np.arange(2))
    del items["state_bias"]
    out = random_walk_oracle(items, state_bias=None,
                             random_walk=np.tile(w.random_walk["test0"], (2, 1)), gravity_mps2=w.gravity_mps2["test0"],
                             rng=np.random.default_rng(0), candidates=4)
    np.testing.assert_array_equal(out[:, 0, 0], items["bias"].numpy()[:, 0])
    with pytest.raises(InputFormatError, match="sensor_random_walk") as exc:  # a dataset cut before it was kept
        random_walk_oracle(items, random_walk=np.full((2, 6), np.nan), state_bias=None,
                           gravity_mps2=w.gravity_mps2["test0"], rng=np.random.default_rng(0))
    assert "\n" not in str(exc.value)
    with pytest.raises(InputFormatError, match="state_bias") as exc:
        state_bias(items, state_bias=np.full(items["bias"].shape, np.nan))  # a sequence without a GT state
    assert "\n" not in str(exc.value)


def test_gravity_is_a_stated_choice(data):
    nominal = load_test_windows(data, PAPER)
    recovered = load_test_windows(data, EvaluationConfig(gravity="recovered"))
    for name in nominal.sequences():
        assert nominal.gravity_source[name] == "nominal" and recovered.gravity_source[name] == "recovery"
        np.testing.assert_array_equal(nominal.gravity_mps2[name], NOMINAL_GRAVITY_MPS2)
        np.testing.assert_array_equal(recovered.gravity_mps2[name], GRAVITY)
    s = evaluate_reference("zero", data, config=PAPER).summary
    assert "gravity: nominal" in s.protocol and "oracle random walk: sensor" in s.protocol
    assert set(s.gravity_source.values()) == {"nominal"}
    assert PAPER.gravity is EvalGravity.NOMINAL and PAPER.oracle_random_walk is OracleWalk.SENSOR
    assert EvaluationConfig.from_mapping(PAPER.to_dict()) == PAPER
    with pytest.raises(ConfigError, match="gravity") as exc:
        EvaluationConfig.from_mapping({"gravity": "earth"})
    assert "\n" not in str(exc.value) and "nominal" in str(exc.value)


def test_real_euroc_windows_take_the_ground_truth_state_interpolated_to_their_stamps(shared_data):
    """MH_04: EuRoC's ground-truth stamps are not all on the IMU clock's grid (about a quarter differ by
    ~100 ns); the windows' start / end states and state bias are that state interpolated to the windows'
    own IMU stamps (scipy's Slerp and interp1d as the independent reference), and every window spans 1 s
    of IMU samples inside the state's span."""
    from scipy.interpolate import interp1d
    from scipy.spatial.transform import Slerp

    from pipeline.io import load_sequence
    from validation.validate import ValidationConfig, build_reference, plan_windows

    seq = load_sequence(shared_data / "euroc" / "MH_04_difficult")
    gt = seq.ground_truth
    assert not np.isin(gt.t_ns, seq.imu.t_ns).all()  # the interpolation is needed
    cfg = ValidationConfig(window_s=1.0, overlap=0.5)
    plan = plan_windows(seq.imu, cfg)
    ref = build_reference(seq, config=cfg)
    s = plan.starts[plan.keep & ref.valid[plan.starts] & ref.valid[plan.starts + plan.n]]
    assert plan.n == 200 and len(s) > 150
    t_s, t_e = seq.imu.t_ns[s], seq.imu.t_ns[s + plan.n]
    assert np.all(np.abs(t_e - t_s - 1_000_000_000) < 1_000)  # 200 intervals of 5 ms
    assert t_s[0] >= gt.t_ns[0] and t_e[-1] <= gt.t_ns[-1]
    x = (gt.t_ns - gt.t_ns[0]).astype(float)
    rel = lambda t: (t - gt.t_ns[0]).astype(float)  # noqa: E731
    slerp = Slerp(x, Rotation.from_quat(gt.quat_wxyz[:, [1, 2, 3, 0]]))
    for t, k in ((t_s, s), (t_e, s + plan.n)):
        np.testing.assert_allclose(ref.R[k], slerp(rel(t)).as_matrix(), atol=1e-9)
        np.testing.assert_allclose(ref.p[k], interp1d(x, gt.p_m, axis=0)(rel(t)), atol=1e-9)
        np.testing.assert_allclose(ref.v[k], interp1d(x, gt.v_mps, axis=0)(rel(t)), atol=1e-9)
    stamps = seq.imu.t_ns[s[:, None] + np.arange(plan.n + 1)]
    bias = interp1d(x, np.hstack([gt.bias_gyro_radps, gt.bias_acc_mps2]), axis=0)(rel(stamps))
    np.testing.assert_allclose(state_bias_at(seq, stamps), bias, atol=1e-12)


def test_paper_walks_step_by_sigma_over_sqrt_dt_and_are_chosen_by_position_and_rotation(data):
    """The paper's random-walk column as its figures imply: per-sample increments sigma / sqrt(h) and the walk
    with the smallest 3 x position error [m] + rotation error [deg] kept, checked against the walks built
    step by step here and integrated by an independent RK4."""
    from training.rows.baselines import PAPER_POSITION_WEIGHT

    w = load_test_windows(data, PAPER)
    name = "test0"
    items = w.items(np.flatnonzero(w.sequence == name)[:3])
    B, T, _ = items["bias"].shape
    rw = np.tile(w.random_walk[name], (B, 1))
    K, seed = 20, 7
    out = random_walk_paper(items, random_walk=rw, state_bias=items["state_bias"],
                            gravity_mps2=w.gravity_mps2[name], rng=np.random.default_rng(seed), candidates=K)
    normals = np.random.default_rng(seed).standard_normal((B, K, T - 1, 6))
    dt, imu = items["dt_s"].numpy(), items["imu"].numpy()
    start = items["state_bias"].numpy()[:, 0]
    q0 = Rotation.from_matrix(items["start_R"].numpy()).as_quat(scalar_first=True)
    end_R = Rotation.from_matrix(items["end_R"].numpy())
    for b in range(B):
        paths = np.empty((K, T, 6))
        paths[:, 0] = start[b]
        for j in range(T - 1):
            paths[:, j + 1] = paths[:, j] + rw[b] / np.sqrt(dt[b, j]) * normals[b, :, j]
        corrected = imu[b][None] - paths
        q, _, p = rk4_integrate(corrected[..., :3], corrected[..., 3:], float(dt[b].mean()), np.repeat(q0[b:b + 1], K, 0),
                                np.repeat(items["start_v"].numpy()[b:b + 1], K, 0),
                                np.repeat(items["start_p"].numpy()[b:b + 1], K, 0), gravity_mps2=NOMINAL_GRAVITY_MPS2)
        pos = np.linalg.norm(p - items["end_p"].numpy()[b], axis=1)
        rot = np.degrees((end_R[b].inv() * Rotation.from_quat(q, scalar_first=True)).magnitude())
        score = PAPER_POSITION_WEIGHT * pos + rot
        chosen = int(np.argmin(np.abs(paths - out[b, 0][None]).max(axis=(1, 2))))
        np.testing.assert_allclose(out[b, 0], paths[chosen], rtol=0, atol=1e-12)
        assert score[chosen] <= score.min() + 1e-4
        # the walk's spread over the window: sigma * sqrt(sum 1/h) per channel, 200x sigma * sqrt(1 s) at 200 Hz
        spread = (paths[:, -1] - paths[:, 0]).std(axis=0)
        np.testing.assert_allclose(spread / (rw[b] * np.sqrt((1.0 / dt[b]).sum())), 1.0, atol=0.5)
