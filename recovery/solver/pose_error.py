"""A pose stream's time-correlated error, as states of the factor graph.

Motion capture errors are not white: marker occlusions, the marker model's fit and the
cameras' calibration give the measured pose an error that wanders for tenths of a second to
seconds, on top of the sample noise. Modelled as white, that error has nowhere to go but the
bias: the bias random walk chosen by evidence runs to its bound and the bias bends with it.
Here the error of each tracked-frame axis group is a first-order Gauss-Markov process
(Ornstein-Uhlenbeck), a variable per keyframe, so the graph can tell it from the bias: a
stationary error of bounded size, against a bias whose walk grows without bound.

Notation (tracked-frame tangent, GTSAM's Pose3 order [rotation (3), translation (3)]):
    z_k     the measured pose of the tracked frame at keyframe k; E = T_imu_pose; X_k the IMU pose
    eps_k   the stream's error, ``z_k = X_k E Exp(eps_k)``
    n_k     its correlated part, the graph variable ``N(k)`` (the active components only)
    a_k     ``exp(-dt_k / tau)`` between keyframes k and k+1

Model:
    1. ``n_0 ~ N(0, sigma^2)``                                      (stationary start)
    2. ``n_{k+1} = a_k n_k + w_k``, ``w_k ~ N(0, (1 - a_k^2) sigma^2)``   (Gauss-Markov step)
    3. ``eps_k - n_k`` is white: the sample noise of the stream (fused keyframes: over the count)

The pose factor with the correlated part (:func:`imu_pose_factor`, extrinsic held fixed) has
the error ``Log(Xm_k^-1 X_k) + Ad_E S n_k`` with ``Xm_k = z_k E^-1`` (its IMU-tangent form, as
GTSAM's PriorFactorPose3 on ``X_k``); with the extrinsic a variable (:func:`tracked_pose_factor`)
``Log(z_k^-1 X_k E) + S n_k``; ``S`` [6, m] selects the active components.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np

from pipeline.types import NS_PER_S


def error_key(k: int) -> int:
    """The key of keyframe ``k``'s correlated pose error ``N(k)``."""
    return gtsam.Symbol("n", k).key()


