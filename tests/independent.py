"""Sequences generated independently of ``pipeline.sim``, written with independent writer code.

Nothing here imports the project's simulator, writers or integrator: the motion, the IMU
model, the bias truth, the mocap stream and the files on disk are all produced from
scratch (numpy, scipy ``Rotation``, pandas, GTSAM's scenario machinery, ``rosbags``), so the
project's readers, integration engine, simulator and recovery can be checked against it.

Generators:

* :class:`LissajousMotion`: closed-form motion. Position is a sum of sinusoids per axis
  (Lissajous-like), orientation ``R = Rz(yaw) Ry(pitch) Rx(roll)`` with sinusoidal Euler
  angles. Body rates come from the analytic Euler-rate map, acceleration from the second
  derivative of the sinusoids; the IMU sees ``omega_b`` and ``f_b = R^T (a - g)``.
* :func:`gtsam_scenario_motion`: GTSAM's ``ConstantTwistScenario`` / ``AcceleratingScenario``
  sampled through ``gtsam.ScenarioRunner`` (``actualAngularVelocity``/``actualSpecificForce``
  for the truth, ``measured*`` with zero bias for GTSAM-sampled white noise).
* :func:`make_sequence`: a motion + a known time-varying bias (turn-on offset + random walk)
  + white noise + a 100-Hz mocap stream (0.5 mm / 0.5 mrad, optional clock offset and marker
  extrinsic), as an :class:`IndependentSequence`; optionally IMU intrinsic errors
  (:class:`IntrinsicErrors`, drawn at MEMS-like sizes by :func:`draw_intrinsics`):
  ``gyro = M_g omega + G f + b_g + n_g``, ``acc = M_a f + b_a + n_a``.

Writers (own code: plain pandas/numpy text output, ``rosbags`` directly):
:func:`write_euroc`, :func:`write_tum_text`, :func:`write_ros1_bag`.

Conventions (the project's, restated so the generator can be checked against them):
``t_imu = pose_stamp + clock_offset_s``; the tracked marker is
``T_world_marker = T_world_imu @ T_imu_marker``; gravity is ``(0, 0, -9.81)`` in the world.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

NS = 1_000_000_000
GRAVITY_MPS2 = np.array([0.0, 0.0, -9.81])
#: Noise model written to imu0/sensor.yaml (EuRoC ADIS16448 datasheet values).
REPORTED = dict(gyro_noise_density=1.6968e-4, gyro_random_walk=1.9393e-5,
                acc_noise_density=2.0e-3, acc_random_walk=3.0e-3)
T0_NS = 1_500_000_000_000_000_000  # an epoch-like start stamp (exact only as int64)


# ----------------------------------------------------------------------------- motion


@dataclass(frozen=True)
class MotionState:
    """True kinematics at times t_s [N]: world frame z up, R = world-from-imu."""

    p_m: np.ndarray
    v_mps: np.ndarray
    a_mps2: np.ndarray
    rotation: Rotation
    omega_body_radps: np.ndarray

    def specific_force(self, gravity_mps2: np.ndarray = GRAVITY_MPS2) -> np.ndarray:
        """``R^T (a - g)`` in the IMU frame, [N, 3]."""
        return self.rotation.inv().apply(self.a_mps2 - gravity_mps2)


def _sines(t: np.ndarray, terms: list[tuple[float, float, float]], offset: float = 0.0
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``offset + sum A sin(w t + ph)`` and its first two derivatives."""
    x = np.full_like(t, offset, dtype=float)
    dx = np.zeros_like(t, dtype=float)
    ddx = np.zeros_like(t, dtype=float)
    for amp, w, ph in terms:
        s, c = np.sin(w * t + ph), np.cos(w * t + ph)
        x += amp * s
        dx += amp * w * c
        ddx -= amp * w * w * s
    return x, dx, ddx


