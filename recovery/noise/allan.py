"""Overlapping Allan deviation of IMU readings, and the noise strengths read off it (the quality
report draws it; the recovery reads the white-noise densities of a recording at rest from it).

For a rate signal ``x`` sampled at ``rate_hz`` (gyro in rad/s, accelerometer in m/s^2) the
integral ``theta_j = sum_{i<j} x_i / rate_hz`` (``theta_0 = 0``) turns the overlapping Allan
variance at cluster time ``tau = m / rate_hz`` into one vectorised second difference::

    avar(tau) = sum_{k=0}^{N-2m} (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2 / (2 tau^2 (N - 2m + 1))

(IEEE Std 952 / 1554; ``N`` samples). Cluster sizes ``m`` are log-spaced from 1 to
``(N - 1) // 2``.

Several segments (e.g. the static stretches of a recording) are pooled: their squared second
differences and counts are summed per ``m`` over every segment long enough for it; each
segment's constant (gravity on the accelerometer, the turn-on bias) drops out of the
differences.

Noise model read off the curve (:func:`fit_noise_parameters`)::

    white noise (density N):      adev = N / sqrt(tau)         slope -1/2, N = line at tau = 1 s
    bias random walk (density K): adev = K * sqrt(tau / 3)     slope +1/2, K = line at tau = 3 s

Units: N in [x]/sqrt(Hz) (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)), K in [x]*sqrt(Hz)/s
(rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz)): the units of ``sensor.yaml``'s ``*_noise_density`` and
``*_random_walk``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.errors import DataError
from pipeline.types import NS_PER_S, ImuSeries
from recovery.calibration_init import RestTest, find_static_segments

#: Default number of log-spaced cluster times (fewer after removing duplicate cluster sizes).
DEFAULT_NUM_TAUS = 60
#: A fixed-slope line is fitted to the points whose local log-log slope is within this of the target.
SLOPE_TOLERANCE = 0.06
#: Points whose cluster time exceeds this fraction of the (longest) segment are not used in fits
#: (too few independent clusters: their scatter is tens of percent).
MAX_TAU_FRACTION = 0.1


def _as_2d(x: np.ndarray) -> tuple[np.ndarray, bool]:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 1:
        return arr[:, None], True
    if arr.ndim != 2:
        raise DataError(f"allan_deviation expects an array of shape [N] or [N, k], got {arr.shape}")
    return arr, False


def _cluster_sizes(n_max: int, taus: np.ndarray | None, rate_hz: float, num: int) -> np.ndarray:
    """Unique integer cluster sizes in ``[1, n_max]`` (log-spaced, or the nearest to ``taus``)."""
    if n_max < 1:
        return np.zeros(0, dtype=np.int64)
    if taus is None:
        m = np.unique(np.round(np.logspace(0.0, math.log10(n_max), num=num)).astype(np.int64))
    else:
        m = np.unique(np.round(np.asarray(taus, dtype=float) * rate_hz).astype(np.int64))
    return m[(m >= 1) & (m <= n_max)]


def allan_deviation(
    x: np.ndarray,
    rate_hz: float,
    taus: np.ndarray | None = None,
    *,
    segments: list[tuple[int, int]] | None = None,
    num_taus: int = DEFAULT_NUM_TAUS,
) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation.

    Args:
        x: Rate samples, [N] or [N, k] (one column per axis), uniformly spaced.
        rate_hz: Sample rate.
        taus: Cluster times in seconds; rounded to whole samples, duplicates and those longer
            than half the (longest) segment dropped. Default: ``num_taus`` log-spaced values.
        segments: Index ranges ``[(i0, i1), ...]`` (half-open) of ``x`` to pool, e.g. the
            static stretches; default the whole array.
        num_taus: Number of default cluster times (before removing duplicates).

    Returns:
        ``(taus, adev)``: cluster times [M] (s) and Allan deviation [M] (or [M, k] for a 2-D
        ``x``), in the units of ``x``.

    Raises:
        DataError: Bad shape, non-positive rate, non-finite samples, or fewer than 3 samples.
    """
    arr, was_1d = _as_2d(x)
    if not rate_hz > 0:
        raise DataError(f"allan_deviation needs a positive rate, got {rate_hz}")
    if segments is None:
        segments = [(0, len(arr))]
    segs = [(max(0, int(a)), min(len(arr), int(b))) for a, b in segments]
    segs = [(a, b) for a, b in segs if b - a >= 3]
    if not segs:
        raise DataError("allan_deviation needs at least 3 samples in one segment")
    longest = max(b - a for a, b in segs)
    m_all = _cluster_sizes((longest - 1) // 2, taus, rate_hz, num_taus)
    k = arr.shape[1]
    sq = np.zeros((len(m_all), k))
    count = np.zeros(len(m_all))
    for a, b in segs:
        seg = arr[a:b]
        if not np.all(np.isfinite(seg)):
            raise DataError("allan_deviation: the samples contain NaN or inf")
        # Integrate relative to the segment mean: a large constant (gravity) would otherwise cost
        # float64 precision in the second differences.
        theta = np.concatenate([np.zeros((1, k)), np.cumsum(seg - seg.mean(axis=0), axis=0)])
        n = len(seg)
        for j, m in enumerate(m_all):
            if 2 * m > n - 1:
                break
            d = theta[2 * m:] - 2.0 * theta[m:-m] + theta[: len(theta) - 2 * m]
            sq[j] += np.einsum("ij,ij->j", d, d)
            count[j] += len(d)
    ok = count > 0
    m_all, sq, count = m_all[ok], sq[ok], count[ok]
    tau = m_all / rate_hz
    # theta holds sums of samples; dividing by rate gives the integral: (d / rate)^2 / (2 tau^2)
    avar = sq / (2.0 * (tau[:, None] * rate_hz) ** 2 * count[:, None])
    adev = np.sqrt(avar)
    return tau, (adev[:, 0] if was_1d else adev)


def _local_slopes(taus: np.ndarray, adev: np.ndarray) -> np.ndarray:
    lt, la = np.log10(taus), np.log10(np.maximum(adev, 1e-300))
    if len(lt) < 3:
        return np.gradient(la, lt) if len(lt) == 2 else np.zeros_like(lt)
    return np.gradient(la, lt)


def _fixed_slope_intercept(taus: np.ndarray, adev: np.ndarray, slope: float, use: np.ndarray) -> float:
    """log10 intercept of the line ``log adev = slope * log tau + b`` fitted to ``use``.

    Weighted least squares: the variance of an Allan-deviation estimate grows with the cluster
    time (it is inversely proportional to the number of independent clusters, ~T / tau), so
    each point is weighted by ``1 / tau``.
    """
    w = 1.0 / taus[use]
    return float(np.sum(w * (np.log10(adev[use]) - slope * np.log10(taus[use]))) / np.sum(w))


def _relative_std(taus: np.ndarray, duration_s: float) -> np.ndarray:
    """Approximate relative std of an Allan-deviation estimate: ``1 / sqrt(2 (T / tau - 1))``."""
    clusters = np.maximum(duration_s / taus - 1.0, 1.0)
    return 1.0 / np.sqrt(2.0 * clusters)


def white_noise_upper_bound(taus: np.ndarray, adev: np.ndarray, *, max_tau_s: float | None = None) -> float:
    """Tightest upper bound of the white-noise density: ``min over tau of adev * sqrt(tau)``.

    Any other noise or motion only adds Allan variance (``avar >= N^2 / tau`` at every tau), so
    this holds for a recording in motion, where no slope -1/2 region can be trusted.

    Args:
        taus: Cluster times [M] (s).
        adev: Allan deviation [M].
        max_tau_s: Ignore longer cluster times (their estimates scatter).
    """
    taus = np.asarray(taus, dtype=float)
    adev = np.asarray(adev, dtype=float)
    ok = np.isfinite(adev) & (adev > 0) & (taus > 0)
    if max_tau_s is not None and (ok & (taus <= max_tau_s)).any():
        ok &= taus <= max_tau_s
    return float(np.min(adev[ok] * np.sqrt(taus[ok]))) if ok.any() else float("nan")


def fit_noise_parameters(
    taus: np.ndarray,
    adev: np.ndarray,
    *,
    max_tau_s: float | None = None,
    duration_s: float | None = None,
) -> tuple[float, float]:
    """White-noise density and bias random walk from one Allan deviation curve.

    White noise (``adev = N / sqrt(tau)``): a slope -1/2 line through the first run of points
    whose local log-log slope is within :data:`SLOPE_TOLERANCE` of -1/2 (least squares with the
    slope fixed, weights ``1 / tau``), read at ``tau = 1 s``. Every point bounds ``N`` from
    above (``N <= adev sqrt(tau)``, other noises only add variance); when no point qualifies
    (motion or another noise dominates everywhere) that tightest upper bound is returned.

    Bias random walk (``adev = K sqrt(tau / 3)``): with the white part removed, every point
    gives ``K^2 = 3 (adev^2 - N^2 / tau) / tau``; these are averaged by weighted least squares
    (each weighted by the inverse of its variance, from the number of independent clusters)
    over ``tau <= max_tau_s``, and ``K`` is the +1/2 line's value at ``tau = 3 s``. When the
    excess over the white line is not significant (below 5 of its standard errors: a short,
    quiet or white-noise-only record) the random walk is not visible and NaN is returned.
    Flat (bias-instability) parts of a real sensor's curve inflate ``K`` somewhat: read it as
    an upper bound there.

    Args:
        taus: Cluster times [M] (s), increasing.
        adev: Allan deviation [M] (one axis).
        max_tau_s: Longest cluster time used (default: ``MAX_TAU_FRACTION`` of ``duration_s``).
        duration_s: Length of the (longest) record; default ``2 * taus[-1]`` (the default
            cluster times reach half the record).

    Returns:
        ``(white_density, random_walk)`` in the units described in the module docstring.
    """
    taus = np.asarray(taus, dtype=float)
    adev = np.asarray(adev, dtype=float)
    if adev.ndim != 1 or len(adev) != len(taus):
        raise DataError(f"fit_noise_parameters expects taus [M] and adev [M], got {taus.shape} and {adev.shape}")
    good = np.isfinite(adev) & (adev > 0) & np.isfinite(taus) & (taus > 0)
    taus, adev = taus[good], adev[good]
    if len(taus) < 2:
        return float("nan"), float("nan")
    duration = float(duration_s) if duration_s else 2.0 * float(taus[-1])
    limit = taus <= (max_tau_s if max_tau_s is not None else MAX_TAU_FRACTION * duration)
    if limit.sum() < 2:
        limit[:2] = True
    taus, adev = taus[limit], adev[limit]
    slopes = _local_slopes(taus, adev)
    # white noise: the first run of points with slope ~ -1/2 (white noise rules the short cluster times);
    # without one, the tightest upper bound (other noises only add variance)
    bound = float(np.min(adev * np.sqrt(taus)))
    ok = np.abs(slopes + 0.5) <= SLOPE_TOLERANCE
    if ok.any():
        i0 = int(np.argmax(ok))
        i1 = i0 + (int(np.argmin(ok[i0:])) if not ok[i0:].all() else len(ok) - i0)
        use = np.zeros(len(taus), bool)
        use[i0:i1] = True
        white = 10.0 ** _fixed_slope_intercept(taus, adev, -0.5, use)
    else:
        white = bound
    # random walk: weighted least squares of K^2 over all points, white part removed
    avar = adev**2
    k2 = 3.0 * (avar - white**2 / taus) / taus
    k2_std = 3.0 * 2.0 * _relative_std(taus, duration) * avar / taus  # d(avar) = 2 avar d(adev)/adev
    w = 1.0 / k2_std**2
    k2_mean = float(np.sum(w * k2) / np.sum(w))
    k2_err = float(1.0 / np.sqrt(np.sum(w)))
    if not k2_mean > 5.0 * k2_err:
        return float(white), float("nan")
    return float(white), float(math.sqrt(k2_mean))


# ----------------------------------------------------------------------------- static detection


@dataclass
class ImuAllan:
    """Allan deviation of an IMU and the fitted noise strengths.

    Attributes:
        taus: Cluster times [M] (s).
        adev_gyro: Gyro Allan deviation [M, 3] (rad/s).
        adev_acc: Accelerometer Allan deviation [M, 3] (m/s^2).
        gyro_white / gyro_rw: Fitted per axis, [3] (NaN where not visible). Without rest
            (``static`` False) the white values are upper bounds and the random walks NaN.
        acc_white / acc_rw: Fitted per axis, [3].
        static: True when computed on static segments only.
        segments_s: The segments used, ``[(t0_s, t1_s)]`` from the first IMU stamp.
        used_s: Total seconds of data used.
        rate_hz: The IMU rate assumed.
        notes: Plain-words remarks (why the whole recording was used, ...).
    """

    taus: np.ndarray
    adev_gyro: np.ndarray
    adev_acc: np.ndarray
    gyro_white: np.ndarray
    gyro_rw: np.ndarray
    acc_white: np.ndarray
    acc_rw: np.ndarray
    static: bool
    segments_s: list[tuple[float, float]]
    used_s: float
    rate_hz: float
    notes: list[str] = field(default_factory=list)


def _find_static_segments(imu: ImuSeries, min_duration_s: float) -> list[tuple[int, int]]:
    """Static intervals ``[(t0_ns, t1_ns)]`` from the recovery's detector, judged by each sensor's
    variation (:attr:`RestTest.VARIATION`): a constant rate, the bias above all, does not move an
    Allan deviation, so a unit's turn-on bias must not hide its rest."""
    return find_static_segments(imu, min_duration_s=min_duration_s, test=RestTest.VARIATION)


def imu_allan(
    imu: ImuSeries,
    *,
    min_static_s: float = 5.0,
    min_total_static_s: float = 20.0,
    num_taus: int = DEFAULT_NUM_TAUS,
) -> ImuAllan:
    """Allan deviation of ``imu`` on its static segments, else on the whole recording.

    On static segments the noise is fitted (:func:`fit_noise_parameters`); on a recording in
    motion only :func:`white_noise_upper_bound` is given and the random walk is NaN.

    Static segments come from :func:`recovery.calibration_init.find_static_segments`
    (``min_duration_s = min_static_s``, judged by each sensor's variation about its window mean); they are used when together they last at least
    ``min_total_static_s``. Stamps are assumed uniform at the IMU's nominal rate (a small
    jitter does not matter for the Allan deviation; a gap inside a segment splits it).

    Args:
        imu: The IMU readings (increasing stamps).
        min_static_s: Shortest static stretch used.
        min_total_static_s: Least total static time for a static-only analysis.
        num_taus: Number of log-spaced cluster times.

    Returns:
        The curves, the fits and what was used.
    """
    rate = float(imu.rate_hz)
    if not (len(imu) >= 10 and math.isfinite(rate) and rate > 0):
        raise DataError("the IMU has too few samples for an Allan deviation")
    t = imu.t_ns
    notes: list[str] = []
    static_ns: list[tuple[int, int]] = []
    try:
        static_ns = _find_static_segments(imu, min_static_s)
    except Exception as exc:  # noqa: BLE001 - the detector's own input errors: fall back to everything
        notes.append(f"the static-segment detector failed ({exc}); the whole recording was used")
    total_static = sum((b - a) / NS_PER_S for a, b in static_ns)
    static = bool(static_ns) and total_static >= min_total_static_s
    if static:
        bounds = [(int(np.searchsorted(t, a, "left")), int(np.searchsorted(t, b, "right"))) for a, b in static_ns]
    else:
        if static_ns:
            notes.append(f"the recording has only {total_static:.1f} s at rest (fewer than {min_total_static_s:g} s)")
        else:
            notes.append(f"the recording has no stretch at rest of {min_static_s:g} s or more")
        bounds = [(0, len(t))]
    # split at gaps (> 2 nominal steps)
    gap = np.flatnonzero(np.diff(t) > 2.0 * NS_PER_S / rate) + 1
    pieces: list[tuple[int, int]] = []
    for a, b in bounds:
        cuts = [a, *[int(g) for g in gap if a < g < b], b]
        pieces += [(c0, c1) for c0, c1 in zip(cuts[:-1], cuts[1:]) if c1 - c0 >= 3]
    longest_s = max((b - a) for a, b in pieces) / rate
    taus, adev_g = allan_deviation(imu.gyro_radps, rate, segments=pieces, num_taus=num_taus)
    _, adev_a = allan_deviation(imu.acc_mps2, rate, segments=pieces, num_taus=num_taus)
    if static:
        fits_g = [fit_noise_parameters(taus, adev_g[:, i], duration_s=longest_s) for i in range(3)]
        fits_a = [fit_noise_parameters(taus, adev_a[:, i], duration_s=longest_s) for i in range(3)]
    else:  # motion: only an upper bound of the white noise; the random walk is not separable
        max_tau = MAX_TAU_FRACTION * longest_s
        fits_g = [(white_noise_upper_bound(taus, adev_g[:, i], max_tau_s=max_tau), math.nan) for i in range(3)]
        fits_a = [(white_noise_upper_bound(taus, adev_a[:, i], max_tau_s=max_tau), math.nan) for i in range(3)]
    t0 = int(t[0])
    return ImuAllan(
        taus=taus, adev_gyro=adev_g, adev_acc=adev_a,
        gyro_white=np.array([f[0] for f in fits_g]), gyro_rw=np.array([f[1] for f in fits_g]),
        acc_white=np.array([f[0] for f in fits_a]), acc_rw=np.array([f[1] for f in fits_a]),
        static=static,
        segments_s=[((int(t[a]) - t0) / NS_PER_S, (int(t[b - 1]) - t0) / NS_PER_S) for a, b in pieces],
        used_s=float(sum(b - a for a, b in pieces) / rate), rate_hz=rate, notes=notes,
    )
