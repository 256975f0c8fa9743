"""True continuous motion of the IMU: smooth splines with analytic derivatives.

Position is a C2 cubic spline (acceleration continuous, piecewise linear), orientation a
:class:`scipy.spatial.transform.RotationSpline` (continuous angular rate and angular
acceleration). The IMU sees, at any time ``t``::

    omega_body(t) = body-frame angular rate of R_world_imu(t)
    f_body(t)     = R_world_imu(t)^T (a_world(t) - g_world)

``RotationSpline(t, 1)`` returns the angular rate in the BODY frame for scipy's
implementation (``R = R_i * exp(theta(t))``); :func:`angular_rate_body` relies on that and
``tests/inputs/test_sim.py`` checks it against a finite difference of the rotation.

Time inside a :class:`Trajectory` is float seconds relative to the first IMU stamp.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline, make_lsq_spline
from scipy.spatial.transform import Rotation, RotationSpline

from pipeline.errors import ConfigError, DataError, InputFormatError
from pipeline.io.asl import read_asl_state_csv
from pipeline.io.tum import detect_tum, read_tum_poses
from pipeline.sim.config import PresetParams
from pipeline.types import PoseSeries, PoseSourceKind, StateSeries

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000


def quat_wxyz_continuous(rotation: Rotation) -> np.ndarray:
    """Hamilton quaternions [N, 4] (w, x, y, z) without sign flips between neighbours; q[0] has w >= 0."""
    q = rotation.as_quat(canonical=True)[:, [3, 0, 1, 2]]
    if len(q) > 1:
        flip = np.cumsum(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0) % 2 == 1
        q[1:][flip] *= -1.0
    return q


@dataclass(frozen=True)
class MotionSample:
    """The true kinematic state at a set of times (world frame = gravity-aligned, z up).

    Attributes:
        p_m: Position of the IMU, [N, 3].
        v_mps: Velocity, [N, 3].
        a_mps2: Acceleration (not specific force), [N, 3].
        rotation: World-from-IMU rotations (N of them).
        omega_body_radps: Angular rate in the IMU frame, [N, 3].
    """

    p_m: np.ndarray
    v_mps: np.ndarray
    a_mps2: np.ndarray
    rotation: Rotation
    omega_body_radps: np.ndarray

    def specific_force(self, gravity_mps2: np.ndarray) -> np.ndarray:
        """``R^T (a - g)`` in the IMU frame, [N, 3]."""
        return self.rotation.inv().apply(self.a_mps2 - np.asarray(gravity_mps2, dtype=float))


class Trajectory:
    """Continuous pose of the IMU in the world, valid on ``[t_min_s, t_max_s]``.

    Args:
        position_spline: Callable ``f(t, nu)`` returning [N, 3] (CubicSpline or BSpline).
        rotation_spline: World-from-IMU orientation spline.
        t_min_s / t_max_s: Domain of validity (seconds relative to the first IMU stamp).
    """

    def __init__(self, position_spline, rotation_spline: RotationSpline, t_min_s: float, t_max_s: float) -> None:
        self._pos = position_spline
        self._rot = rotation_spline
        self.t_min_s = float(t_min_s)
        self.t_max_s = float(t_max_s)

    def _check(self, t_s: np.ndarray) -> np.ndarray:
        t_s = np.atleast_1d(np.asarray(t_s, dtype=float))
        if len(t_s) and (t_s.min() < self.t_min_s - 1e-9 or t_s.max() > self.t_max_s + 1e-9):
            raise DataError(
                f"motion evaluated at t in [{t_s.min():.3f}, {t_s.max():.3f}] s outside its domain "
                f"[{self.t_min_s:.3f}, {self.t_max_s:.3f}] s"
            )
        return t_s

    def position(self, t_s: np.ndarray) -> np.ndarray:
        """Position [N, 3]."""
        return np.asarray(self._pos(self._check(t_s), 0))

    def rotation(self, t_s: np.ndarray) -> Rotation:
        """World-from-IMU rotations."""
        return self._rot(self._check(t_s))

    def angular_rate_body(self, t_s: np.ndarray) -> np.ndarray:
        """Body-frame angular rate [N, 3] (scipy's RotationSpline rate is body-frame)."""
        return np.asarray(self._rot(self._check(t_s), 1))

    def sample(self, t_s: np.ndarray) -> MotionSample:
        """Full kinematic state at ``t_s`` [N]."""
        t_s = self._check(t_s)
        return MotionSample(
            p_m=np.asarray(self._pos(t_s, 0)),
            v_mps=np.asarray(self._pos(t_s, 1)),
            a_mps2=np.asarray(self._pos(t_s, 2)),
            rotation=self._rot(t_s),
            omega_body_radps=np.asarray(self._rot(t_s, 1)),
        )


class RestThenMove(Trajectory):
    """A trajectory at rest (at ``inner``'s pose at t = 0) until ``rest_s``, then ``inner`` started
    smoothly: time is warped as ``u(t)`` with ``u' = 0`` at rest, rising as a smoothstep to 1 over
    ``ramp_s`` (``u''`` continuous), so the motion's rates and accelerations are continuous. Same
    interface as :class:`Trajectory`; valid for ``t <= inner.t_max_s + rest_s``."""

    def __init__(self, inner: Trajectory, rest_s: float, ramp_s: float = 2.0) -> None:
        super().__init__(inner._pos, inner._rot, inner.t_min_s, inner.t_max_s + float(rest_s))
        self._inner, self.rest_s, self.ramp_s = inner, float(rest_s), float(ramp_s)

    def _warp(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(u, du/dt, d2u/dt2)`` at ``t_s``."""
        t = self._check(t_s)
        x = np.clip((t - self.rest_s) / self.ramp_s, 0.0, 1.0)
        u = np.where(x < 1.0, self.ramp_s * (x**3 - 0.5 * x**4), t - self.rest_s - 0.5 * self.ramp_s)
        return u, 3 * x**2 - 2 * x**3, 6 * x * (1 - x) / self.ramp_s

    def position(self, t_s: np.ndarray) -> np.ndarray:
        return self._inner.position(self._warp(t_s)[0])

    def rotation(self, t_s: np.ndarray) -> Rotation:
        return self._inner.rotation(self._warp(t_s)[0])

    def angular_rate_body(self, t_s: np.ndarray) -> np.ndarray:
        u, du, _ = self._warp(t_s)
        return self._inner.angular_rate_body(u) * du[:, None]

    def sample(self, t_s: np.ndarray) -> MotionSample:
        u, du, ddu = self._warp(t_s)
        s = self._inner.sample(u)
        return MotionSample(p_m=s.p_m, v_mps=s.v_mps * du[:, None],
                            a_mps2=s.a_mps2 * du[:, None] ** 2 + s.v_mps * ddu[:, None],
                            rotation=s.rotation, omega_body_radps=s.omega_body_radps * du[:, None])


def random_trajectory(params: PresetParams, t_end_s: float, rng: np.random.Generator, *, pad_s: float) -> Trajectory:
    """Random smooth motion through waypoints and key orientations.

    Args:
        params: Preset numbers (key spacing, amplitudes, angle limits).
        t_end_s: The motion must be valid on ``[-pad_s, t_end_s + pad_s]``.
        rng: Random generator (motion stream).
        pad_s: Extra time at both ends (spline end effects, pose clock offsets).

    Returns:
        The trajectory; waypoints are uniform in the box ``+-position_amplitude_m`` around
        (0, 0, 1) m, roll/pitch uniform in ``+-max_roll_pitch_deg``, yaw a random walk.
    """
    h = params.key_interval_s
    n_keys = int(np.ceil((t_end_s + 2 * pad_s) / h)) + 3
    t_keys = -pad_s - h + h * np.arange(n_keys)
    amp = np.asarray(params.position_amplitude_m, dtype=float)
    waypoints = rng.uniform(-1.0, 1.0, size=(n_keys, 3)) * amp + np.array([0.0, 0.0, 1.0])
    position = CubicSpline(t_keys, waypoints, axis=0)

    lim = np.deg2rad(params.max_roll_pitch_deg)
    step = np.deg2rad(params.yaw_step_deg)
    yaw = np.cumsum(np.clip(rng.normal(0.0, step, n_keys), -np.deg2rad(150), np.deg2rad(150)))
    yaw += rng.uniform(-np.pi, np.pi)
    roll_pitch = rng.uniform(-lim, lim, size=(n_keys, 2))
    keys = Rotation.from_euler("ZYX", np.column_stack([yaw, roll_pitch[:, 1], roll_pitch[:, 0]]))
    return Trajectory(position, RotationSpline(t_keys, keys), t_keys[0], t_keys[-1])


def read_ground_truth_file(path: str | Path) -> StateSeries | PoseSeries:
    """Read the motion of a semi-real simulation.

    Two kinds of file are accepted:

    * a EuRoC ground-truth state CSV (``state_groundtruth_estimate0/data.csv``, read with
      :func:`pipeline.io.asl.read_asl_state_csv`): motion and bias -> :class:`StateSeries`;
    * a TUM pose file of the IMU (``t[s] x y z qx qy qz qw``, read with
      :func:`pipeline.io.tum.read_tum_poses`), e.g. EuRoC's ground truth of a sequence whose state
      file is not at hand: motion only -> :class:`PoseSeries` (the simulator then draws the bias
      from the IMU's random-walk model).

    Rows are sorted by stamp and repeated stamps dropped (the simulator needs a function of time).

    Raises:
        ConfigError: The file does not exist.
        InputFormatError: It is neither kind of file, or holds fewer than 10 rows.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError("ground-truth file not found", path=path, field="motion.ground_truth_path")
    motion: StateSeries | PoseSeries
    if detect_tum(path):
        motion, findings = read_tum_poses(path, source_kind=PoseSourceKind.GROUND_TRUTH)
    else:
        motion, findings = read_asl_state_csv(path)
    for finding in findings:
        log.warning("%s: %s", path, finding.message)
    if len(motion) < 10:
        raise InputFormatError(f"only {len(motion)} ground-truth rows", path=path,
                               hint="give a mav0/state_groundtruth_estimate0/data.csv or a TUM pose file of the IMU")
    order = np.argsort(motion.t_ns, kind="stable")
    keep = np.r_[True, np.diff(motion.t_ns[order]) > 0]
    return motion.take(order[keep])


def ground_truth_trajectory(
    gt: StateSeries | PoseSeries,
    t0_ns: int,
    *,
    position_knot_interval_s: float,
    orientation_key_interval_s: float,
) -> Trajectory:
    """Smooth splines fitted to a ground-truth file, time relative to ``t0_ns``.

    Position: least-squares cubic B-spline with knots every ``position_knot_interval_s``
    (removes the file's micrometre quantisation so the derived accelerometer is not noisy).
    Orientation: RotationSpline through the file's orientations taken every
    ``orientation_key_interval_s``.
    """
    t_s = (gt.t_ns - t0_ns) / NS_PER_S
    span = t_s[-1] - t_s[0]
    if span < 4 * max(position_knot_interval_s, orientation_key_interval_s):
        raise DataError(f"ground-truth file spans only {span:.3f} s")
    n_int = max(int(np.floor(span / position_knot_interval_s)) - 1, 1)
    interior = np.linspace(t_s[0], t_s[-1], n_int + 2)[1:-1]
    knots = np.r_[[t_s[0]] * 4, interior, [t_s[-1]] * 4]
    try:
        position = make_lsq_spline(t_s, gt.p_m, knots, k=3, axis=0)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise DataError(
            f"cannot fit a position spline to the ground truth ({exc}); the file probably has a gap longer "
            f"than motion.gt_position_knot_interval_s={position_knot_interval_s}"
        ) from None
    grid = np.arange(t_s[0], t_s[-1], orientation_key_interval_s)
    idx = np.unique(np.r_[np.searchsorted(t_s, grid).clip(0, len(t_s) - 1), len(t_s) - 1])
    quat_xyzw = gt.quat_wxyz[idx][:, [1, 2, 3, 0]]
    rotation = RotationSpline(t_s[idx], Rotation.from_quat(quat_xyzw))
    return Trajectory(position, rotation, t_s[idx[0]], t_s[idx[-1]])