@dataclass(frozen=True)
class LissajousMotion:
    """Closed-form smooth motion with analytic rates (see module docstring).

    Each entry is a list of ``(amplitude, angular frequency rad/s, phase rad)`` sinusoids.
    """

    pos: tuple = (
        [(1.5, 0.50, 0.0), (0.30, 1.70, 0.2)],
        [(1.2, 0.80, 0.5), (0.25, 1.30, 1.1)],
        [(0.4, 0.60, 1.0), (0.10, 2.10, 0.3)],
    )
    pos_offset: tuple = (0.0, 0.0, 1.2)
    yaw: list = field(default_factory=lambda: [(1.2, 0.35, 0.0), (0.35, 1.10, 0.7)])
    pitch: list = field(default_factory=lambda: [(0.35, 0.90, 0.4), (0.10, 2.30, 1.3)])
    roll: list = field(default_factory=lambda: [(0.40, 0.70, 1.0), (0.15, 2.30, 0.2)])

    def state(self, t_s: np.ndarray) -> MotionState:
        t = np.asarray(t_s, dtype=float)
        p, v, a = (np.zeros((len(t), 3)) for _ in range(3))
        for i in range(3):
            p[:, i], v[:, i], a[:, i] = _sines(t, self.pos[i], self.pos_offset[i])
        psi, dpsi, _ = _sines(t, self.yaw)
        th, dth, _ = _sines(t, self.pitch)
        ph, dph, _ = _sines(t, self.roll)
        # intrinsic Z-Y'-X'' (yaw, pitch, roll): R = Rz(psi) Ry(th) Rx(ph); body rates:
        omega = np.column_stack([
            dph - dpsi * np.sin(th),
            dth * np.cos(ph) + dpsi * np.cos(th) * np.sin(ph),
            -dth * np.sin(ph) + dpsi * np.cos(th) * np.cos(ph),
        ])
        rot = Rotation.from_euler("ZYX", np.column_stack([psi, th, ph]))
        return MotionState(p, v, a, rot, omega)


@dataclass(frozen=True)
class RestThenMotion:
    """``motion`` held at its t = 0 pose for ``rest_s``, then started smoothly over ``ramp_s``.

    Time is warped: ``s(t) = 0`` at rest, ``s'(t)`` rises as ``3x^2 - 2x^3`` (``x`` the fraction of
    the ramp) and is 1 after it. By the chain rule the velocity is ``v(s) s'``, the acceleration
    ``a(s) s'^2 + v(s) s''`` and the body rate ``omega(s) s'`` (the attitude is ``R(s(t))``).
    """

    motion: LissajousMotion
    rest_s: float
    ramp_s: float = 2.0

    def state(self, t_s: np.ndarray) -> MotionState:
        t = np.asarray(t_s, dtype=float)
        x = np.clip((t - self.rest_s) / self.ramp_s, 0.0, 1.0)
        s = np.where(x < 1.0, self.ramp_s * (x**3 - x**4 / 2), t - self.rest_s - self.ramp_s / 2)
        ds, dds = 3 * x**2 - 2 * x**3, 6 * x * (1 - x) / self.ramp_s
        st = self.motion.state(s)
        return MotionState(st.p_m, st.v_mps * ds[:, None], st.a_mps2 * ds[:, None] ** 2 + st.v_mps * dds[:, None],
                           st.rotation, st.omega_body_radps * ds[:, None])


