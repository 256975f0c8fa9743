"""IMU resampling onto a uniform grid of another rate, with an anti-alias filter.

:func:`resample_imu_filtered` cuts the recording at its gaps and resamples each gap-free piece
with :func:`scipy.signal.resample_poly` (polyphase filtering by the rational ratio of the two
rates: a Kaiser-windowed FIR low-pass at the lower of the two Nyquist frequencies, zero phase,
``padtype="line"`` so that the ends of a piece with a trend or an offset such as gravity do not
ring). A piece whose stamps jitter is first put onto its own nominal grid by linear interpolation
(within a fraction of a sample, far below the filter's band edge). The output grid of a piece is
``t_first + round(k / rate_hz)`` (ns), the convention of :mod:`training.data.windows`.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
from scipy.signal import resample_poly

from pipeline.errors import DataError
from pipeline.types import NS_PER_S, ImuSeries

#: Largest numerator / denominator of the rational rate ratio (a finer ratio is rounded to one).
MAX_RATIO_TERM = 1000


def _pieces(t_ns: np.ndarray, gap_factor: float) -> list[slice]:
    """Gap-free index ranges (an interval > ``gap_factor`` x the median one is a gap)."""
    dt = np.diff(t_ns)
    cuts = np.nonzero(dt > gap_factor * float(np.median(dt)))[0] + 1
    edges = [0, *cuts.tolist(), len(t_ns)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b - a >= 2]


def _resample_piece(t_ns: np.ndarray, values: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """One gap-free piece: ``(grid_ns [M], values [M, C])`` at ``rate_hz``."""
    n = len(t_ns)
    recorded_hz = (n - 1) * NS_PER_S / float(t_ns[-1] - t_ns[0])
    ratio = Fraction(rate_hz / recorded_hz).limit_denominator(MAX_RATIO_TERM)
    up, down = ratio.numerator, ratio.denominator
    period_in = float(t_ns[-1] - t_ns[0]) / (n - 1)
    nominal = int(t_ns[0]) + np.round(np.arange(n) * period_in).astype(np.int64)
    x = (t_ns - t_ns[0]).astype(float)
    uniform = np.column_stack([np.interp((nominal - t_ns[0]).astype(float), x, values[:, c])
                               for c in range(values.shape[1])])
    out = resample_poly(uniform, up, down, axis=0, padtype="line")
    period_out = NS_PER_S / float(rate_hz)
    m = min(len(out), int(np.floor((t_ns[-1] - t_ns[0]) / period_out + 1e-9)) + 1)
    grid = int(t_ns[0]) + np.round(np.arange(m) * period_out).astype(np.int64)
    return grid, out[:m]


def resample_imu_filtered(imu: ImuSeries, rate_hz: float, *, gap_factor: float = 2.0) -> ImuSeries:
    """The IMU at ``rate_hz`` on a uniform grid per gap-free piece, anti-alias filtered (module docstring).

    Args:
        imu: Recorded IMU, strictly increasing stamps.
        rate_hz: Target rate (Hz), positive.
        gap_factor: An interval longer than this times the median one is a gap (kept as a gap).

    Returns:
        The resampled IMU (temperature resampled alike).

    Raises:
        DataError: Stamps not strictly increasing, a non-positive rate, or no piece of two samples.
    """
    t = np.asarray(imu.t_ns, dtype=np.int64)
    if not rate_hz > 0:
        raise DataError(f"cannot resample to {rate_hz!r} Hz", field="--resample-hz", hint="give a positive rate")
    if len(t) < 2 or np.any(np.diff(t) <= 0):
        raise DataError("cannot resample: the IMU stamps are not strictly increasing",
                        hint="run 'biasgt convert --repair all' first")
    columns = [imu.gyro_radps, imu.acc_mps2] + ([imu.temperature_degc[:, None]]
                                                 if imu.temperature_degc is not None else [])
    values = np.hstack(columns).astype(float)
    grids, outs = [], []
    for piece in _pieces(t, gap_factor):
        grid, out = _resample_piece(t[piece], values[piece], rate_hz)
        grids.append(grid)
        outs.append(out)
    if not grids:
        raise DataError("cannot resample: no two consecutive IMU samples without a gap")
    t_out, v = np.concatenate(grids), np.vstack(outs)
    temp = v[:, 6].copy() if imu.temperature_degc is not None else None
    return ImuSeries(t_out, v[:, :3].copy(), v[:, 3:6].copy(), temp)
