"""How well can a bias be recovered at all? The optimal smoother's error for the noise at hand.

One axis, attitude and everything else known: the bias ``b`` is a random walk
(``b' = q w``) seen through the difference between the IMU and the differentiated
pose stream. For the gyro, ``omega_meas - d(theta_meas)/dt = b + n_g - d(n_theta)/dt``;
for the accelerometer, ``f_meas - d2(p_meas)/dt2 = b + n_a - d2(n_p)/dt2``. With white
pose noise of variance ``sigma^2`` at ``rate`` samples/s (spectral density
``r = sigma^2 / rate``), the noise spectrum is ``S_n(w) = s_imu^2 + r w^(2 m)``
(``m`` = 1 for attitude, 2 for position) against the bias spectrum
``S_b(w) = q^2 / w^2``. The steady-state error variance of the optimal (Wiener)
smoother is

    var = (1 / pi) * integral_0^inf S_b S_n / (S_b + S_n) dw

so ``sqrt(var)`` is a floor no estimator beats on that axis (real recoveries also
estimate attitude, gravity and the extrinsic, and sit somewhat above it).
"""

from __future__ import annotations

import math

from scipy.integrate import quad


def bias_rmse_floor(noise_density: float, random_walk: float, pose_sigma: float, pose_rate_hz: float,
                    derivative_order: int) -> float:
    """Steady-state RMSE of the optimal smoother of one bias axis (see the module docstring).

    Args:
        noise_density: IMU white noise, rad/s/sqrt(Hz) (gyro) or m/s^2/sqrt(Hz) (acc).
        random_walk: Bias random walk, rad/s^2/sqrt(Hz) or m/s^3/sqrt(Hz).
        pose_sigma: Pose noise per sample, rad (attitude) or m (position).
        pose_rate_hz: Pose samples per second.
        derivative_order: 1 (gyro bias through attitude) or 2 (acc bias through position).

    Returns:
        The RMSE floor in the bias's unit.
    """
    if derivative_order not in (1, 2):
        raise ValueError("derivative_order must be 1 (attitude) or 2 (position)")
    q2, s2 = random_walk**2, noise_density**2
    r = pose_sigma**2 / pose_rate_hz
    m2 = 2 * derivative_order

    def integrand(w: float) -> float:
        sb = q2 / (w * w)
        sn = s2 + r * w**m2
        return sb * sn / (sb + sn)

    # integrate over log(w) around the crossover of S_b with the pose term (the integrand decays
    # as w^-2 above it and is bounded by s2 or r w^2m below it): smooth, no infinite range
    knee = (q2 / r) ** (1.0 / (m2 + 2)) if r > 0 else max(q2 / max(s2, 1e-300), 1e-12) ** 0.5
    u0 = math.log(knee)
    total = quad(lambda u: integrand(math.exp(u)) * math.exp(u), u0 - 30.0, u0 + 30.0, limit=400,
                 points=[u0])[0]
    return math.sqrt(total / math.pi)