class GtsamScenarioMotion:
    """A GTSAM scenario as a motion (truth from ``Scenario``/``ScenarioRunner``).

    Args:
        scenario: ``gtsam.ConstantTwistScenario`` or ``gtsam.AcceleratingScenario``.
        dt_s: IMU sample time given to the runner.
        gyro_noise_density / acc_noise_density: continuous white-noise densities; GTSAM's
            ``ScenarioRunner.measured*`` draws discrete noise ``density / sqrt(dt)``.
    """

    def __init__(self, scenario, dt_s: float, gyro_noise_density: float = 0.0,
                 acc_noise_density: float = 0.0) -> None:
        import gtsam

        self.scenario = scenario
        params = gtsam.PreintegrationParams.MakeSharedU(-GRAVITY_MPS2[2])
        params.setGyroscopeCovariance(max(gyro_noise_density, 1e-30) ** 2 * np.eye(3))
        params.setAccelerometerCovariance(max(acc_noise_density, 1e-30) ** 2 * np.eye(3))
        params.setIntegrationCovariance(1e-12 * np.eye(3))
        self.params = params
        self.runner = gtsam.ScenarioRunner(scenario, params, dt_s, gtsam.imuBias.ConstantBias())

    def state(self, t_s: np.ndarray) -> MotionState:
        t = np.asarray(t_s, dtype=float)
        p = np.array([self.scenario.pose(x).translation() for x in t])
        v = np.array([self.scenario.velocity_n(x) for x in t])
        a = np.array([self.scenario.acceleration_n(x) for x in t])
        R = np.array([self.scenario.rotation(x).matrix() for x in t])
        w = np.array([self.scenario.omega_b(x) for x in t])
        return MotionState(p, v, a, Rotation.from_matrix(R), w)

    def specific_force_gtsam(self, t_s: np.ndarray) -> np.ndarray:
        """GTSAM's own ``actualSpecificForce`` at t_s, [N, 3]."""
        return np.array([self.runner.actualSpecificForce(float(x)) for x in t_s])

    def white_noise(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """GTSAM-sampled white noise (measured - actual with zero bias), [N, 3] each."""
        g = np.array([self.runner.measuredAngularVelocity(float(x)) - self.runner.actualAngularVelocity(float(x))
                      for x in t_s])
        f = np.array([self.runner.measuredSpecificForce(float(x)) - self.runner.actualSpecificForce(float(x))
                      for x in t_s])
        return g, f


def gtsam_scenario_motion(kind: str = "accelerating", dt_s: float = 0.005, **noise: float) -> GtsamScenarioMotion:
    """A ready GTSAM scenario: ``"twist"`` (a climbing, pitching loop) or ``"accelerating"``."""
    import gtsam

    if kind == "twist":
        scen = gtsam.ConstantTwistScenario(np.array([0.1, -0.3, 0.6]), np.array([1.5, 0.0, 0.2]),
                                           gtsam.Pose3(gtsam.Rot3.Ypr(0.3, 0.1, -0.2), np.array([1.0, 2.0, 1.5])))
    elif kind == "accelerating":
        scen = gtsam.AcceleratingScenario(gtsam.Rot3.Ypr(0.4, -0.2, 0.1), np.array([0.5, -1.0, 1.0]),
                                          np.array([0.8, 0.1, 0.0]), np.array([0.3, -0.2, 0.1]),
                                          np.array([0.4, 0.7, -0.9]))
    else:
        raise ValueError(kind)
    return GtsamScenarioMotion(scen, dt_s, **noise)


# ----------------------------------------------------------------------------- sequences


@dataclass(frozen=True)
class IndependentSequence:
    """An independently generated recording and its truth.

    Attributes:
        t_ns: IMU stamps (IMU clock), int64 [N].
        gyro_radps / acc_mps2: Measured IMU (truth + bias + noise), [N, 3].
        gyro_true_radps / acc_true_mps2: Noise- and bias-free IMU, [N, 3].
        bias_gyro_radps / bias_acc_mps2: True bias, [N, 3].
        p_m / quat_wxyz / v_mps: True IMU state at t_ns, [N, 3] / [N, 4] / [N, 3].
        pose_t_ns: Mocap stamps on the mocap clock, int64 [M].
        pose_p_m / pose_quat_wxyz: Measured marker pose, [M, 3] / [M, 4].
        clock_offset_s: ``t_imu = pose_stamp + clock_offset_s``.
        T_imu_marker: True 4x4 marker extrinsic.
        rate_hz: IMU rate.
    """

    t_ns: np.ndarray
    gyro_radps: np.ndarray
    acc_mps2: np.ndarray
    gyro_true_radps: np.ndarray
    acc_true_mps2: np.ndarray
    bias_gyro_radps: np.ndarray
    bias_acc_mps2: np.ndarray
    p_m: np.ndarray
    quat_wxyz: np.ndarray
    v_mps: np.ndarray
    pose_t_ns: np.ndarray
    pose_p_m: np.ndarray
    pose_quat_wxyz: np.ndarray
    clock_offset_s: float
    T_imu_marker: np.ndarray
    rate_hz: float


def quat_wxyz(rot: Rotation) -> np.ndarray:
    """Continuous (no sign flips) Hamilton quaternions, [N, 4] w first."""
    q = rot.as_quat()[:, [3, 0, 1, 2]]
    flips = np.concatenate([[False], np.einsum("ij,ij->i", q[1:], q[:-1]) < 0])
    sign = np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)
    q = q * sign[:, None]
    return q if q[0, 0] >= 0 else -q


def random_walk_bias(n: int, rate_hz: float, rng: np.random.Generator, *, turn_on_sigma: float,
                     random_walk: float) -> np.ndarray:
    """Turn-on offset ``N(0, turn_on_sigma^2)`` plus a Wiener process of strength ``random_walk``, [n, 3]."""
    steps = rng.standard_normal((n - 1, 3)) * (random_walk / np.sqrt(rate_hz))
    return rng.standard_normal(3) * turn_on_sigma + np.vstack([np.zeros((1, 3)), np.cumsum(steps, 0)])


