"""Bias at IMU rate, with uncertainty, from keyframe estimates.

Model: each bias component b(t) is a random walk (Brownian motion) with
diffusion ``q`` [unit^2/s] (``q = sigma_rw^2``, sigma_rw the continuous-time
random-walk strength used by the recovery). Between two keyframes
``t0 < t < t1`` with estimates ``b0``, ``b1`` and marginal variances
``P0``, ``P1``:

* **Linear (default).** Given the endpoint values, the random walk between them
  is a Brownian bridge whose mean is the straight line

      b(t) = (1 - s) b0 + s b1,              s = (t - t0) / (t1 - t0)

  and whose variance is the bridge variance ``q (t - t0)(t1 - t) / (t1 - t0)``.
  The endpoint uncertainty adds ``Var[(1 - s) b0 + s b1]``; consecutive
  keyframe estimates are strongly correlated (they share almost all their
  information), and only marginals are stored, so we use the upper bound for
  correlation 1: ``((1 - s) sigma0 + s sigma1)^2``. Total:

      sigma(t)^2 = ((1 - s) sigma0 + s sigma1)^2 + q (t - t0)(t1 - t) / (t1 - t0)

  It equals the keyframe marginal at the keyframes and is continuous.

* **Cubic / Akima.** A smooth curve through the keyframes (``scipy``'s
  Akima1DInterpolator, robust to overshoot) for users who want C1 bias; the
  sigma is the same as for the linear method.

Stamps outside the recovered span are never extrapolated silently: the default
refuses; with ``clamp=True`` the nearest keyframe value is held, its sigma grows
with the random walk (``sigma0^2 + q |t - t_end|``) and the rows are counted and
flagged in :class:`InterpolatedBias`.
"""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.atomic import atomic_path
from pipeline.errors import DataError, InputFormatError
from pipeline.types import NS_PER_S

BIAS_COLUMNS = ("bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z")
STD_COLUMNS = tuple(f"{c}_std" for c in BIAS_COLUMNS)
CSV_HEADER = ("t_ns",) + BIAS_COLUMNS + STD_COLUMNS


class InterpolationMethod(str, enum.Enum):
    """How bias is interpolated between keyframes."""

    LINEAR = "linear"  # Brownian-bridge mean (default)
    CUBIC = "cubic"  # Akima spline through the keyframes


@dataclass(frozen=True)
class BiasTrack:
    """Bias samples with marginal standard deviations.

    Attributes:
        t_ns: Stamps on the IMU clock, int64 [N], strictly increasing.
        bias: ``[bg_x, bg_y, bg_z, ba_x, ba_y, ba_z]`` in rad/s and m/s^2, [N, 6].
        std: Marginal standard deviations, [N, 6].
        clamped: True where the value was held beyond the recovered span, [N].
    """

    t_ns: np.ndarray
    bias: np.ndarray
    std: np.ndarray
    clamped: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def bias_gyro_radps(self) -> np.ndarray:
        return self.bias[:, :3]

    @property
    def bias_acc_mps2(self) -> np.ndarray:
        return self.bias[:, 3:]

    def to_frame(self) -> pd.DataFrame:
        frame = pd.DataFrame({"t_ns": np.asarray(self.t_ns, dtype=np.int64)})
        for i, c in enumerate(BIAS_COLUMNS):
            frame[c] = self.bias[:, i]
        for i, c in enumerate(STD_COLUMNS):
            frame[c] = self.std[:, i]
        return frame


def read_bias_csv(path: str | Path, *, require_std: bool = True) -> BiasTrack:
    """Read a ``bias.csv`` (the recovery contract) or an interpolated bias CSV/Parquet.

    Args:
        path: The table.
        require_std: Whether the six ``*_std`` columns must be there. A bias to compare against
            (a constant, another tool's estimate) may have none: its sigma is then 0.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFormatError("bias file does not exist", path=path,
                               hint="run 'biasgt recover' first or give the right path")
    try:
        frame = pq.read_table(path).to_pandas() if path.suffix == ".parquet" else pd.read_csv(
            path, dtype={"t_ns": np.int64})
    except (ValueError, OSError, pa.ArrowInvalid) as exc:
        raise InputFormatError(f"cannot parse bias table ({exc})", path=path,
                               hint=f"the header must be {','.join(CSV_HEADER)}") from exc
    missing = [c for c in CSV_HEADER if c not in frame.columns]
    if not require_std and missing == list(STD_COLUMNS):
        frame[list(STD_COLUMNS)] = 0.0
        missing = []
    if missing:
        raise InputFormatError("missing columns " + ", ".join(missing), path=path,
                               hint=f"the header must be {','.join(CSV_HEADER)}")
    t_ns = frame["t_ns"].to_numpy(dtype=np.int64)
    if len(t_ns) == 0:
        raise DataError("bias table is empty", path=path, hint="re-run the recovery")
    if np.any(np.diff(t_ns) <= 0):
        bad = int(np.argmax(np.diff(t_ns) <= 0)) + 3  # header is line 1
        raise DataError("bias stamps are not strictly increasing", path=path, line=bad,
                        hint="sort the rows by t_ns and drop duplicates")
    bias = frame[list(BIAS_COLUMNS)].to_numpy(dtype=np.float64)
    std = frame[list(STD_COLUMNS)].to_numpy(dtype=np.float64)
    if not (np.all(np.isfinite(bias)) and np.all(np.isfinite(std))):
        raise DataError("bias table holds NaN or inf values", path=path, hint="re-run the recovery")
    return BiasTrack(t_ns, bias, std)


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
            from scipy.interpolate import Akima1DInterpolator

            mean = Akima1DInterpolator(ks, keyframes.bias, axis=0)(qs)
        else:  # pragma: no cover - enum exhausted
            raise ValueError(method)
    # Beyond the span: the random walk keeps diffusing from the end value.
    beyond_s = np.abs(t_ns - np.clip(t_ns, k_t[0], k_t[-1])) / NS_PER_S
    var = var + beyond_s[:, None] * q[None, :]
    return BiasTrack(t_ns, np.asarray(mean, dtype=np.float64), np.sqrt(var), outside)


def write_bias_table(track: BiasTrack, path: str | Path, *, metadata: dict | None = None) -> Path:
    """Write a bias track as CSV (``.csv``) or Parquet (``.parquet``), atomically.

    The columns are those of ``bias.csv``: ``t_ns,bg_x,...,ba_z_std``. For Parquet
    the ``metadata`` dict (and the clamped count) is stored in the schema metadata.
    """
    path = Path(path)
    frame = track.to_frame()
    with atomic_path(path) as tmp:
        if path.suffix == ".parquet":
            table = pa.Table.from_pandas(frame, preserve_index=False)
            meta = dict(metadata or {})
            if track.clamped is not None:
                meta["clamped_rows"] = int(np.sum(track.clamped))
            table = table.replace_schema_metadata({b"biasgt": json.dumps(meta).encode()})
            pq.write_table(table, tmp)
        else:
            frame.to_csv(tmp, index=False, float_format="%.10g")
    return path
