"""The ``start_rest`` reference row: each sequence's bias read from the IMU at rest, held constant.

From the sequence's own IMU record (:mod:`training.data.records`), no pose and no label:

* **gyro**: the mean gyro over the first rest of the record (:func:`training.data.records.detect_rests`);
  the Earth's rotation (7.3e-5 rad/s) is left in it.
* **accelerometer**: at rest the accelerometer reads ``f + b_a`` with ``|f| = g``. With the gravity
  magnitude known, only the bias component along gravity is observable from one static attitude:
  ``b_a . u = |a_rest| - g`` with ``u = a_rest / |a_rest|`` (first order in ``|b_a| / g``). That
  component replaces the train mean's along ``u``; the two horizontal components stay the train
  mean's.
* **fallback**: a window that sees no rest (none in the record before its last sample, or none at
  all) takes the train mean, gyro and accelerometer.

Causal: a window reads the rest only up to its own last sample (:meth:`SequenceContext.rest_mean`),
so windows after the rest all hold the same constant, and one inside it uses the rest so far.
"""

from __future__ import annotations

import numpy as np

from training.data.records import SequenceContext

__all__ = ["start_rest_bias", "start_rest_note", "start_rest_row"]


def start_rest_bias(context: SequenceContext, stop: np.ndarray, bias_mean: np.ndarray,
                    gravity_norm_mps2: float) -> tuple[np.ndarray, np.ndarray]:
    """The start-rest bias [B, 6] (rad/s, m/s^2) of windows ending before sample ``stop`` [B], and
    whether each saw a rest [B] (bool; else the train mean ``bias_mean`` [6])."""
    mean, found, _ = context.rest_mean(stop)
    m = np.asarray(bias_mean, dtype=np.float64)
    out = np.tile(m, (len(found), 1))
    acc = mean[:, 3:]
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    u = acc / np.maximum(norm, 1e-9)
    along = norm[:, 0] - float(gravity_norm_mps2)
    acc_bias = m[3:] + (along - u @ m[3:])[:, None] * u
    out[found, :3] = mean[found, :3]
    out[found, 3:] = acc_bias[found]
    return out, found


def start_rest_row(items: dict, *, context: SequenceContext, bias_mean: np.ndarray,
                   gravity_mps2: np.ndarray) -> np.ndarray:
    """The row's bias [B, 1, T, 6] for windows ``items`` (``imu`` [B, T, 6], ``t0_ns`` [B]) of the
    sequence whose record is ``context`` (:mod:`training.references` gives the inputs)."""
    B, T, _ = np.shape(items["imu"])
    stop = context.index(np.asarray(items["t0_ns"], dtype=np.int64)) + T
    b, _ = start_rest_bias(context, stop, bias_mean, float(np.linalg.norm(gravity_mps2)))
    return np.broadcast_to(b[:, None, None, :], (B, 1, T, 6)).copy()


def start_rest_note(summaries: list) -> str | None:
    """Table I's footnote on the ``start_rest`` row (None when the table does not hold it)."""
    if not any(s.method == "start_rest" for s in summaries):
        return None
    return ("Start-rest bias (a usable row, not in the paper): from the IMU alone, the gyro mean over the "
            "record's first rest and the accelerometer bias along gravity there (the train mean across "
            "gravity, and on every channel before a rest is seen), held for the sequence. It reads the "
            "dataset's sequence records (context/: each whole IMU record once, 56 bytes per IMU sample, 64 "
            "with temperature, whatever the window overlap).")
