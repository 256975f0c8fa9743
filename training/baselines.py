"""Reference rows of the evaluation that need no training.

:class:`Baseline` names them (they are not learned :class:`training.config.Method` values):

``zero``
    No bias correction: the raw readings are integrated.
``train_mean``
    The train split's mean bias, held constant (the manifest's ``normalization.bias_mean``).
``ground_truth``
    The recovered ground-truth bias of each window itself: what the labels allow.
``state_bias``
    The dataset's own ground-truth-state bias (EuRoC's ``state_groundtruth_estimate0``): the
    labels of the paper and AirIMU.
``random_walk_oracle``
    The ground-truth bias at each window's first sample, continued by ``K`` random-walk paths
    ``b_k(t_{j+1}) = b_k(t_j) + sigma_rw sqrt(h_j) n_j``, of which the one with the smallest
    end-of-window position error against the ground-truth end pose is kept: an **oracle upper
    bound** (it uses the ground truth twice), as in the paper's Table I. The walks ``sigma_rw``
    [6] are the sensor's calibration or the recovery's (:class:`training.config.OracleWalk`).
``random_walk_paper``
    The same oracle with the walks the paper's random-walk column implies: increments
    ``sigma_rw / sqrt(h_j) n_j`` (the density taken per sample) and the path kept by
    ``3 * position error [m] + rotation error [deg]`` (the released code's checkpoint ranking).
    Kept beside the stated model's row so that Table I can be set beside the paper's.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import InputFormatError
from training.config import Baseline
from validation.metrics import window_end_errors

__all__ = ["Baseline", "ORACLE_CANDIDATES", "PAPER_POSITION_WEIGHT", "baseline_bias", "random_walk_paths"]

#: Random-walk candidates per window of the oracle (the paper's 50).
ORACLE_CANDIDATES = 50


#: The paper's path choice (inferred): metres of end-position error per degree of end-rotation error.
PAPER_POSITION_WEIGHT = 3.0


def random_walk_paths(start_bias: np.ndarray, random_walk: np.ndarray, dt_s: np.ndarray, k: int,
                      rng: np.random.Generator, per_sample: bool = False) -> np.ndarray:
    """``k`` random-walk bias paths per window starting at ``start_bias``.

    Args:
        start_bias: Bias at the first sample, [B, 6].
        random_walk: Random-walk strengths per channel, [B, 6] (unit/sqrt(s)).
        dt_s: Sample intervals, [B, T-1] (s).
        k: Paths per window.
        rng: Source of the increments.
        per_sample: Increments ``random_walk / sqrt(h)`` (the paper's walks, see the module docstring)
            instead of ``random_walk * sqrt(h)``.

    Returns:
        [B, k, T, 6] paths (sample 0 equals ``start_bias``).
    """
    B, n = dt_s.shape
    scale = 1.0 / np.sqrt(dt_s) if per_sample else np.sqrt(dt_s)
    steps = rng.standard_normal((B, k, n, 6)) * (random_walk[:, None, None, :] * scale[:, None, :, None])
    walk = np.concatenate([np.zeros((B, k, 1, 6)), np.cumsum(steps, axis=2)], axis=2)
    return start_bias[:, None, None, :] + walk


def baseline_bias(baseline: Baseline, items: dict, *, bias_mean: np.ndarray, random_walk: np.ndarray,
                  gravity_mps2: np.ndarray, rng: np.random.Generator,
                  candidates: int = ORACLE_CANDIDATES) -> np.ndarray:
    """The bias a reference row subtracts from each window, [B, 1, T, 6] (one prediction).

    Args:
        baseline: Which row.
        items: Collated window items (:class:`training.dataset.WindowDataset`, float64):
            ``imu``, ``bias``, ``dt_s``, ``start_*``, ``end_*``.
        bias_mean: The train split's mean bias, [6].
        random_walk: Random-walk strengths of each window's sequence, [B, 6].
        gravity_mps2: Gravity in the world frame of the windows' sequence, [3].
        rng: Random source of the oracle's paths.
        candidates: Oracle paths per window.

    Raises:
        InputFormatError: The oracle without finite random-walk strengths.
    """
    gt = np.asarray(items["bias"], dtype=np.float64)
    B, T, _ = gt.shape
    state = np.asarray(items["state_bias"], dtype=np.float64) if "state_bias" in items else None
    if baseline is Baseline.ZERO:
        return np.zeros((B, 1, T, 6))
    if baseline is Baseline.TRAIN_MEAN:
        return np.broadcast_to(np.asarray(bias_mean, dtype=np.float64), (B, 1, T, 6)).copy()
    if baseline is Baseline.GROUND_TRUTH:
        return gt[:, None].copy()
    if baseline is Baseline.STATE_BIAS:
        if state is None or not np.all(np.isfinite(state)):
            raise InputFormatError("the test windows have no ground-truth-state bias (state_bias) to evaluate",
                                   hint="evaluate 'state_bias' only on sequences with a ground-truth state "
                                        "(EuRoC's state_groundtruth_estimate0), re-created with 'biasgt windows'")
        return state[:, None].copy()
    rw = np.asarray(random_walk, dtype=np.float64)
    if rw.shape != (B, 6) or not np.all(np.isfinite(rw)):
        raise InputFormatError("the dataset has no bias random walks for the oracle (manifest info."
                               "bias_random_walk or info.sensor_random_walk)",
                               hint="re-create the dataset with this version's 'biasgt windows' from recovery folders")
    dt = np.asarray(items["dt_s"], dtype=np.float64)
    start = gt[:, 0] if state is None or not np.all(np.isfinite(state[:, 0])) else state[:, 0]
    paper = baseline is Baseline.RANDOM_WALK_PAPER
    paths = random_walk_paths(start, rw, dt, candidates, rng, per_sample=paper)  # [B, K, T, 6]
    rep = lambda key: np.repeat(np.asarray(items[key], dtype=np.float64), candidates, axis=0)  # noqa: E731
    pos, rot = window_end_errors(rep("imu"), paths.reshape(B * candidates, T, 6), rep("dt_s"), rep("start_R"),
                                 rep("start_v"), rep("start_p"), rep("end_R"), rep("end_p"),
                                 gravity_mps2=gravity_mps2)
    score = PAPER_POSITION_WEIGHT * pos + rot if paper else pos
    best = score.reshape(B, candidates).argmin(axis=1)
    return paths[np.arange(B), best][:, None]
