"""The ``sequence_mean`` oracle row: each test sequence's own mean bias, held constant.

The mean over every sample of the sequence's windows (overlapping windows count each shared
sample twice, which weighs the record almost uniformly) of its **dataset bias**: the ground-truth
state's own bias (the dataset's ``STATE_BIAS`` array, EuRoC's ``state_groundtruth_estimate0``)
where the sequence has one, else the labels (``bias``). An oracle: it reads the test sequence's ground truth, so it bounds
what any constant per sequence can do; it is not a method.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from training.data.dataset import STATE_BIAS

__all__ = ["sequence_mean_bias", "sequence_mean_note", "sequence_mean_row"]


def sequence_mean_bias(sequence_folder: str | Path) -> np.ndarray:
    """The mean dataset bias [6] (rad/s, m/s^2) of one sequence's windows folder (``sequences/<name>``)."""
    folder = Path(sequence_folder)
    state = folder / f"{STATE_BIAS}.npy"
    if state.is_file():
        b = np.load(state, mmap_mode="r").reshape(-1, 6)
        ok = np.all(np.isfinite(b), axis=1)
        if ok.any():
            return np.asarray(b[ok], dtype=np.float64).mean(axis=0)
    return np.asarray(np.load(folder / "bias.npy", mmap_mode="r"), dtype=np.float64).reshape(-1, 6).mean(axis=0)


def sequence_mean_row(items: dict, *, sequence_dir: Path) -> np.ndarray:
    """The row's bias [B, 1, T, 6] for windows ``items`` of the sequence in ``sequence_dir``
    (:mod:`training.references` gives the inputs)."""
    B, T, _ = np.shape(items["imu"])
    return np.broadcast_to(sequence_mean_bias(sequence_dir), (B, 1, T, 6)).copy()


def sequence_mean_note(summaries: list) -> str | None:
    """Table I's footnote on the ``sequence_mean`` oracle (None when the table does not hold it)."""
    if not any(s.method == "sequence_mean" for s in summaries):
        return None
    return ("Sequence-mean bias (oracle, not in the paper): each test sequence's own mean of its dataset "
            "bias (the ground-truth state's where there is one, else the labels), held constant: the best "
            "one constant per sequence can do.")
