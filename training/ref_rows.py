"""The reference rows that read a whole sequence, not one window: ``start_rest`` and ``sequence_mean``.

:class:`training.evaluate.ReferencePredictor` hands these two :class:`training.config.Baseline`
rows here; each row's rule is in its own module (:mod:`training.ref_start_rest`,
:mod:`training.ref_sequence_mean`). ``start_rest`` needs the dataset's sequence records
(:func:`training.context.write_context`).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from training.config import Baseline
from training.context import SequenceContext
from training.ref_sequence_mean import sequence_mean_bias
from training.ref_start_rest import start_rest_bias

__all__ = ["open_context", "sequence_reference_bias"]


@functools.lru_cache(maxsize=64)
def open_context(root: str, name: str) -> SequenceContext:
    """The sequence record of ``name`` in the dataset at ``root`` (opened once per process)."""
    return SequenceContext.open(root, name)


def sequence_reference_bias(baseline: Baseline, items: dict[str, Any], sequence: str, windows: Any) -> np.ndarray:
    """The bias [B, 1, T, 6] of ``baseline`` for windows ``items`` (``imu`` [B, T, 6], ``t0_ns`` [B]) of
    ``sequence``; ``windows`` is the evaluation's :class:`training.eval_windows.TestWindows`."""
    B, T, _ = items["imu"].shape
    if baseline is Baseline.SEQUENCE_MEAN:
        entry = windows.manifest["sequences"][sequence]
        b = sequence_mean_bias(Path(windows.root) / entry["path"])
        return np.broadcast_to(b, (B, 1, T, 6)).copy()
    if baseline is not Baseline.START_REST:
        raise ValueError(f"{baseline} is not a sequence-level reference row")
    ctx = open_context(str(Path(windows.root).resolve()), sequence)
    stop = ctx.index(np.asarray(items["t0_ns"], dtype=np.int64)) + T
    g = float(np.linalg.norm(windows.gravity_mps2[sequence]))
    b, _ = start_rest_bias(ctx, stop, windows.bias_mean, g)
    return np.broadcast_to(b[:, None, None, :], (B, 1, T, 6)).copy()
