"""IMU error model: bias (turn-on + random walk + temperature term), white noise, scale/misalignment.

All functions are vectorised over the samples; one hour at 200 Hz takes well under a second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from pipeline.sim.config import ImuNoiseConfig, TemperatureConfig


@dataclass(frozen=True)
class BiasTruth:
    """The true bias at the IMU stamps and the draws that made it.

    Attributes:
        bias_gyro_radps: [N, 3].
        bias_acc_mps2: [N, 3].
        temperature_degc: Die temperature [N] (``None`` when the bias came from a file).
        turn_on_gyro_radps / turn_on_acc_mps2: The constant parts, [3].
        temp_coeff_gyro / temp_coeff_acc: Per-axis temperature coefficients, [3] (per degC).
    """

    bias_gyro_radps: np.ndarray
    bias_acc_mps2: np.ndarray
    temperature_degc: np.ndarray | None
    turn_on_gyro_radps: np.ndarray
    turn_on_acc_mps2: np.ndarray
    temp_coeff_gyro: np.ndarray
    temp_coeff_acc: np.ndarray


@dataclass(frozen=True)
class SensorMatrices:
    """Deterministic sensor errors: ``gyro = M_g w + G f + ...``, ``acc = M_a f + ...``.

    Attributes:
        gyro_matrix: M_g, [3, 3] (identity when off).
        acc_matrix: M_a, [3, 3].
        gyro_g_sensitivity: G, [3, 3] rad/s per m/s^2 (zero when off).
    """

    gyro_matrix: np.ndarray
    acc_matrix: np.ndarray
    gyro_g_sensitivity: np.ndarray


def temperature_profile(cfg: TemperatureConfig, t_s: np.ndarray) -> np.ndarray:
    """Die temperature [N] at times ``t_s`` [N] (seconds from the start)."""
    warm = cfg.warmup_delta_degc * (1.0 - np.exp(-t_s / cfg.warmup_tau_s)) if cfg.warmup_tau_s > 0 else 0.0
    osc = 0.0
    if cfg.oscillation_period_s > 0:
        osc = cfg.oscillation_amp_degc * np.sin(2.0 * np.pi * t_s / cfg.oscillation_period_s)
    return cfg.ambient_degc + warm + osc


def _first_order_lag(x: np.ndarray, dt_s: float, tau_s: float) -> np.ndarray:
    """Exact discretisation of ``tau y' = x - y`` with ``y(0) = 0`` (x [N] starts near 0)."""
    if tau_s <= 0:
        return x.copy()
    alpha = 1.0 - np.exp(-dt_s / tau_s)
    return lfilter([alpha], [1.0, alpha - 1.0], x)


def simulate_bias(
    cfg: ImuNoiseConfig,
    t_s: np.ndarray,
    rng_turn_on: np.random.Generator,
    rng_walk: np.random.Generator,
    rng_temp: np.random.Generator,
) -> BiasTruth:
    """The true bias at the IMU stamps.

    Args:
        cfg: IMU error model.
        t_s: Sample times [N], seconds from the first stamp (uniform, 1 / rate_hz apart).
        rng_turn_on / rng_walk / rng_temp: Independent random streams per component.

    Returns:
        ``b(t) = turn_on + random_walk(t) + coeff * (lag(T)(t) - reference)`` for gyro and
        accelerometer (``reference`` default ``T(0)``; see :class:`TemperatureConfig`).
        The random walk starts at 0 and has increments ``N(0, sigma^2 dt)``.
    """
    n = len(t_s)
    dt = 1.0 / cfg.rate_hz
    tg = rng_turn_on.normal(0.0, 1.0, 3) * cfg.gyro_turn_on_sigma
    ta = rng_turn_on.normal(0.0, 1.0, 3) * cfg.acc_turn_on_sigma
    if not cfg.turn_on_bias:
        tg, ta = np.zeros(3), np.zeros(3)
    else:  # the unit's repeatable part, the same in every run
        tg = tg + (0.0 if cfg.gyro_turn_on_mean_radps is None else np.asarray(cfg.gyro_turn_on_mean_radps, float))
        ta = ta + (0.0 if cfg.acc_turn_on_mean_mps2 is None else np.asarray(cfg.acc_turn_on_mean_mps2, float))
    bg = np.broadcast_to(tg, (n, 3)).copy()
    ba = np.broadcast_to(ta, (n, 3)).copy()
    if cfg.bias_random_walk and n > 1:
        steps = rng_walk.normal(0.0, np.sqrt(dt), size=(n - 1, 6))
        walk = np.vstack([np.zeros((1, 6)), np.cumsum(steps, axis=0)])
        bg += walk[:, :3] * cfg.gyro_random_walk
        ba += walk[:, 3:] * cfg.acc_random_walk
    tcfg = cfg.temperature
    temperature = temperature_profile(tcfg, t_s)
    cg = rng_temp.normal(0.0, 1.0, 3) * tcfg.gyro_coeff_sigma
    ca = rng_temp.normal(0.0, 1.0, 3) * tcfg.acc_coeff_sigma
    if tcfg.gyro_coeff_radps_per_degc is not None:
        cg = np.asarray(tcfg.gyro_coeff_radps_per_degc, dtype=np.float64)
    if tcfg.acc_coeff_mps2_per_degc is not None:
        ca = np.asarray(tcfg.acc_coeff_mps2_per_degc, dtype=np.float64)
    if tcfg.enabled:
        reference = temperature[0] if tcfg.reference_degc is None else tcfg.reference_degc
        lagged = _first_order_lag(temperature - temperature[0], dt, tcfg.sensor_tau_s) + (temperature[0] - reference)
        bg += lagged[:, None] * cg
        ba += lagged[:, None] * ca
    else:
        cg, ca = np.zeros(3), np.zeros(3)
    return BiasTruth(bg, ba, temperature, tg, ta, cg, ca)