def extrinsic(rotvec_deg: tuple[float, float, float], trans_m: tuple[float, float, float]) -> np.ndarray:
    """4x4 ``T_imu_marker`` from a rotation vector (deg) and a translation (m)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    T[:3, 3] = trans_m
    return T


#: The hard variant's marker: 15 deg about a skew axis, 10 cm lever arm.
HARD_EXTRINSIC = extrinsic(tuple(15.0 * np.array([0.48, -0.64, 0.6]) / np.linalg.norm([0.48, -0.64, 0.6])),
                           tuple(0.10 * np.array([0.6, 0.0, -0.8])))


@dataclass(frozen=True)
class IntrinsicErrors:
    """IMU intrinsic errors: ``gyro = M_g omega + G f + ...``, ``acc = M_a f + ...`` (IMU frame).

    Attributes:
        gyro_matrix / acc_matrix: ``M_g`` / ``M_a``, [3, 3] (identity = perfect).
        g_sensitivity: ``G``, [3, 3] rad/s per m/s^2.
    """

    gyro_matrix: np.ndarray
    acc_matrix: np.ndarray
    g_sensitivity: np.ndarray


def draw_intrinsics(seed: int, *, gyro_scale: tuple[float, float] = (0.005, 0.01),
                    misalignment_deg: tuple[float, float] = (0.2, 0.5), acc_scale: tuple[float, float] = (0.002, 0.005),
                    g_sensitivity: float = 2e-4) -> IntrinsicErrors:
    """MEMS-like intrinsic errors drawn for ``seed`` (a stream of its own: the sequence's draws are unchanged).

    Every size is uniform in its range with a random sign: the scale errors on the diagonals; each of
    the six off-diagonal terms of ``M_g`` independently (a non-orthogonal gyro triad that is also
    rotated against the accelerometer's: the matrix is not symmetric); each of the nine terms of
    ``G`` uniform in [-g, g]. ``M_g = diag(1 + s_g) + offdiag``, ``M_a = diag(1 + s_a)``: the
    accelerometer triad defines the IMU frame (its rotation is the pose extrinsic's).
    """
    rng = np.random.default_rng([seed, 7_170_345])

    def signed(lo: float, hi: float, n: int) -> np.ndarray:
        return rng.uniform(lo, hi, n) * rng.choice([-1.0, 1.0], n)

    M_g = np.diag(1.0 + signed(*gyro_scale, 3))
    M_g[~np.eye(3, dtype=bool)] = np.radians(signed(*misalignment_deg, 6))
    M_a = np.diag(1.0 + signed(*acc_scale, 3))
    return IntrinsicErrors(M_g, M_a, rng.uniform(-g_sensitivity, g_sensitivity, (3, 3)))


def gauss_markov_rotvec(t_s: np.ndarray, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """Three unit-variance first-order Gauss-Markov processes at ``t_s`` [M], [M, 3].

    The exact discretisation of ``dx = -x / tau dt + sqrt(2 / tau) dW``: ``x_k = phi x_{k-1} + sqrt(1 - phi^2) w_k``,
    ``phi = exp(-(t_k - t_{k-1}) / tau)``, ``x_0 ~ N(0, 1)`` (stationary), exact for uneven steps.
    """
    w = rng.standard_normal((len(t_s), 3))
    phi = np.exp(-np.diff(np.asarray(t_s, dtype=float)) / tau_s)
    gain = np.sqrt(1.0 - phi**2)
    x = np.empty_like(w)
    x[0] = w[0]
    for k in range(1, len(w)):
        x[k] = phi[k - 1] * x[k - 1] + gain[k - 1] * w[k]
    return x


def make_sequence(
    duration_s: float = 60.0,
    *,
    seed: int = 0,
    motion=None,
    rate_hz: float = 200.0,
    pose_rate_hz: float = 100.0,
    noise: bool = True,
    gtsam_noise: bool = False,
    gyro_random_walk: float = 10 * REPORTED["gyro_random_walk"],
    acc_random_walk: float = 10 * REPORTED["acc_random_walk"],
    gyro_noise_density: float = REPORTED["gyro_noise_density"],
    acc_noise_density: float = REPORTED["acc_noise_density"],
    gyro_turn_on_sigma: float = 0.02,
    acc_turn_on_sigma: float = 0.1,
    position_noise_m: float = 0.5e-3,
    rotation_noise_rad: float = 0.5e-3,
    clock_offset_s: float = 0.0,
    T_imu_marker: np.ndarray | None = None,
    t0_ns: int = T0_NS,
    intrinsics: IntrinsicErrors | None = None,
    gravity_mps2: np.ndarray = GRAVITY_MPS2,
    correlated_rotation_noise_rad: float = 0.0,
    correlated_noise_tau_s: float = 1.0,
    dropouts_s: tuple[tuple[float, float], ...] = (),
) -> IndependentSequence:
    """Generate an independent sequence (IMU with known bias + mocap), see module docstring.

    Args:
        duration_s: IMU span.
        seed: Seeds bias, noise and the mocap phase.
        motion: :class:`LissajousMotion` (default) or :class:`GtsamScenarioMotion`.
        noise: Add white IMU noise and mocap noise (``False``: both noise-free; bias kept).
        gyro_noise_density / acc_noise_density: The white noise's densities (default: the datasheet's).
        gtsam_noise: Draw the IMU white noise with GTSAM's ScenarioRunner (GtsamScenarioMotion only).
        clock_offset_s: Mocap stamps are ``t_imu - clock_offset_s`` (rounded to ns).
        T_imu_marker: Marker extrinsic (default identity: the mocap tracks the IMU).
        intrinsics: IMU intrinsic errors applied to the true rate and specific force (the
            ``*_true`` fields stay the ideal ones).
        gravity_mps2: Gravity in the mocap world frame (tilt it for a frame that is not level).
        correlated_rotation_noise_rad / correlated_noise_tau_s: Stationary std per axis and correlation
            time of a first-order Gauss-Markov attitude error of the mocap (right-multiplied, on top of
            the white noise; :func:`gauss_markov_rotvec`).
        dropouts_s: ``(start, length)`` seconds after the first IMU sample with no mocap samples.
    """
    motion = motion or LissajousMotion()
    rng = np.random.default_rng([seed, 20261122])
    n = int(round(duration_s * rate_hz)) + 1
    rel_ns = np.round(np.arange(n) * (NS / rate_hz)).astype(np.int64)
    t_ns = t0_ns + rel_ns
    t_s = rel_ns / NS
    st = motion.state(t_s)
    w_true = st.omega_body_radps
    f_true = st.specific_force(np.asarray(gravity_mps2, dtype=float))
    bg = random_walk_bias(n, rate_hz, rng, turn_on_sigma=gyro_turn_on_sigma, random_walk=gyro_random_walk)
    ba = random_walk_bias(n, rate_hz, rng, turn_on_sigma=acc_turn_on_sigma, random_walk=acc_random_walk)
    if noise and gtsam_noise:
        ng, na = motion.white_noise(t_s)
    elif noise:
        sq = np.sqrt(rate_hz)
        ng = rng.standard_normal((n, 3)) * gyro_noise_density * sq
        na = rng.standard_normal((n, 3)) * acc_noise_density * sq
    else:
        ng = na = np.zeros((n, 3))

    T = np.eye(4) if T_imu_marker is None else np.asarray(T_imu_marker, float)
    period = NS / pose_rate_hz
    phase_ns = int(rng.integers(0, int(period)))
    m = int((rel_ns[-1] - phase_ns) // period) + 1
    true_rel_ns = phase_ns + np.round(np.arange(m) * period).astype(np.int64)
    pst = motion.state(true_rel_ns / NS)
    p_marker = pst.p_m + pst.rotation.apply(T[:3, 3])
    rot_marker = pst.rotation * Rotation.from_matrix(T[:3, :3])
    if noise:
        p_marker = p_marker + rng.standard_normal((m, 3)) * position_noise_m
        rot_marker = rot_marker * Rotation.from_rotvec(rng.standard_normal((m, 3)) * rotation_noise_rad)
    if correlated_rotation_noise_rad > 0:
        gm_rng = np.random.default_rng([seed, 5_550_123])  # a stream of its own: the other draws are unchanged
        rot_marker = rot_marker * Rotation.from_rotvec(
            gauss_markov_rotvec(true_rel_ns / NS, correlated_noise_tau_s, gm_rng) * correlated_rotation_noise_rad)
    keep = np.ones(m, dtype=bool)
    for start_s, length_s in dropouts_s:
        keep &= ~((true_rel_ns >= start_s * NS) & (true_rel_ns < (start_s + length_s) * NS))
    true_rel_ns, p_marker, rot_marker = true_rel_ns[keep], p_marker[keep], rot_marker[keep]
    pose_t_ns = t0_ns + true_rel_ns - int(round(clock_offset_s * NS))
    w_meas, f_meas = w_true, f_true
    if intrinsics is not None:
        w_meas = w_true @ intrinsics.gyro_matrix.T + f_true @ intrinsics.g_sensitivity.T
        f_meas = f_true @ intrinsics.acc_matrix.T
    return IndependentSequence(
        t_ns=t_ns, gyro_radps=w_meas + bg + ng, acc_mps2=f_meas + ba + na, gyro_true_radps=w_true,
        acc_true_mps2=f_true, bias_gyro_radps=bg, bias_acc_mps2=ba, p_m=st.p_m, quat_wxyz=quat_wxyz(st.rotation),
        v_mps=st.v_mps, pose_t_ns=pose_t_ns, pose_p_m=p_marker, pose_quat_wxyz=quat_wxyz(rot_marker),
        clock_offset_s=float(clock_offset_s), T_imu_marker=T, rate_hz=rate_hz,
    )


# ----------------------------------------------------------------------------- writers (own code)

IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
VICON_HEADER = ("#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], "
                "q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []")
STATE_HEADER = ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
                "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
                "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], "
                "b_a_RS_S_z [m s^-2]")


def _write_csv(path: Path, header: str, t_ns: np.ndarray, values: np.ndarray) -> None:
    """Header line, then ``int stamp, values...`` with round-trip float text (pandas' repr)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    frame = pd.DataFrame(values)
    frame.insert(0, "t", np.asarray(t_ns, dtype=np.int64))
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(header + "\n")
        frame.to_csv(fh, header=False, index=False, lineterminator="\n")


def _yaml_matrix(T: np.ndarray) -> str:
    data = ", ".join(repr(float(x)) for x in np.asarray(T, float).ravel())
    return f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{data}]\n"


def write_euroc(seq: IndependentSequence, root: str | Path, *, extrinsic_known: bool = True,
                with_ground_truth: bool = True) -> Path:
    """Write an EuRoC ASL folder ``root/mav0/{imu0,vicon0,state_groundtruth_estimate0}``.

    ``vicon0/sensor.yaml`` carries ``T_BS = T_imu_marker`` only when ``extrinsic_known``
    (imu0's T_BS is the identity, so body = IMU).
    """
    mav0 = Path(root) / "mav0"
    _write_csv(mav0 / "imu0" / "data.csv", IMU_HEADER, seq.t_ns, np.hstack([seq.gyro_radps, seq.acc_mps2]))
    (mav0 / "imu0" / "sensor.yaml").write_text(
        "%YAML:1.0\n# independent test sequence\nsensor_type: imu\ncomment: independent generator\n"
        + _yaml_matrix(np.eye(4))
        + f"rate_hz: {seq.rate_hz:g}\n"
        + "".join(f"{k}: {REPORTED[v]!r}\n" for k, v in (
            ("gyroscope_noise_density", "gyro_noise_density"), ("gyroscope_random_walk", "gyro_random_walk"),
            ("accelerometer_noise_density", "acc_noise_density"), ("accelerometer_random_walk", "acc_random_walk"))),
        encoding="utf-8")
    _write_csv(mav0 / "vicon0" / "data.csv", VICON_HEADER, seq.pose_t_ns, np.hstack([seq.pose_p_m, seq.pose_quat_wxyz]))
    if extrinsic_known:
        (mav0 / "vicon0" / "sensor.yaml").write_text(
            "%YAML:1.0\nsensor_type: visual-inertial\ncomment: vicon marker\n" + _yaml_matrix(seq.T_imu_marker),
            encoding="utf-8")
    if with_ground_truth:
        _write_csv(mav0 / "state_groundtruth_estimate0" / "data.csv", STATE_HEADER, seq.t_ns,
                   np.hstack([seq.p_m, seq.quat_wxyz, seq.v_mps, seq.bias_gyro_radps, seq.bias_acc_mps2]))
    return Path(root)


def stamps_text(t_ns: np.ndarray) -> list[str]:
    """Exact decimal seconds of int64 ns stamps (non-negative)."""
    return [f"{int(t) // NS}.{int(t) % NS:09d}" for t in np.asarray(t_ns, dtype=np.int64)]


def write_tum_text(path: str | Path, t_ns: np.ndarray, p_m: np.ndarray, quat_wxyz_: np.ndarray) -> Path:
    """A TUM trajectory ``t[s] x y z qx qy qz qw`` (stamps exact to the ns, values repr)."""
    path = Path(path)
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for s, p, q in zip(stamps_text(t_ns), p_m, quat_wxyz_):
        vals = [p[0], p[1], p[2], q[1], q[2], q[3], q[0]]
        lines.append(s + " " + " ".join(repr(float(v)) for v in vals))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_ros1_bag(seq: IndependentSequence, path: str | Path, *, imu_topic: str = "/imu0",
                   pose_topic: str = "/vicon/marker") -> Path:
    """A ROS1 bag with ``sensor_msgs/Imu`` and ``geometry_msgs/PoseStamped`` (rosbags directly).

    Header stamps are the data stamps; receive times are shifted by +3 ms (so a reader that
    took receive times instead of header stamps would be caught).
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    Imu = ts.types["sensor_msgs/msg/Imu"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    V3 = ts.types["geometry_msgs/msg/Vector3"]
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    P = ts.types["geometry_msgs/msg/Point"]
    Pose = ts.types["geometry_msgs/msg/Pose"]
    PoseStamped = ts.types["geometry_msgs/msg/PoseStamped"]
    cov = np.zeros(9)

    def header(t: int, seq_no: int, frame: str):
        return Header(seq=seq_no, stamp=Time(sec=int(t) // NS, nanosec=int(t) % NS), frame_id=frame)

    msgs = []
    for i, t in enumerate(seq.t_ns):
        g, a = seq.gyro_radps[i], seq.acc_mps2[i]
        m = Imu(header=header(t, i, "imu"), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=cov, angular_velocity=V3(x=g[0], y=g[1], z=g[2]),
                angular_velocity_covariance=cov, linear_acceleration=V3(x=a[0], y=a[1], z=a[2]),
                linear_acceleration_covariance=cov)
        msgs.append((int(t), imu_topic, "sensor_msgs/msg/Imu", m))
    for i, t in enumerate(seq.pose_t_ns):
        p, q = seq.pose_p_m[i], seq.pose_quat_wxyz[i]
        m = PoseStamped(header=header(t, i, "world"),
                        pose=Pose(position=P(x=p[0], y=p[1], z=p[2]), orientation=Q(x=q[1], y=q[2], z=q[3], w=q[0])))
        msgs.append((int(t), pose_topic, "geometry_msgs/msg/PoseStamped", m))
    msgs.sort(key=lambda x: x[0])
    path = Path(path)
    with Writer(path) as writer:
        conns = {imu_topic: writer.add_connection(imu_topic, "sensor_msgs/msg/Imu", typestore=ts),
                 pose_topic: writer.add_connection(pose_topic, "geometry_msgs/msg/PoseStamped", typestore=ts)}
        for t, topic, msgtype, m in msgs:
            writer.write(conns[topic], t + 3_000_000, ts.serialize_ros1(m, msgtype))
    return path


# ----------------------------------------------------------------------------- independent integrator


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of [..., 4] wxyz quaternions."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], -1)


def rk4_integrate(gyro_radps: np.ndarray, acc_mps2: np.ndarray, h_s: float, q0_wxyz: np.ndarray,
                  v0: np.ndarray, p0: np.ndarray, gravity_mps2: np.ndarray = GRAVITY_MPS2
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Classical RK4 of ``q' = 1/2 q (0, w)``, ``v' = R(q) f + g``, ``p' = v``.

    Written independently of :mod:`pipeline.geometry.integration`. Samples are uniformly ``h_s``
    apart; one RK4 step spans two sample intervals (stages at samples k, k+1, k+1, k+2), so
    the number of samples must be odd. Batched over a leading window axis.

    Args:
        gyro_radps / acc_mps2: Bias-free samples, [B, T, 3] (T odd).
        h_s: Sample spacing.
        q0_wxyz / v0 / p0: Initial state, [B, 4] / [B, 3] / [B, 3].

    Returns:
        ``(q_wxyz [B, 4], v [B, 3], p [B, 3])`` at the last sample.
    """
    T = gyro_radps.shape[1]
    if T % 2 != 1:
        raise ValueError("rk4_integrate needs an odd number of samples")

    def deriv(q, v, w, f):
        dq = 0.5 * _quat_mul(q, np.concatenate([np.zeros(w.shape[:-1] + (1,)), w], -1))
        qn = q / np.linalg.norm(q, axis=-1, keepdims=True)
        R = Rotation.from_quat(qn[:, [1, 2, 3, 0]])
        return dq, R.apply(f) + gravity_mps2, v

    q, v, p = q0_wxyz.astype(float).copy(), v0.astype(float).copy(), p0.astype(float).copy()
    H = 2.0 * h_s
    for k in range(0, T - 1, 2):
        w0, w1, w2 = gyro_radps[:, k], gyro_radps[:, k + 1], gyro_radps[:, k + 2]
        f0, f1, f2 = acc_mps2[:, k], acc_mps2[:, k + 1], acc_mps2[:, k + 2]
        k1 = deriv(q, v, w0, f0)
        k2 = deriv(q + 0.5 * H * k1[0], v + 0.5 * H * k1[1], w1, f1)
        k3 = deriv(q + 0.5 * H * k2[0], v + 0.5 * H * k2[1], w1, f1)
        k4 = deriv(q + H * k3[0], v + H * k3[1], w2, f2)
        q = q + H / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v_new = v + H / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        p = p + H / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        v = v_new
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return q, v, p


def rotation_error_deg(q_a_wxyz: np.ndarray, q_b_wxyz: np.ndarray) -> np.ndarray:
    """Angle of ``a^-1 b`` in degrees, [B]."""
    ra = Rotation.from_quat(np.asarray(q_a_wxyz)[..., [1, 2, 3, 0]])
    rb = Rotation.from_quat(np.asarray(q_b_wxyz)[..., [1, 2, 3, 0]])
    return np.degrees((ra.inv() * rb).magnitude())


# ----------------------------------------------------------------------------- recovery figures


@dataclass(frozen=True)
class RecoveryFigures:
    """Errors of a recovery result against an independent truth."""

    gyro_rmse_radps: np.ndarray  # [3]
    acc_rmse_mps2: np.ndarray  # [3]
    nees_gyro: float  # per DoF
    nees_acc: float
    offset_error_s: float
    extrinsic_rot_error_deg: float
    extrinsic_trans_error_m: float
    nees_per_axis: np.ndarray | None = None  # [6] gyro xyz, acc xyz

    def lines(self, name: str) -> list[str]:
        return [
            f"[{name}] gyro RMSE per axis {np.array2string(self.gyro_rmse_radps, precision=7)} rad/s",
            f"[{name}] acc  RMSE per axis {np.array2string(self.acc_rmse_mps2, precision=6)} m/s^2",
            f"[{name}] NEES per DoF gyro {self.nees_gyro:.3f}, acc {self.nees_acc:.3f}",
            f"[{name}] clock offset error {self.offset_error_s * 1e3:.4f} ms; extrinsic error "
            f"{self.extrinsic_rot_error_deg:.4f} deg, {self.extrinsic_trans_error_m * 100:.3f} cm",
        ]


def recovery_figures(result, seq: IndependentSequence) -> RecoveryFigures:
    """Per-axis bias RMSE, NEES, clock-offset and extrinsic errors of ``result`` vs the truth."""
    rel_truth = (seq.t_ns - seq.t_ns[0]).astype(float)
    rel = (np.asarray(result.t_ns, dtype=np.int64) - seq.t_ns[0]).astype(float)
    tg = np.stack([np.interp(rel, rel_truth, seq.bias_gyro_radps[:, c]) for c in range(3)], 1)
    ta = np.stack([np.interp(rel, rel_truth, seq.bias_acc_mps2[:, c]) for c in range(3)], 1)
    eg, ea = result.bias_gyro_radps - tg, result.bias_acc_mps2 - ta
    rep = result.report
    q = rep["T_imu_pose"]["quat_wxyz"]
    R_est = Rotation.from_quat([q[1], q[2], q[3], q[0]])
    rot_err = float(np.degrees((R_est.inv() * Rotation.from_matrix(seq.T_imu_marker[:3, :3])).magnitude()))
    trans_err = float(np.linalg.norm(np.asarray(rep["T_imu_pose"]["p_m"]) - seq.T_imu_marker[:3, 3]))
    return RecoveryFigures(
        gyro_rmse_radps=np.sqrt((eg**2).mean(0)), acc_rmse_mps2=np.sqrt((ea**2).mean(0)),
        nees_gyro=float(((eg / result.bias_gyro_std_radps) ** 2).mean()),
        nees_acc=float(((ea / result.bias_acc_std_mps2) ** 2).mean()),
        offset_error_s=float(rep["pose_time_offset_s"] - seq.clock_offset_s),
        extrinsic_rot_error_deg=rot_err, extrinsic_trans_error_m=trans_err,
        nees_per_axis=np.concatenate([((eg / result.bias_gyro_std_radps) ** 2).mean(0),
                                      ((ea / result.bias_acc_std_mps2) ** 2).mean(0)]),
    )
