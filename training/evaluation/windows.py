"""The evaluation's test windows: the test split made non-overlapping, with the protocol's choices.

See :mod:`training.evaluation.evaluate` for the protocol. :func:`load_test_windows` applies the evaluation's
stated choices (:class:`training.config.EvaluationConfig`): the gravity of the integration
(:class:`training.config.EvalGravity`) and the oracle's random walks
(:class:`training.config.OracleWalk`), and carries optional per-window dataset arrays (the
ground-truth-state bias :data:`training.data.dataset.STATE_BIAS`, and those a reference row needs; NaN
where a sequence has none) into the items.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import default_collate

from pipeline.errors import DataError
from training.config import EvalGravity, EvaluationConfig, OracleWalk
from training.data.dataset import STATE_BIAS, Split, WindowDataset
from pipeline.types import DEFAULT_GRAVITY_MPS2

__all__ = ["TestWindows", "load_test_windows", "non_overlapping"]


@dataclass(frozen=True)
class TestWindows:
    """The non-overlapping test windows of a dataset.

    Attributes:
        dataset: The test split, float64 items.
        index: Dataset item of each kept window, [W].
        sequence: Sequence name of each kept window, [W].
        t0_ns: First stamp of each kept window, [W].
        gravity_mps2: Sequence -> gravity in its world frame, [3].
        gravity_source: Sequence -> "nominal", "recovery" or "default" (recovered asked, none kept).
        random_walk: Sequence -> bias random-walk strengths of the oracle, [6] (NaN when unknown).
        bias_mean: The train split's mean bias, [6].
        arrays: Optional per-window dataset arrays of the kept windows, name -> [W, ...] (NaN where
            the sequence has none), e.g. the ground-truth-state bias.
    """

    dataset: WindowDataset
    index: np.ndarray
    sequence: np.ndarray
    t0_ns: np.ndarray
    gravity_mps2: dict[str, np.ndarray]
    gravity_source: dict[str, str]
    random_walk: dict[str, np.ndarray]
    bias_mean: np.ndarray
    arrays: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def root(self) -> Path:
        return self.dataset.root

    @property
    def manifest(self) -> dict[str, Any]:
        return self.dataset.manifest

    def __len__(self) -> int:
        return len(self.index)

    def sequences(self) -> list[str]:
        """Test sequences with at least one window, in dataset order."""
        return [s for s in self.dataset.sequences if np.any(self.sequence == s)]

    def items(self, rows: np.ndarray) -> dict[str, Any]:
        """Collated float64 items of the kept windows ``rows`` (positions in ``index``), with the ``arrays``."""
        items = default_collate([self.dataset[int(i)] for i in self.index[rows]])
        for name, values in self.arrays.items():
            items[name] = torch.from_numpy(np.ascontiguousarray(values[rows]))
        return items


def non_overlapping(t_ns: np.ndarray) -> np.ndarray:
    """Positions of the windows kept greedily in time order so that no two overlap (see module docstring)."""
    keep, last_end = [], None
    for w in np.argsort(t_ns[:, 0], kind="stable"):
        if last_end is None or t_ns[w, 0] >= last_end:
            keep.append(int(w))
            last_end = t_ns[w, -1]
    return np.asarray(keep, dtype=np.int64)


def load_test_windows(root: str | Path, config: EvaluationConfig = EvaluationConfig(),
                      arrays: tuple[str, ...] = ()) -> TestWindows:
    """The non-overlapping test windows of the dataset at ``root``, with ``config``'s gravity and oracle walks,
    the ground-truth-state bias and the optional per-window ``arrays`` (``<name>.npy`` of the sequence folders).

    Raises:
        InputFormatError: Not a dataset, another format version.
        DataError: The test split has no window.
    """
    ds = WindowDataset(root, Split.TEST, dtype=torch.float64)
    if len(ds) == 0:
        raise DataError("the dataset has no test window", hint="assign sequences to split 'test' in 'biasgt windows' "
                        f"(--splits) and re-create {Path(root)}")
    names_of_arrays = tuple(dict.fromkeys((STATE_BIAS, *arrays)))
    index, names, t0, extra = [], [], [], {a: [] for a in names_of_arrays}
    gravity, gsource, walk = {}, {}, {}
    offset = 0
    for name in ds.sequences:
        t_ns = np.asarray(ds.arrays(name)["t_ns"])
        keep = non_overlapping(t_ns)
        index.append(offset + keep)
        names.append(np.full(len(keep), name, dtype=object))
        t0.append(t_ns[keep, 0])
        offset += len(t_ns)
        entry = ds.manifest["sequences"][name]
        info = entry.get("info", {})
        g = None if config.gravity is EvalGravity.NOMINAL else info.get("gravity_mps2")
        gravity[name] = np.asarray(DEFAULT_GRAVITY_MPS2 if g is None else g, dtype=np.float64)
        gsource[name] = "nominal" if config.gravity is EvalGravity.NOMINAL else "default" if g is None else "recovery"
        rw = info.get("sensor_random_walk" if config.oracle_random_walk is OracleWalk.SENSOR else "bias_random_walk")
        walk[name] = np.full(6, np.nan) if rw is None else np.asarray(rw, dtype=np.float64)
        for a in names_of_arrays:
            extra[a].append(_array(Path(root) / entry["path"], a, keep, t_ns.shape[1]))
    return TestWindows(ds, np.concatenate(index), np.concatenate(names), np.concatenate(t0), gravity, gsource, walk,
                       np.asarray(ds.manifest["normalization"]["bias_mean"], dtype=np.float64),
                       {a: np.concatenate(v) for a, v in extra.items()})


def _array(folder: Path, name: str, keep: np.ndarray, samples: int) -> np.ndarray:
    """The per-window array ``name`` of the kept windows of one sequence folder, [K, ...] (NaN [K, T, 6] when
    the sequence has none)."""
    path = folder / f"{name}.npy"
    if not path.is_file():
        return np.full((len(keep), samples, 6), np.nan)
    return np.asarray(np.load(path, mmap_mode="r")[keep], dtype=np.float64)