def sensor_matrices(cfg: ImuNoiseConfig, rng: np.random.Generator) -> SensorMatrices:
    """Draw scale factor, misalignment and g-sensitivity (identity / zero when their sigma is 0)."""
    draws = rng.normal(0.0, 1.0, size=(5, 3, 3))
    off = ~np.eye(3, dtype=bool)

    def matrix(scale_sigma: float, mis_sigma: float, d_scale: np.ndarray, d_mis: np.ndarray) -> np.ndarray:
        m = np.eye(3) + np.diag(np.diag(d_scale)) * scale_sigma
        m[off] += d_mis[off] * mis_sigma
        return m

    return SensorMatrices(
        gyro_matrix=matrix(cfg.gyro_scale_sigma, cfg.gyro_misalignment_sigma, draws[0], draws[1]),
        acc_matrix=matrix(cfg.acc_scale_sigma, cfg.acc_misalignment_sigma, draws[2], draws[3]),
        gyro_g_sensitivity=draws[4] * cfg.gyro_g_sensitivity_sigma + 0.0,
    )


def _apply(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``x @ M.T`` for [N, 3] ``x``; a copy of ``x`` when ``M`` is the identity."""
    return x.copy() if np.array_equal(M, np.eye(3)) else x @ M.T


def measure(
    cfg: ImuNoiseConfig,
    omega_body_radps: np.ndarray,
    f_body_mps2: np.ndarray,
    bias_gyro_radps: np.ndarray,
    bias_acc_mps2: np.ndarray,
    matrices: SensorMatrices,
    rng_noise: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """IMU readings from the true rate and specific force.

    Args:
        omega_body_radps / f_body_mps2: True angular rate and specific force, [N, 3].
        bias_gyro_radps / bias_acc_mps2: True bias, [N, 3].
        matrices: Scale/misalignment/g-sensitivity.
        rng_noise: White-noise stream.

    Returns:
        ``(gyro_radps [N, 3], acc_mps2 [N, 3])``; white noise has discrete standard deviation
        ``density * sqrt(rate_hz)``.
    """
    gyro = _apply(matrices.gyro_matrix, omega_body_radps) + bias_gyro_radps
    if np.any(matrices.gyro_g_sensitivity):
        gyro = gyro + f_body_mps2 @ matrices.gyro_g_sensitivity.T
    acc = _apply(matrices.acc_matrix, f_body_mps2) + bias_acc_mps2
    if cfg.white_noise:
        noise = rng_noise.normal(0.0, 1.0, size=(len(gyro), 6))
        sq = np.sqrt(cfg.rate_hz)
        gyro = gyro + noise[:, :3] * (cfg.gyro_noise_density * sq)
        acc = acc + noise[:, 3:] * (cfg.acc_noise_density * sq)
    return gyro, acc
