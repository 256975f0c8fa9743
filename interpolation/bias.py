"""Bias at IMU rate, with uncertainty, from keyframe estimates.

Model: each bias component b(t) is a random walk with diffusion ``q`` [unit^2/s]
(``q = sigma_rw^2``, the continuous-time random-walk strength the recovery used). Between two
keyframes ``t0 < t < t1`` with estimates ``b0``, ``b1`` and marginal sigmas ``sigma0``, ``sigma1``:

* **Linear (default).** The Brownian bridge between the endpoints: mean
  ``b(t) = (1 - s) b0 + s b1`` with ``s = (t - t0) / (t1 - t0)``, and variance

      sigma(t)^2 = ((1 - s) sigma0 + s sigma1)^2 + q (t - t0)(t1 - t) / (t1 - t0),

  the first term the endpoint uncertainty at correlation 1 (an upper bound: consecutive
  keyframe estimates share almost all their information, and only marginals are stored). It
  equals the keyframe marginal at the keyframes and is continuous.
* **Cubic / Akima.** A smooth curve through the keyframes (``scipy``'s Akima1DInterpolator,
  robust to overshoot); the sigma is the same as for the linear method.

Stamps outside the recovered span are never extrapolated silently: the default refuses; with
``clamp=True`` the nearest keyframe value is held, its sigma grows with the random walk
(``sigma0^2 + q |t - t_end|``) and the rows are counted and flagged in
:class:`pipeline.bias_table.BiasTrack`.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import Akima1DInterpolator

from interpolation.config import InterpolationMethod
from pipeline.bias_table import BiasTrack
from pipeline.errors import DataError
from pipeline.types import NS_PER_S


def interpolate_bias(
    keyframes: BiasTrack,
    t_ns: np.ndarray,
    *,
    random_walk: np.ndarray,
    method: InterpolationMethod = InterpolationMethod.LINEAR,
    clamp: bool = False,
) -> BiasTrack:
    """Bias and its sigma at arbitrary stamps (e.g. every IMU stamp).

    Args:
        keyframes: Keyframe estimates (``bias.csv``).
        t_ns: Query stamps, int64 [M], on the IMU clock.
        random_walk: Continuous-time random-walk strength per component,
            [6] (rad/s^2/sqrt(Hz) x3, m/s^3/sqrt(Hz) x3), as used by the recovery.
        method: Interpolation of the mean.
        clamp: Hold the end values outside the keyframe span (flagged) instead of refusing.

    Returns:
        The bias at ``t_ns`` with ``clamped`` flags.

    Raises:
        DataError: A stamp lies outside the keyframe span and ``clamp`` is False.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    q = np.asarray(random_walk, dtype=np.float64).reshape(6) ** 2  # diffusion, unit^2/s
    k_t = keyframes.t_ns
    outside = (t_ns < k_t[0]) | (t_ns > k_t[-1])
    if np.any(outside) and not clamp:
        n = int(outside.sum())
        raise DataError(
            f"{n} of {len(t_ns)} stamps lie outside the recovered bias span "
            f"[{k_t[0]}, {k_t[-1]}] ns",
            hint="recover over the whole IMU span, crop the IMU, or allow holding the end values (--clamp)",
        )
    # Work in seconds relative to the first keyframe (exact enough: int64 difference first).
    ks = (k_t - k_t[0]) / NS_PER_S
    qs = (np.clip(t_ns, k_t[0], k_t[-1]) - k_t[0]) / NS_PER_S
    if len(k_t) == 1:
        mean = np.repeat(keyframes.bias, len(t_ns), axis=0)
        var = np.repeat(keyframes.std**2, len(t_ns), axis=0)
    else:
        idx = np.clip(np.searchsorted(ks, qs, side="right") - 1, 0, len(ks) - 2)
        t0, t1 = ks[idx], ks[idx + 1]
        span = t1 - t0
        s = ((qs - t0) / span)[:, None]
        sig = (1.0 - s) * keyframes.std[idx] + s * keyframes.std[idx + 1]
        bridge = ((qs - t0) * (t1 - qs) / span)[:, None] * q[None, :]
        var = sig**2 + bridge
        if method is InterpolationMethod.LINEAR or len(k_t) < 3:
            mean = (1.0 - s) * keyframes.bias[idx] + s * keyframes.bias[idx + 1]
        elif method is InterpolationMethod.CUBIC:
            mean = Akima1DInterpolator(ks, keyframes.bias, axis=0)(qs)
        else:  # pragma: no cover - enum exhausted
            raise ValueError(method)
    # Beyond the span: the random walk keeps diffusing from the end value.
    beyond_s = np.abs(t_ns - np.clip(t_ns, k_t[0], k_t[-1])) / NS_PER_S
    var = var + beyond_s[:, None] * q[None, :]
    return BiasTrack(t_ns, np.asarray(mean, dtype=np.float64), np.sqrt(var), outside)