@dataclass(frozen=True)
class PoseErrorModel:
    """First-order Gauss-Markov error of a 6-DoF pose stream, per axis group of the tracked frame.

    Attributes:
        rotation_sigma_rad: Stationary 1-sigma of the correlated rotation error per axis (0: none).
        rotation_tau_s: Its correlation time.
        position_sigma_m: Stationary 1-sigma of the correlated position error per axis (0: none).
        position_tau_s: Its correlation time.
    """

    rotation_sigma_rad: float = 0.0
    rotation_tau_s: float = 1.0
    position_sigma_m: float = 0.0
    position_tau_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("rotation_sigma_rad", "position_sigma_m"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        for name in ("rotation_tau_s", "position_tau_s"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")

    @property
    def active(self) -> bool:
        """Whether any component is modelled."""
        return self.rotation_sigma_rad > 0.0 or self.position_sigma_m > 0.0

    @property
    def position_active(self) -> bool:
        return self.position_sigma_m > 0.0

    def selection(self) -> np.ndarray:
        """``S`` [6, m]: the active components of the tangent (rotation first)."""
        mask = np.array([self.rotation_sigma_rad > 0.0] * 3 + [self.position_sigma_m > 0.0] * 3)
        return np.eye(6)[:, mask]

    def sigmas_taus(self) -> tuple[np.ndarray, np.ndarray]:
        """Stationary sigmas and correlation times of the active components, [m] each."""
        sig = np.array([self.rotation_sigma_rad] * 3 + [self.position_sigma_m] * 3)
        tau = np.array([self.rotation_tau_s] * 3 + [self.position_tau_s] * 3)
        keep = sig > 0.0
        return sig[keep], tau[keep]

    def replace(self, **changes: float) -> "PoseErrorModel":
        return PoseErrorModel(**{**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, float]:
        return {"rotation_sigma_rad": float(self.rotation_sigma_rad), "rotation_tau_s": float(self.rotation_tau_s),
                "position_sigma_m": float(self.position_sigma_m), "position_tau_s": float(self.position_tau_s)}


def add_error_states(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, t_ns: np.ndarray,
                     model: PoseErrorModel) -> float:
    """Add ``N(k)`` for every keyframe (zero) and the Gauss-Markov process over them.

    The process's density (steps 1-2 of the module docstring) is a quadratic form whose
    precision is tridiagonal; it is written with GTSAM's native vector factors, exactly:
    expanding ``(n_{k+1} - a_k n_k)^2 / v_k`` (``v_k = (1 - a_k^2) sigma^2``) gives

        ``(n_{k+1} - n_k)^2 / q_k``  with  ``q_k = v_k / a_k``            (BetweenFactorVector)
        ``n_k^2 p_k``  with  ``p_k = (1 / (1 + a_{k-1}) - a_k / (1 + a_k)) / sigma^2``   (PriorFactorVector)

    (the first node without the ``a_{k-1}`` term but with the stationary prior's ``1 / sigma^2``,
    the last without the ``a_k`` term; each ``p_k >= 0``). The factors' own Gaussian normalisers
    differ from the process's, which is returned instead.

    Args:
        graph / values: The window's graph and initial values (extended in place).
        t_ns: Keyframe stamps, int64 [K].
        model: An active model.

    Returns:
        The process's Gaussian normaliser (``0.5 log det(2 pi Cov)``, for the evidence).
    """
    sig, tau = model.sigmas_taus()
    m, K = len(sig), len(t_ns)
    zero = np.zeros(m)
    for k in range(K):
        values.insert(error_key(k), zero)
    dt_s = np.diff(np.asarray(t_ns, dtype=np.int64)) / NS_PER_S
    a = np.exp(-dt_s[:, None] / tau[None, :])  # [K - 1, m]
    v = np.maximum(1.0 - a * a, 1e-12) * sig**2
    precision = np.zeros((K, m))
    precision[0] += 1.0 / sig**2
    precision[1:] += 1.0 / ((1.0 + a) * sig**2)
    precision[:-1] -= a / ((1.0 + a) * sig**2)
    for k in range(K - 1):
        live = a[k] > 1e-12
        if live.all():
            graph.add(gtsam.BetweenFactorVector(error_key(k), error_key(k + 1), zero,
                                                gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(v[k] / a[k]))))
        elif live.any():  # a long gap on some component: only the others are linked
            sigmas = np.where(live, np.sqrt(v[k] / np.maximum(a[k], 1e-300)), 1e150)
            graph.add(gtsam.BetweenFactorVector(error_key(k), error_key(k + 1), zero,
                                                gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    for k in range(K):
        p = np.maximum(precision[k], 1e-300)
        graph.add(gtsam.PriorFactorVector(error_key(k), zero, gtsam.noiseModel.Diagonal.Precisions(p)))
    return float(0.5 * m * K * math.log(2.0 * math.pi) + np.sum(np.log(sig)) + 0.5 * np.sum(np.log(v)))


def imu_pose_factor(x_meas: gtsam.Pose3, Ad_E: np.ndarray, S: np.ndarray, noise: Any, key_x: int,
                    key_n: int) -> gtsam.CustomFactor:
    """A measured IMU pose ``Xm = z E^-1`` with the correlated error ``N``: ``Log(Xm^-1 X) + Ad_E S n``.

    Args:
        x_meas: The measured IMU pose. Ad_E: ``E``'s adjoint [6, 6]. S: The active components [6, m].
        noise: The white part's model in the IMU tangent (robust or not).
    """
    AdS = np.asarray(Ad_E @ S, dtype=float, order="F")

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        x = values.atPose3(key_x)
        Hm = np.zeros((6, 6), order="F")
        Hx = np.zeros((6, 6), order="F")
        d = x_meas.between(x, Hm, Hx)
        Hl = np.zeros((6, 6), order="F")
        r = gtsam.Pose3.Logmap(d, Hl) + AdS @ values.atVector(key_n)
        if H is not None:
            H[0] = Hl @ Hx
            H[1] = AdS
        return r

    return gtsam.CustomFactor(noise, [key_x, key_n], error)


def tracked_pose_factor(z: gtsam.Pose3, S: np.ndarray, noise: Any, key_x: int, key_e: int,
                        key_n: int) -> gtsam.CustomFactor:
    """A measured tracked-frame pose with the extrinsic ``E`` a variable: ``Log(z^-1 X E) + S n``
    (``noise``: the white part's model in the tracked-frame tangent)."""
    S = np.asarray(S, dtype=float, order="F")

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        x, e = values.atPose3(key_x), values.atPose3(key_e)
        Hx = np.zeros((6, 6), order="F")
        He = np.zeros((6, 6), order="F")
        pred = x.compose(e, Hx, He)
        Hz = np.zeros((6, 6), order="F")
        Hp = np.zeros((6, 6), order="F")
        d = z.between(pred, Hz, Hp)
        Hl = np.zeros((6, 6), order="F")
        r = gtsam.Pose3.Logmap(d, Hl) + S @ values.atVector(key_n)
        if H is not None:
            H[0] = Hl @ Hp @ Hx
            H[1] = Hl @ Hp @ He
            H[2] = S
        return r

    return gtsam.CustomFactor(noise, [key_x, key_e, key_n], error)


def rotation_factor(R_meas: gtsam.Rot3, R_E: np.ndarray, S_rot: np.ndarray, noise: Any, key_x: int,
                    key_n: int) -> gtsam.CustomFactor:
    """The measured IMU rotation ``Rm = R_z R_E^T`` with the correlated error (lever arm estimated,
    ``R_E`` fixed): ``Log(Rm^-1 R_X) + R_E S_rot n`` (``S_rot`` [3, m]: the rotation rows of ``S``)."""
    A = np.asarray(R_E @ S_rot, dtype=float, order="F")
    R_inv = R_meas.inverse()

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        Hr = np.zeros((3, 6), order="F")
        r_x = values.atPose3(key_x).rotation(Hr)
        Hl = np.zeros((3, 3), order="F")
        r = gtsam.Rot3.Logmap(R_inv.compose(r_x), Hl) + A @ values.atVector(key_n)
        if H is not None:
            H[0] = Hl @ Hr  # d(Rm^-1 R_X) / dR_X is the identity in the right tangent
            H[1] = A
        return r

    return gtsam.CustomFactor(noise, [key_x, key_n], error)


def lever_position_factor(p_meas_m: np.ndarray, R_E: np.ndarray, S_pos: np.ndarray, noise: Any, key_x: int,
                          key_l: int, key_n: int) -> gtsam.CustomFactor:
    """The measured tracked-point position with the lever arm ``L`` a variable and the correlated
    error: ``X (L + R_E S_pos n) - p_meas`` (``S_pos`` [3, m]: the position rows of ``S``)."""
    A = np.asarray(R_E @ S_pos, dtype=float, order="F")
    p_meas_m = np.asarray(p_meas_m, dtype=float)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        Hx = np.zeros((3, 6), order="F")
        Hq = np.zeros((3, 3), order="F")
        q = values.atPoint3(key_l) + A @ values.atVector(key_n)
        r = values.atPose3(key_x).transformFrom(q, Hx, Hq) - p_meas_m
        if H is not None:
            H[0] = Hx
            H[1] = Hq
            H[2] = Hq @ A
        return r

    return gtsam.CustomFactor(noise, [key_x, key_l, key_n], error)


def velocity_fit_variance(model: PoseErrorModel, span_s: float, n: int) -> float:
    """Variance per axis (m^2/s^2) that the correlated position error adds to the least-squares slope of
    ``n`` samples evenly spread over ``span_s``: ``w^T C w`` with ``w`` the slope's weights and
    ``C = sigma^2 exp(-|t_i - t_j| / tau)`` the process's covariance (0 for fewer than 2 samples)."""
    if not model.position_active or span_s <= 0 or n < 2:
        return 0.0
    t = np.linspace(0.0, span_s, n)
    w = (t - t.mean()) / np.sum((t - t.mean()) ** 2)
    C = model.position_sigma_m**2 * np.exp(-np.abs(t[:, None] - t[None, :]) / model.position_tau_s)
    return float(w @ C @ w)
