"""Keyframes inside pose gaps: IMU-only states that keep every preintegrated interval short.

A pose stream that pauses (a dropout, a block the cross-validation holds out) would otherwise leave
one IMU factor across the whole pause. GTSAM corrects a preintegrated interval for a change of its
bias to first order only; over seconds the second-order terms (a rotation error times gravity times
``t^2``) dominate, and Levenberg-Marquardt stops far from the optimum. Keyframes without pose
factors every ``GAP_KEYFRAME_PERIOD_S`` inside such a pause keep each interval short. Their initial
states come from integrating the IMU across the pause (:func:`bridge_gaps`), corrected so that they
meet the state after it.

Notation: ``a`` and ``b`` are the measured keyframes before and after a pause of length ``T``;
``s = t - t_a``; ``e_p``, ``e_v`` and ``e_R`` the mismatch at ``b`` between the measured state and
the one integrated from ``a``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gtsam
import numpy as np

from pipeline.types import NS_PER_S

__all__ = ["GAP_KEYFRAME_PERIOD_S", "GAP_MIN_S", "bridge_gaps", "gap_keyframe_stamps"]

#: A pause between measured keyframes longer than this (and than 3 of the stream's keyframe periods)
#: gets keyframes without pose factors.
GAP_MIN_S = 0.3
#: Their spacing (or the stream's own keyframe period where that is longer): short enough for the
#: first-order bias correction (a 10 mrad/s gyro-bias change turns an interval by 5 mrad: its
#: second-order position term is ~2e-5 m), long enough to keep the chain well conditioned (much
#: shorter, the time-ordered Bayes tree's marginals can lose definiteness along a 10-s pause).
GAP_KEYFRAME_PERIOD_S = 0.5


def gap_keyframe_stamps(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keyframe stamps with pauses filled: ``(t_ns [K'], measured [K'])``.

    Args:
        t_ns: Measured keyframe stamps, int64 [K], strictly increasing.

    Returns:
        All stamps in order (int64) and whether each is a measured one (bool); the added stamps
        are evenly spaced inside each pause, at most ``max(GAP_KEYFRAME_PERIOD_S, median spacing)``
        apart.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    if len(t_ns) < 3:
        return t_ns.copy(), np.ones(len(t_ns), dtype=bool)
    dt = np.diff(t_ns)
    median = float(np.median(dt))
    period_ns = max(GAP_KEYFRAME_PERIOD_S * NS_PER_S, median)
    gaps = np.nonzero(dt > max(GAP_MIN_S * NS_PER_S, 3.0 * median))[0]
    if not len(gaps):
        return t_ns.copy(), np.ones(len(t_ns), dtype=bool)
    added = []
    for g in gaps:
        n = int(np.ceil(dt[g] / period_ns)) - 1
        added.append(t_ns[g] + np.round(np.arange(1, n + 1) * (dt[g] / (n + 1))).astype(np.int64))
    extra = np.concatenate(added)
    out = np.concatenate([t_ns, extra])
    measured = np.concatenate([np.ones(len(t_ns), dtype=bool), np.zeros(len(extra), dtype=bool)])
    order = np.argsort(out, kind="stable")
    return out[order], measured[order]


def _runs(measured: np.ndarray) -> list[tuple[int, int]]:
    """``(a, b)``: the measured keyframes around each run of unmeasured ones (``a < k < b``)."""
    idx = np.nonzero(measured)[0]
    return [(int(a), int(b)) for a, b in zip(idx[:-1], idx[1:]) if b - a > 1]


def bridge_gaps(pims: Sequence[Any], Xs: list[gtsam.Pose3], vel: np.ndarray, t_ns: np.ndarray,
                measured: np.ndarray) -> tuple[list[gtsam.Pose3], np.ndarray]:
    """Initial IMU poses and velocities of the unmeasured keyframes, from the IMU across each pause.

    Args:
        pims: Preintegrated intervals, ``pims[k]`` from keyframe ``k`` to ``k + 1`` [K - 1].
        Xs: IMU poses [K] (those of measured keyframes are kept).
        vel: IMU velocities [K, 3] (those of measured keyframes are kept).
        t_ns: Keyframe stamps, int64 [K].
        measured: Whether each keyframe has a pose measurement, bool [K].

    Returns:
        ``(Xs, vel)`` with the unmeasured keyframes replaced.

    Each pause from ``a`` to ``b``:
        1. integrate forward from ``(X_a, v_a)`` with each interval's own bias: ``X~(t), v~(t)``;
        2. ``e_p = p_b - p~_b``, ``e_v = v_b - v~_b``, ``e_R = Log(R~_b^T R_b)``;
        3. a constant world acceleration ``d_a = 2 (e_v T - e_p) / T^2`` and velocity change
           ``d_v = e_v - d_a T`` close the mismatch of ``p`` and ``v`` at ``b`` (a gravity or
           acceleration-bias error is such a constant to first order);
        4. ``p = p~ + d_v s + d_a s^2 / 2``, ``v = v~ + d_v + d_a s``, ``R = R~ Exp((s / T) e_R)``.
    """
    Xs, vel = list(Xs), np.array(vel, dtype=float)
    for a, b in _runs(np.asarray(measured, dtype=bool)):
        state = gtsam.NavState(Xs[a], vel[a])
        fwd = []
        for k in range(a, b):
            state = pims[k].predict(state, pims[k].biasHat())
            fwd.append(state)
        T = (t_ns[b] - t_ns[a]) / NS_PER_S
        e_p = Xs[b].translation() - fwd[-1].position()
        e_v = vel[b] - fwd[-1].velocity()
        e_R = gtsam.Rot3.Logmap(fwd[-1].attitude().between(Xs[b].rotation()))
        d_a = 2.0 * (e_v * T - e_p) / T**2
        d_v = e_v - d_a * T
        for k in range(a + 1, b):
            s = (t_ns[k] - t_ns[a]) / NS_PER_S
            nav = fwd[k - a - 1]
            R = nav.attitude().compose(gtsam.Rot3.Expmap(e_R * (s / T)))
            Xs[k] = gtsam.Pose3(R, nav.position() + d_v * s + 0.5 * d_a * s**2)
            vel[k] = nav.velocity() + d_v + d_a * s
    return Xs, vel
