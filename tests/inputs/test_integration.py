"""Tests of pipeline.geometry.so3_torch, so3_numpy and the IMU integration engine pipeline.geometry.integration (values asserted)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation, RotationSpline

from pipeline.errors import DataError
from pipeline.geometry.integration import IntegrationResult, IntegrationScheme, integrate, integrate_numpy
from pipeline.geometry.so3_numpy import (
    hat_np,
    matrix_to_quat_wxyz_np,
    quat_wxyz_to_matrix_np,
    rotation_angle_deg,
    so3_exp_np,
    so3_log_np,
)
from pipeline.geometry.so3_torch import hat, matrix_to_quat_wxyz, quat_wxyz_to_matrix, so3_exp, so3_log, vee

G = np.array([0.0, 0.0, -9.81])
RATE_HZ = 200.0
F64 = torch.float64


def _t(x: np.ndarray, dtype: torch.dtype = F64) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x), dtype=dtype)


# ============================================================================ so3


def _test_rotvecs() -> np.ndarray:
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(40, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate(
        [[0.0, 1e-12, 1e-8, 1e-5, 1e-3, 9.9e-3, 1.01e-2, 0.1, 1.0, 2.0, 3.0, math.pi - 1e-4, math.pi - 1e-7],
         rng.uniform(0, math.pi, size=27)]
    )
    return axes * angles[:, None]


def test_exp_matches_scipy_and_log_round_trip():
    phi = _test_rotvecs()
    R = so3_exp(_t(phi))
    np.testing.assert_allclose(R.numpy(), Rotation.from_rotvec(phi).as_matrix(), atol=1e-14)
    back = so3_log(R).numpy()
    np.testing.assert_allclose(back, phi, atol=1e-9)  # near pi the log is conditioned ~1/(pi - angle)
    np.testing.assert_allclose(back[:-2], phi[:-2], atol=2e-14)
    # numpy side agrees with torch
    np.testing.assert_allclose(so3_exp_np(phi), R.numpy(), atol=1e-14)
    np.testing.assert_allclose(so3_log_np(R.numpy()), back, atol=1e-9)


def test_log_at_pi_and_identity():
    R_pi = Rotation.from_rotvec([0.0, 0.0, math.pi]).as_matrix()
    phi = so3_log(_t(R_pi)).numpy()
    assert abs(abs(phi[2]) - math.pi) < 1e-12 and np.abs(phi[:2]).max() < 1e-12
    # 180 deg about a generic axis: either sign is a valid log; Exp(log) must reproduce R.
    u = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    R = Rotation.from_rotvec(math.pi * u).as_matrix()
    phi = so3_log(_t(R))
    assert abs(phi.norm().item() - math.pi) < 1e-12
    np.testing.assert_allclose(so3_exp(phi).numpy(), R, atol=1e-12)
    assert so3_log(torch.eye(3, dtype=F64)).abs().max().item() == 0.0


def test_float32_exp_log_accuracy():
    phi = _test_rotvecs()[:-2]
    R = so3_exp(_t(phi, torch.float32))
    np.testing.assert_allclose(R.numpy(), Rotation.from_rotvec(phi).as_matrix(), atol=3e-7)
    np.testing.assert_allclose(so3_log(R).numpy(), phi, atol=2e-6)


def test_exp_gradient_at_zero_is_the_generators_and_gradcheck():
    phi0 = torch.zeros(3, dtype=F64, requires_grad=True)
    jac = torch.autograd.functional.jacobian(so3_exp, phi0)  # [3, 3, 3]: d R_ij / d phi_k
    for k in range(3):
        e = torch.zeros(3, dtype=F64)
        e[k] = 1.0
        torch.testing.assert_close(jac[..., k], hat(e), atol=1e-15, rtol=0)
    for phi in ([0.0, 0.0, 0.0], [1e-7, -2e-7, 3e-8], [3e-3, 2e-3, -1e-3], [0.3, -1.2, 0.8]):
        x = torch.tensor(phi, dtype=F64, requires_grad=True)
        assert torch.autograd.gradcheck(so3_exp, (x,))
    for phi in ([1e-7, -2e-7, 3e-8], [3e-4, 2e-4, -1e-4], [0.3, -1.2, 0.8], [2.0, 1.0, -1.5]):
        R = so3_exp(torch.tensor(phi, dtype=F64)).requires_grad_(True)
        assert torch.autograd.gradcheck(so3_log, (R,))
    # gradient of log at exactly the identity is finite and equals vee
    eye = torch.eye(3, dtype=F64, requires_grad=True)
    g = torch.autograd.functional.jacobian(so3_log, eye)
    assert torch.isfinite(g).all()
    dM = torch.tensor([[0.0, -0.3, 0.2], [0.3, 0.0, -0.1], [-0.2, 0.1, 0.0]], dtype=F64)
    torch.testing.assert_close((g * dM).sum((-1, -2)), vee(dM), atol=1e-12, rtol=0)


def test_quaternion_conventions_wxyz():
    # 90 deg about z: q = (cos 45, 0, 0, sin 45), R maps x -> y.
    s = math.sqrt(0.5)
    q = np.array([s, 0.0, 0.0, s])
    R_expected = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(quat_wxyz_to_matrix_np(q), R_expected, atol=1e-15)
    np.testing.assert_allclose(quat_wxyz_to_matrix(_t(q)).numpy(), R_expected, atol=1e-15)
    np.testing.assert_allclose(matrix_to_quat_wxyz_np(R_expected), q, atol=1e-15)
    np.testing.assert_allclose(matrix_to_quat_wxyz(_t(R_expected)).numpy(), q, atol=1e-15)
    # random round trips, torch vs numpy, canonical w >= 0, including angles near pi
    phi = _test_rotvecs()
    R = Rotation.from_rotvec(phi).as_matrix()
    q_np = matrix_to_quat_wxyz_np(R)
    q_t = matrix_to_quat_wxyz(_t(R)).numpy()
    assert q_np.shape == (len(phi), 4) and (q_np[:, 0] >= 0).all() and (q_t[:, 0] >= 0).all()
    # at exactly w == 0 the sign is ambiguous; compare up to sign
    np.testing.assert_allclose(np.abs((q_np * q_t).sum(1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat_wxyz_to_matrix(_t(q_t)).numpy(), R, atol=1e-14)
    np.testing.assert_allclose(quat_wxyz_to_matrix_np(q_np), R, atol=1e-14)
    # non-unit input is normalised; batch shapes are kept
    np.testing.assert_allclose(quat_wxyz_to_matrix_np(3.0 * q_np.reshape(4, 10, 4)), R.reshape(4, 10, 3, 3), atol=1e-14)


def test_hat_vee_and_rotation_angle():
    v = np.array([0.3, -1.0, 2.0])
    w = np.array([-0.7, 0.2, 0.5])
    np.testing.assert_allclose(hat_np(v) @ w, np.cross(v, w), atol=1e-15)
    np.testing.assert_allclose(hat(_t(v)).numpy(), hat_np(v), atol=0)
    np.testing.assert_allclose(vee(hat(_t(v))).numpy(), v, atol=0)
    R_a = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    R_b = R_a @ Rotation.from_rotvec([0.0, 0.0, math.radians(7.5)]).as_matrix()
    assert rotation_angle_deg(R_a, R_b) == pytest.approx(7.5, abs=1e-12)
    tiny = R_a @ Rotation.from_rotvec([1e-9, 0.0, 0.0]).as_matrix()
    assert rotation_angle_deg(R_a, tiny) == pytest.approx(math.degrees(1e-9), rel=1e-5)
    batch = rotation_angle_deg(np.stack([R_a, R_a]), np.stack([R_a, R_b]))
    np.testing.assert_allclose(batch, [0.0, 7.5], atol=1e-12)


# ============================================================================ integration helpers


def _skew_np(v: np.ndarray) -> np.ndarray:
    return hat_np(v)


def _truth_position(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """p(t) = [sin t, cos 2t, 0.5 t^2] and its first two derivatives, [N, 3] each."""
    p = np.stack([np.sin(t), np.cos(2 * t), 0.5 * t**2], -1)
    v = np.stack([np.cos(t), -2 * np.sin(2 * t), t], -1)
    a = np.stack([-np.sin(t), -4 * np.cos(2 * t), np.ones_like(t)], -1)
    return p, v, a


def _window_fixed_axis(t0: float = 0.3, duration_s: float = 1.0, rate_hz: float = RATE_HZ):
    """Rotation R(t) = R_c Exp(u sin(2t)) (fixed axis u, body rate u * 2 cos 2t) + analytic p(t)."""
    n = int(round(duration_s * rate_hz)) + 1
    t = t0 + np.arange(n) / rate_hz
    u = np.array([0.48, -0.6, 0.64])
    R_c = Rotation.from_rotvec([0.2, -0.4, 1.0])
    rot = R_c * Rotation.from_rotvec(np.sin(2 * t)[:, None] * u)
    gyro = (2 * np.cos(2 * t))[:, None] * u  # R^T dR/dt = [u]x theta_dot for a fixed axis
    return t, rot.as_matrix(), gyro


def _window_spline(t0: float = 0.3, duration_s: float = 1.0, rate_hz: float = RATE_HZ):
    """Time-varying axis: SciPy RotationSpline through keyframes; rate from spline(t, 1)."""
    key_t = np.linspace(0.0, 1.6, 9)
    key_rv = np.stack([0.8 * np.sin(1.3 * key_t), 0.6 * np.cos(0.9 * key_t), 0.9 * np.sin(0.7 * key_t + 0.4)], -1)
    spline = RotationSpline(key_t, Rotation.from_rotvec(key_rv))
    n = int(round(duration_s * rate_hz)) + 1
    t = t0 + np.arange(n) / rate_hz
    return t, spline(t).as_matrix(), spline(t, 1), spline


def _imu_from_truth(t: np.ndarray, R: np.ndarray, gyro: np.ndarray):
    p, v, a_world = _truth_position(t)
    acc = np.einsum("nji,nj->ni", R, a_world - G)  # specific force in the body: R^T (a - g)
    return gyro, acc, p, v


def _run(gyro, acc, R, v, p, dt, scheme, dtype=F64, **kw) -> IntegrationResult:
    return integrate(
        _t(gyro[None], dtype),
        _t(acc[None], dtype),
        dt,
        _t(R[0][None], dtype),
        _t(v[0][None], dtype),
        _t(p[0][None], dtype),
        gravity_mps2=G,
        scheme=scheme,
        **kw,
    )


def _errors(res: IntegrationResult, R_true: np.ndarray, p_true: np.ndarray, v_true: np.ndarray):
    pos_m = float(np.linalg.norm(res.p[0].detach().double().numpy() - p_true))
    vel_mps = float(np.linalg.norm(res.v[0].detach().double().numpy() - v_true))
    rot_deg = float(rotation_angle_deg(res.R[0].detach().double().numpy(), R_true))
    return pos_m, vel_mps, rot_deg


# ============================================================================ integration accuracy


def test_scipy_rotation_spline_rate_is_body_frame():
    """Documents the convention the reference relies on: RotationSpline(t, 1) = vee(R^T dR/dt)."""
    _, _, _, spline = _window_spline()
    tt, eps = 0.77, 1e-6
    R = spline(tt).as_matrix()
    dR = (spline(tt + eps).as_matrix() - spline(tt - eps).as_matrix()) / (2 * eps)
    body = 0.5 * np.array([(R.T @ dR)[2, 1] - (R.T @ dR)[1, 2], (R.T @ dR)[0, 2] - (R.T @ dR)[2, 0],
                           (R.T @ dR)[1, 0] - (R.T @ dR)[0, 1]])
    world = 0.5 * np.array([(dR @ R.T)[2, 1] - (dR @ R.T)[1, 2], (dR @ R.T)[0, 2] - (dR @ R.T)[2, 0],
                            (dR @ R.T)[1, 0] - (dR @ R.T)[0, 1]])
    np.testing.assert_allclose(spline(tt, 1), body, atol=1e-7)
    assert np.linalg.norm(spline(tt, 1) - world) > 0.1


def test_constant_rate_and_specific_force_closed_form():
    w = np.array([0.3, -0.5, 0.8])  # |w| ~ 1 rad/s
    a = np.array([0.5, -1.0, 9.5])
    R0 = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix()
    v0 = np.array([0.4, -0.2, 0.1])
    p0 = np.array([1.0, 2.0, 3.0])
    T = 201
    h = 1.0 / RATE_HZ
    tau = h * (T - 1)
    # closed form: R(t) = R0 Exp(w t); with K = [w/|w|]x, s = |w|:
    #   int_0^t Exp(w x) dx      = t I + (1 - cos st)/s K + (t - sin(st)/s) K^2
    #   int_0^t int_0^x Exp(w y)  = t^2/2 I + (t/s - sin(st)/s^2) K + (t^2/2 - (1 - cos st)/s^2) K^2
    s = np.linalg.norm(w)
    K = _skew_np(w / s)
    I3 = np.eye(3)
    J1 = tau * I3 + (1 - math.cos(s * tau)) / s * K + (tau - math.sin(s * tau) / s) * K @ K
    J2 = (
        tau**2 / 2 * I3
        + (tau / s - math.sin(s * tau) / s**2) * K
        + (tau**2 / 2 - (1 - math.cos(s * tau)) / s**2) * K @ K
    )
    R_true = R0 @ Rotation.from_rotvec(w * tau).as_matrix()
    v_true = v0 + G * tau + R0 @ J1 @ a
    p_true = p0 + v0 * tau + 0.5 * G * tau**2 + R0 @ J2 @ a
    gyro = np.tile(w, (T, 1))
    acc = np.tile(a, (T, 1))
    errs = {}
    for scheme in IntegrationScheme:
        res = integrate(
            _t(gyro[None]), _t(acc[None]), h, _t(R0[None]), _t(v0[None]), _t(p0[None]), gravity_mps2=G, scheme=scheme
        )
        errs[scheme] = _errors(res, R_true, p_true, v_true)
    pos, vel, rot = errs[IntegrationScheme.MIDPOINT]
    assert rot < 1e-10  # a constant rate is integrated exactly by both schemes
    assert pos < 1e-5 and vel < 2e-5
    pos_e, vel_e, rot_e = errs[IntegrationScheme.EULER]
    assert rot_e < 1e-10
    assert pos_e > 1e-3 and vel_e > 1e-2  # first order: ~h/2 * |dR a/dt| lag
    assert pos_e > 100 * pos and vel_e > 100 * vel


@pytest.mark.parametrize("window", ["fixed_axis", "spline"])
def test_one_second_window_end_pose(window):
    if window == "fixed_axis":
        t, R_true, gyro = _window_fixed_axis()
    else:
        t, R_true, gyro, _ = _window_spline()
    gyro, acc, p_true, v_true = _imu_from_truth(t, R_true, gyro)
    assert abs(t[-1] - t[0] - 1.0) < 1e-12 and len(t) == 201
    dt = 1.0 / RATE_HZ
    end = (R_true[-1], p_true[-1], v_true[-1])
    mid = _errors(_run(gyro, acc, R_true, v_true, p_true, dt, IntegrationScheme.MIDPOINT), *end)
    eul = _errors(_run(gyro, acc, R_true, v_true, p_true, dt, IntegrationScheme.EULER), *end)
    pos, vel, rot = mid
    assert pos < 1e-4, mid  # the integration's accuracy target: 1e-4 m
    assert rot < 1e-3, mid  # and 1e-3 deg
    assert vel < 2e-4, mid
    pos_e, vel_e, rot_e = eul
    assert pos_e > 1e-3 and rot_e > 1e-2, eul  # Euler lags by half a sample
    assert pos_e > 20 * pos and rot_e > 20 * rot, (mid, eul)
    # default scheme is MIDPOINT
    res_default = integrate(
        _t(gyro[None]), _t(acc[None]), dt, _t(R_true[:1]), _t(v_true[:1]), _t(p_true[:1]), gravity_mps2=G
    )
    assert _errors(res_default, R_true[-1], p_true[-1], v_true[-1]) == mid


def test_midpoint_is_second_order():
    """Halving the sample interval divides the end-pose error by ~4 (Euler: by ~2)."""
    out = {}
    for scheme in IntegrationScheme:
        errs = []
        for rate in (100.0, 200.0):
            t, R_true, gyro, _ = _window_spline(rate_hz=rate)
            gyro, acc, p_true, v_true = _imu_from_truth(t, R_true, gyro)
            res = _run(gyro, acc, R_true, v_true, p_true, 1.0 / rate, scheme)
            errs.append(_errors(res, R_true[-1], p_true[-1], v_true[-1]))
        out[scheme] = (errs[0][0] / errs[1][0], errs[0][2] / errs[1][2])
    pos_ratio, rot_ratio = out[IntegrationScheme.MIDPOINT]
    assert 3.0 < pos_ratio < 5.0 and 3.0 < rot_ratio < 5.0, out
    pos_ratio, rot_ratio = out[IntegrationScheme.EULER]
    assert 1.6 < pos_ratio < 2.4 and 1.6 < rot_ratio < 2.4, out


def test_jittered_stamps_and_trajectory():
    """Per-interval dt [B, T-1] with stamp jitter; the whole trajectory follows the truth."""
    rng = np.random.default_rng(3)
    n = 201
    t = 0.3 + np.cumsum(np.r_[0.0, (1.0 / RATE_HZ) * (1 + rng.uniform(-0.2, 0.2, n - 1))])
    u = np.array([0.48, -0.6, 0.64])
    R_true = (Rotation.from_rotvec([0.2, -0.4, 1.0]) * Rotation.from_rotvec(np.sin(2 * t)[:, None] * u)).as_matrix()
    gyro, acc, p_true, v_true = _imu_from_truth(t, R_true, (2 * np.cos(2 * t))[:, None] * u)
    dt = _t(np.diff(t)[None])
    res = _run(gyro, acc, R_true, v_true, p_true, dt, IntegrationScheme.MIDPOINT, return_trajectory=True)
    assert res.R_traj.shape == (1, n, 3, 3) and res.v_traj.shape == (1, n, 3) and res.p_traj.shape == (1, n, 3)
    assert np.abs(res.p_traj[0].numpy() - p_true).max() < 1e-4
    assert np.abs(res.v_traj[0].numpy() - v_true).max() < 2e-4
    assert np.max(rotation_angle_deg(res.R_traj[0].numpy(), R_true)) < 1e-3
    torch.testing.assert_close(res.R_traj[:, 0], _t(R_true[:1]), atol=0, rtol=0)
    torch.testing.assert_close(res.p_traj[:, -1], res.p, atol=0, rtol=0)
    torch.testing.assert_close(res.v_traj[:, -1], res.v, atol=0, rtol=0)
    torch.testing.assert_close(res.R_traj[:, -1], res.R, atol=0, rtol=0)
    no_traj = _run(gyro, acc, R_true, v_true, p_true, dt, IntegrationScheme.MIDPOINT)
    assert no_traj.R_traj is None and no_traj.p_traj is None
    torch.testing.assert_close(no_traj.p, res.p, atol=1e-12, rtol=0)


def test_stationary_and_single_sample():
    B, T = 3, 50
    R0 = so3_exp(_t(np.array([[0.1, 0.2, 0.3], [2.0, -1.0, 0.5], [0.0, 0.0, 0.0]])))
    acc = torch.einsum("bji,j->bi", R0, _t(-G))[:, None].expand(B, T, 3)  # gravity reaction
    res = integrate(torch.zeros(B, T, 3, dtype=F64), acc, 0.01, R0, torch.zeros(B, 3, dtype=F64),
                    torch.ones(B, 3, dtype=F64), gravity_mps2=G)
    torch.testing.assert_close(res.R, R0, atol=1e-15, rtol=0)
    assert res.v.abs().max().item() < 1e-12 and (res.p - 1).abs().max().item() < 1e-12
    one = integrate(torch.zeros(B, 1, 3, dtype=F64), acc[:, :1], 0.01, R0, torch.zeros(B, 3, dtype=F64),
                    torch.ones(B, 3, dtype=F64), gravity_mps2=G, return_trajectory=True)
    assert torch.equal(one.R, R0) and one.R_traj.shape == (B, 1, 3, 3)


# ============================================================================ batch, bias, dtype, autograd


def _random_batch(B: int, T: int, dtype=F64, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    gyro = torch.randn(B, T, 3, generator=gen, dtype=dtype)
    acc = torch.randn(B, T, 3, generator=gen, dtype=dtype) + torch.tensor([0.0, 0.0, 9.81], dtype=dtype)
    R0 = so3_exp(torch.randn(B, 3, generator=gen, dtype=dtype))
    v0 = torch.randn(B, 3, generator=gen, dtype=dtype)
    p0 = torch.randn(B, 3, generator=gen, dtype=dtype)
    bg = 0.01 * torch.randn(B, 3, generator=gen, dtype=dtype)
    ba = 0.1 * torch.randn(B, 3, generator=gen, dtype=dtype)
    return gyro, acc, R0, v0, p0, bg, ba


@pytest.mark.parametrize("scheme", list(IntegrationScheme))
def test_bias_broadcast_and_subtraction(scheme):
    gyro, acc, R0, v0, p0, bg, ba = _random_batch(4, 30)
    kw = dict(gravity_mps2=G, scheme=scheme, return_trajectory=True)
    a = integrate(gyro, acc, 0.005, R0, v0, p0, bias_gyro_radps=bg, bias_acc_mps2=ba, **kw)
    b = integrate(gyro, acc, 0.005, R0, v0, p0, bias_gyro_radps=bg[:, None].expand(4, 30, 3),
                  bias_acc_mps2=ba[:, None].expand(4, 30, 3).contiguous(), **kw)
    c = integrate(gyro - bg[:, None], acc - ba[:, None], 0.005, R0, v0, p0, **kw)
    for other in (b, c):
        for name in ("R", "v", "p", "R_traj", "v_traj", "p_traj"):
            torch.testing.assert_close(getattr(a, name), getattr(other, name), atol=1e-13, rtol=0)
    # the bias matters: ~0.01 rad/s over 0.145 s
    assert (a.R - integrate(gyro, acc, 0.005, R0, v0, p0, **kw).R).abs().max().item() > 1e-4
    # time-varying bias is used per sample
    bg_t = bg[:, None] * torch.linspace(0, 2, 30, dtype=F64)[None, :, None]
    d = integrate(gyro, acc, 0.005, R0, v0, p0, bias_gyro_radps=bg_t, **kw)
    e = integrate(gyro - bg_t, acc, 0.005, R0, v0, p0, **kw)
    torch.testing.assert_close(d.p, e.p, atol=1e-13, rtol=0)


def test_identical_windows_give_identical_outputs_and_dt_forms_agree():
    gyro, acc, R0, v0, p0, bg, ba = _random_batch(1, 201)
    B = 64
    rep = integrate(gyro.expand(B, -1, -1), acc.expand(B, -1, -1), 0.005, R0.expand(B, 3, 3), v0.expand(B, 3),
                    p0.expand(B, 3), gravity_mps2=G, bias_gyro_radps=bg.expand(B, 3), bias_acc_mps2=ba.expand(B, 3))
    single = integrate(gyro, acc, 0.005, R0, v0, p0, gravity_mps2=G, bias_gyro_radps=bg, bias_acc_mps2=ba)
    for name in ("R", "v", "p"):
        x = getattr(rep, name)
        assert (x - x[:1]).abs().max().item() == 0.0
        torch.testing.assert_close(x[:1], getattr(single, name), atol=1e-14, rtol=0)
    per_interval = integrate(gyro, acc, torch.full((1, 200), 0.005, dtype=F64), R0, v0, p0, gravity_mps2=G,
                             bias_gyro_radps=bg, bias_acc_mps2=ba)
    torch.testing.assert_close(per_interval.p, single.p, atol=1e-14, rtol=0)


def test_float32_agrees_with_float64():
    t, R_true, gyro, _ = _window_spline()
    gyro, acc, p_true, v_true = _imu_from_truth(t, R_true, gyro)
    r64 = _run(gyro, acc, R_true, v_true, p_true, 0.005, IntegrationScheme.MIDPOINT, F64)
    r32 = _run(gyro, acc, R_true, v_true, p_true, 0.005, IntegrationScheme.MIDPOINT, torch.float32)
    assert r32.p.dtype == torch.float32 and r32.R.dtype == torch.float32
    assert (r32.p.double() - r64.p).abs().max().item() < 2e-5
    assert (r32.v.double() - r64.v).abs().max().item() < 2e-5
    assert rotation_angle_deg(r32.R[0].double().numpy(), r64.R[0].numpy()) < 5e-4


@pytest.mark.parametrize("scheme", list(IntegrationScheme))
def test_gradcheck(scheme):
    gyro, acc, R0, v0, p0, bg, ba = _random_batch(2, 5)
    gyro[0, 2] = 0.0  # an exactly-zero rotation increment (Euler) must still have a finite gradient
    gyro[0, 1] = 0.0
    dt = torch.tensor([[0.01, 0.02, 0.015, 0.01], [0.01, 0.01, 0.01, 0.01]], dtype=F64)
    bg_t = 0.01 * torch.randn(2, 5, 3, dtype=F64, generator=torch.Generator().manual_seed(5))
    inputs = [x.clone().requires_grad_(True) for x in (gyro, acc, bg_t, ba, R0, v0, p0, dt)]

    def fn(gyro, acc, bg, ba, R0, v0, p0, dt):
        r = integrate(gyro, acc, dt, R0, v0, p0, gravity_mps2=G, bias_gyro_radps=bg, bias_acc_mps2=ba,
                      scheme=scheme, return_trajectory=True)
        return r.R_traj, r.v_traj, r.p_traj

    assert torch.autograd.gradcheck(fn, inputs)


def test_gradient_through_bias_is_finite_at_zero_motion():
    gyro = torch.zeros(2, 20, 3, dtype=F64)
    bg = torch.zeros(2, 3, dtype=F64, requires_grad=True)
    res = integrate(gyro, torch.zeros(2, 20, 3, dtype=F64), 0.005, torch.eye(3, dtype=F64), torch.zeros(3, dtype=F64),
                    torch.zeros(3, dtype=F64), gravity_mps2=G, bias_gyro_radps=bg)
    loss = so3_log(res.R).square().sum() + res.p.square().sum()
    (grad,) = torch.autograd.grad(loss, bg)
    assert torch.isfinite(grad).all()
    assert grad.abs().max().item() == 0.0  # zero is a minimum of this loss


# ============================================================================ numpy wrapper, errors, devices


def test_integrate_numpy_single_and_batched():
    t, R_true, gyro, _ = _window_spline()
    gyro, acc, p_true, v_true = _imu_from_truth(t, R_true, gyro)
    res = integrate_numpy(gyro, acc, np.diff(t), R_true[0], v_true[0], p_true[0], gravity_mps2=G,
                          bias_gyro_radps=np.zeros(3), return_trajectory=True)
    assert isinstance(res.p, np.ndarray) and res.p.shape == (3,) and res.R.shape == (3, 3)
    assert res.R_traj.shape == (201, 3, 3) and res.p.dtype == np.float64
    assert np.linalg.norm(res.p - p_true[-1]) < 1e-4 and rotation_angle_deg(res.R, R_true[-1]) < 1e-3
    batched = integrate_numpy(np.stack([gyro, gyro]), np.stack([acc, acc]), 0.005, np.stack([R_true[0]] * 2),
                              np.stack([v_true[0]] * 2), np.stack([p_true[0]] * 2), gravity_mps2=G)
    assert batched.p.shape == (2, 3) and batched.R_traj is None
    np.testing.assert_allclose(batched.p[1], res.p, atol=1e-12)


def test_shape_errors_raise_data_error():
    gyro, acc, R0, v0, p0, bg, ba = _random_batch(2, 10)
    with pytest.raises(DataError, match="acc_mps2"):
        integrate(gyro, acc[:, :9], 0.005, R0, v0, p0, gravity_mps2=G)
    with pytest.raises(DataError, match="dt_s"):
        integrate(gyro, acc, torch.ones(2, 10, dtype=F64), R0, v0, p0, gravity_mps2=G)
    with pytest.raises(DataError, match="bias_gyro_radps"):
        integrate(gyro, acc, 0.005, R0, v0, p0, gravity_mps2=G, bias_gyro_radps=torch.zeros(3, 3, dtype=F64))
    with pytest.raises(DataError, match="gyro_radps"):
        integrate(gyro[0], acc[0], 0.005, R0, v0, p0, gravity_mps2=G)
    with pytest.raises(DataError, match="R0"):
        integrate(gyro, acc, 0.005, R0[:, :2], v0, p0, gravity_mps2=G)
    with pytest.raises(ValueError):
        integrate(gyro, acc, 0.005, R0, v0, p0, gravity_mps2=G, scheme="rk4")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_cuda_matches_cpu():
    gyro, acc, R0, v0, p0, bg, ba = _random_batch(8, 201)
    cpu = integrate(gyro, acc, 0.005, R0, v0, p0, gravity_mps2=G, bias_gyro_radps=bg, bias_acc_mps2=ba)
    dev = [x.cuda() for x in (gyro, acc, R0, v0, p0, bg, ba)]
    gpu = integrate(*dev[:2], 0.005, *dev[2:5], gravity_mps2=G, bias_gyro_radps=dev[5], bias_acc_mps2=dev[6])
    assert gpu.p.device.type == "cuda"
    torch.testing.assert_close(gpu.p.cpu(), cpu.p, atol=1e-10, rtol=0)


@pytest.mark.parametrize("scheme", list(IntegrationScheme))
def test_end_state_matches_trajectory_for_every_dt_form_and_time_blocking(scheme, monkeypatch):
    """The end-state fast path (weighted sums) equals the trajectory path, for dt given as a
    float, [T-1], [B, 1] and per-window [B, T-1], and with time processed in many blocks."""
    import pipeline.geometry.integration as integration

    B, T = 3, 23
    gyro, acc, R0, v0, p0, bg, ba = _random_batch(B, T)
    gen = torch.Generator().manual_seed(7)
    dt_forms = {
        "float": 0.01,
        "[T-1]": 0.01 + 0.002 * torch.rand(T - 1, generator=gen, dtype=F64),
        "[B,1]": torch.tensor([[0.01], [0.012], [0.008]], dtype=F64),
        "[B,T-1]": 0.01 + 0.002 * torch.rand(B, T - 1, generator=gen, dtype=F64),
    }
    kw = dict(gravity_mps2=G, bias_gyro_radps=bg, bias_acc_mps2=ba, scheme=scheme)
    for name, dt in dt_forms.items():
        ref = integrate(gyro, acc, dt, R0, v0, p0, return_trajectory=True, **kw)
        end = integrate(gyro, acc, dt, R0, v0, p0, **kw)
        for attr in ("R", "v", "p"):
            torch.testing.assert_close(getattr(end, attr), getattr(ref, attr), atol=1e-12, rtol=0, msg=name)
        # window b alone, with its own dt, gives the same result
        dt_full = torch.as_tensor(dt, dtype=F64).expand(B, T - 1)
        one = integrate(gyro[1:2], acc[1:2], dt_full[1:2], R0[1:2], v0[1:2], p0[1:2], gravity_mps2=G,
                        bias_gyro_radps=bg[1:2], bias_acc_mps2=ba[1:2], scheme=scheme)
        torch.testing.assert_close(one.p, end.p[1:2], atol=1e-12, rtol=0, msg=name)
        # many small time blocks (4 steps; the last one partial) give the same numbers
        monkeypatch.setattr(integration, "_CPU_BLOCK_ELEMENTS", 1)
        blocked = integrate(gyro, acc, dt, R0, v0, p0, **kw)
        blocked_traj = integrate(gyro, acc, dt, R0, v0, p0, return_trajectory=True, **kw)
        monkeypatch.undo()
        for attr in ("R", "v", "p"):
            torch.testing.assert_close(getattr(blocked, attr), getattr(ref, attr), atol=1e-12, rtol=0, msg=name)
        torch.testing.assert_close(blocked_traj.p_traj, ref.p_traj, atol=1e-12, rtol=0, msg=name)
        torch.testing.assert_close(blocked_traj.R_traj, ref.R_traj, atol=1e-12, rtol=0, msg=name)


@pytest.mark.parametrize("scheme", list(IntegrationScheme))
def test_gradcheck_end_state_path(scheme, monkeypatch):
    import pipeline.geometry.integration as integration

    monkeypatch.setattr(integration, "_CPU_BLOCK_ELEMENTS", 1)  # several time blocks
    gyro, acc, R0, v0, p0, bg, ba = _random_batch(2, 7, seed=2)
    dt = 0.01 + 0.005 * torch.rand(2, 6, dtype=F64, generator=torch.Generator().manual_seed(1))
    inputs = [x.clone().requires_grad_(True) for x in (gyro, acc, bg, ba, R0, v0, p0, dt)]

    def fn(gyro, acc, bg, ba, R0, v0, p0, dt):
        r = integrate(gyro, acc, dt, R0, v0, p0, gravity_mps2=G, bias_gyro_radps=bg, bias_acc_mps2=ba, scheme=scheme)
        return r.R, r.v, r.p

    assert torch.autograd.gradcheck(fn, inputs)
