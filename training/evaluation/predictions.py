"""Every evaluated window's predicted bias, kept so that Table I can be re-derived from a run's files.

``predictions.parquet`` (written by :func:`training.evaluation.outputs.write_evaluation` beside
``summary.json``) holds one row per sampler, test window and time step:

* ``sampler`` ("" for a deterministic predictor), ``window`` (position among the evaluation's
  non-overlapping test windows, as in ``windows.parquet``), ``sequence``, ``t0_ns`` (the
  window's first stamp), ``t_index`` (sample within the window, from 0);
* per channel ``c`` of :data:`CHANNELS` (rad/s, m/s^2), float32:
  ``mean_c``, the per-time-step mean of the K samples (the prediction itself when K = 1); with
  K > 1 also ``std_c`` (over the samples, ddof 0), ``median_c`` (numpy's median, the MEDIAN
  aggregation's prediction) and ``q{level}_c`` for :data:`PREDICTION_QUANTILES`.

So the MEAN and MEDIAN rows of a diffusion model and the row of every deterministic predictor
are recomputed from this file alone (to float32 rounding of the bias); the per-sample rows
need the samples themselves, whose errors ``windows.parquet`` keeps.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["CHANNELS", "PREDICTIONS_PARQUET", "PREDICTION_QUANTILES", "prediction_frame", "prediction_array"]

PREDICTIONS_PARQUET = "predictions.parquet"
#: Quantiles of the K samples kept per time step and channel (besides mean, std and median).
PREDICTION_QUANTILES = (0.025, 0.16, 0.84, 0.975)
#: Bias channels, in the order of the arrays' last axis.
CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")


def _stats(pred: np.ndarray) -> dict[str, np.ndarray]:
    """Statistic name -> [B, T, 6] over the samples of ``pred`` [B, K, T, 6]."""
    out = {"mean": pred.mean(axis=1)}
    if pred.shape[1] > 1:
        out["std"] = pred.std(axis=1)
        out["median"] = np.median(pred, axis=1)
        for level, q in zip(PREDICTION_QUANTILES, np.quantile(pred, PREDICTION_QUANTILES, axis=1)):
            out[f"q{level:g}"] = q
    return out


def prediction_frame(pred: np.ndarray, window: np.ndarray, sequence: np.ndarray, t0_ns: np.ndarray,
                     sampler: str) -> pd.DataFrame:
    """Rows of ``predictions.parquet`` for a batch of windows.

    Args:
        pred: Predicted bias [B, K, T, 6] (rad/s, m/s^2).
        window: Window positions [B].
        sequence: Sequence name of each window [B].
        t0_ns: First stamp of each window [B].
        sampler: Sampler name, "" for a deterministic predictor.
    """
    B, _, T, C = pred.shape
    frame: dict[str, object] = {
        "sampler": sampler, "window": np.repeat(np.asarray(window, dtype=np.int64), T),
        "sequence": np.repeat(np.asarray(sequence).astype(str), T),
        "t0_ns": np.repeat(np.asarray(t0_ns, dtype=np.int64), T), "t_index": np.tile(np.arange(T, dtype=np.int32), B),
    }
    for name, values in _stats(pred).items():
        flat = values.reshape(B * T, C).astype(np.float32)
        for c, channel in enumerate(CHANNELS):
            frame[f"{name}_{channel}"] = flat[:, c]
    return pd.DataFrame(frame)


def prediction_array(frame: pd.DataFrame, stat: str = "mean", sampler: str = "") -> tuple[np.ndarray, np.ndarray]:
    """One statistic of one sampler back as an array.

    Args:
        frame: ``predictions.parquet`` read with pandas.
        stat: ``mean``, ``std``, ``median`` or ``q{level}``.
        sampler: Sampler name ("" for a deterministic predictor).

    Returns:
        ``(window [W], values [W, T, 6])``, windows in ascending order (float64 values).

    Raises:
        KeyError: No such sampler or statistic in ``frame``.
    """
    sub = frame[frame["sampler"] == sampler].sort_values(["window", "t_index"])
    if sub.empty:
        raise KeyError(f"no predictions of sampler '{sampler}'")
    windows = sub["window"].unique()
    values = sub[[f"{stat}_{c}" for c in CHANNELS]].to_numpy(dtype=np.float64)
    return windows, values.reshape(len(windows), -1, len(CHANNELS))
