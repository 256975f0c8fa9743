"""The clock offset between a pose stream and the IMU over the whole overlap, at offsets of up to minutes.

The recovery's own offset search (:mod:`recovery.calibration_init.time_offset`) looks within
``max_time_offset_s`` (0.5 s) of zero; a mocap PC whose clock runs seconds off the IMU's sends it
astray. :func:`coarse_clock_offset` searches every offset at which the streams still overlap by
:data:`MIN_OVERLAP_FRACTION` of the shorter one (and at most ``max_offset_s``), on a 20-Hz grid:

* 6-DoF streams (``"rotation"``): the Pearson correlation of ``|omega|`` of the gyro and of the pose
  orientations (mean rates over 0.1 s; rotation invariant, so no extrinsic is needed);
* position-only streams (``"position"``): the R^2 per offset of the linear fit
  ``|f|^2 = s^2 |a|^2 - 2 s a.g + |g|^2`` of the accelerometer's ``|f|^2`` on the positions'
  second derivative ``a`` (features ``|a|^2``, ``a``, 1; invariant to the positions' unit ``s``).

The peak is trusted when it is high (:data:`MIN_PEAK`) and stands above the best value more than
:data:`EXCLUSION_S` away from it by :data:`MIN_MARGIN` (a motion that repeats gives several peaks).
Offsets follow the recovery's convention: seconds to ADD to pose stamps to put them on the IMU clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.checks.rig_signals import (
    Grid,
    gyro_rate_norm,
    lags,
    masked_lag_correlation,
    masked_lag_regression,
    parabolic_peak,
    pose_acceleration,
    pose_rate_norm,
    specific_force_sq,
)
from pipeline.types import ImuSeries, PoseSeries

#: Grid step of the coarse search (s).
GRID_DT_S = 0.05
#: ``|omega|`` is the mean rate over this window (s).
RATE_WINDOW_S = 0.1
#: Gaussian smoothing of the accelerations and of ``|f|^2`` (sigma, s).
ACC_SMOOTH_S = 0.1
#: The streams must overlap by at least this share of the shorter one at a searched offset.
MIN_OVERLAP_FRACTION = 0.4
#: ... and by at least this many seconds.
MIN_OVERLAP_S = 10.0
#: The largest offset searched by default (s).
MAX_OFFSET_S = 120.0
#: A peak below this correlation (rotation) or sqrt(R^2) (position) is not trusted.
MIN_PEAK = 0.5
#: The runner-up is the best value further than this from the peak (s).
EXCLUSION_S = 2.0
#: The peak must exceed the runner-up by this much.
MIN_MARGIN = 0.1


@dataclass(frozen=True)
class CoarseOffset:
    """The coarse clock offset of a pose stream.

    Attributes:
        offset_s: Seconds to add to the pose stamps to put them on the IMU clock.
        peak: The correlation (rotation) or sqrt(R^2) (position) at ``offset_s``.
        runner_up: The best value further than :data:`EXCLUSION_S` from the peak (NaN: none searched).
        overlap_s: Seconds the streams overlap at ``offset_s``.
        searched_s: The largest offset searched (each side).
        method: ``"rotation"`` or ``"position"``.
    """

    offset_s: float
    peak: float
    runner_up: float
    overlap_s: float
    searched_s: float
    method: str

    @property
    def trusted(self) -> bool:
        """High and unambiguous (see the module docstring)."""
        margin = self.peak - (self.runner_up if np.isfinite(self.runner_up) else -1.0)
        return bool(self.peak >= MIN_PEAK and margin >= MIN_MARGIN)

    def describe(self) -> str:
        what = "|omega| correlation" if self.method == "rotation" else "|f|^2 fit R"
        return (f"{what} {self.peak:.2f} at {self.offset_s:+.3f} s, next best {self.runner_up:.2f} "
                f"(searched +-{self.searched_s:.0f} s)")


def _search_mask(count: np.ndarray, k: np.ndarray, dt_s: float, n_short: float, max_offset_s: float) -> np.ndarray:
    need = max(MIN_OVERLAP_FRACTION * n_short, MIN_OVERLAP_S / dt_s)
    return (count >= need) & (np.abs(k) * dt_s <= max_offset_s)


def _peak(score: np.ndarray, allowed: np.ndarray, k: np.ndarray, dt_s: float) -> tuple[float, float, float, int] | None:
    """``(offset_s, peak, runner_up, index)`` of the best allowed lag, or None."""
    s = np.where(allowed & np.isfinite(score), score, -np.inf)
    i = int(np.argmax(s))
    if not np.isfinite(s[i]):
        return None
    far = np.abs(k - k[i]) * dt_s > EXCLUSION_S
    runner = float(np.max(s[far])) if far.any() else float("nan")
    return float((k[i] + parabolic_peak(s, i)) * dt_s), float(s[i]), runner if np.isfinite(runner) else float("nan"), i


def coarse_clock_offset(imu: ImuSeries, poses: PoseSeries, *, max_offset_s: float = MAX_OFFSET_S
                        ) -> CoarseOffset | None:
    """The offset that best aligns ``poses`` with ``imu`` over their whole overlap (see the module docstring).

    Args:
        imu: IMU readings (sorted, finite).
        poses: The pose stream (sorted, finite); orientations, when present, select the rotation method.
        max_offset_s: Largest offset searched (each side).

    Returns:
        The estimate (check :attr:`CoarseOffset.trusted`), or None when the streams are too short or
        never overlap enough.
    """
    grid = Grid.spanning([(int(imu.t_ns[0]), int(imu.t_ns[-1])), (int(poses.t_ns[0]), int(poses.t_ns[-1]))],
                         GRID_DT_S)
    if poses.quat_wxyz is not None:
        y, my = gyro_rate_norm(imu, grid, RATE_WINDOW_S)
        x, mx = pose_rate_norm(poses, grid, RATE_WINDOW_S)
        score, count = masked_lag_correlation(x, mx, y, my)
        method = "rotation"
    else:
        a, mx = pose_acceleration(poses, grid, ACC_SMOOTH_S)
        y, my = specific_force_sq(imu, grid, ACC_SMOOTH_S)
        r2, _, count = masked_lag_regression(position_features(a), mx, y, my)
        score = np.sqrt(np.clip(r2, 0.0, 1.0))
        method = "position"
    k = lags(grid.n)
    allowed = _search_mask(count, k, grid.dt_s, min(mx.sum(), my.sum()), max_offset_s)
    found = _peak(score, allowed, k, grid.dt_s)
    if found is None:
        return None
    offset, peak, runner, i = found
    searched = float(min(max_offset_s, np.max(np.abs(k[allowed])) * grid.dt_s))
    return CoarseOffset(offset, peak, runner, float(count[i] * grid.dt_s), searched, method)


def position_features(acc: np.ndarray) -> np.ndarray:
    """The regressors of ``|f|^2`` on the poses' acceleration ``[n, 3]``: ``|a|^2``, ``a``, 1 (``[n, 5]``),
    each ``a`` scaled by its RMS so that the fit is as well conditioned in millimetres as in metres."""
    scale = float(np.sqrt(np.mean(acc**2))) or 1.0
    a = acc / scale
    return np.column_stack([np.sum(a**2, axis=1), a, np.ones(len(a))])
