"""Each sequence's whole IMU record beside a window dataset, for models that look before their window.

The window dataset (:mod:`training.data.dataset`) holds 1-s windows only. A model or reference row that
may see what came *before* its window (a rest at the start, a long history) reads the sequence's
record from ``DATASET/context/`` instead, stored once per sequence::

    DATASET/context/<name>/imu.npy               [N, 6] gyro (rad/s) then acc (m/s^2), float64
    DATASET/context/<name>/t_ns.npy              [N]    int64 IMU stamps (the windows' grid)
    DATASET/context/<name>/temperature_degc.npy  [N]    IMU temperature (degC), when the IMU has one

A window finds its place by its first stamp (``searchsorted``), so nothing is copied into the
windows. **Memory**: 56 bytes per IMU sample per sequence (64 with temperature), whatever the
window count or overlap: at 200 Hz, 0.67 MB per minute of recording (EuRoC's ten sequences:
about 15 MB), against ``T * 6 * 8 * 3`` bytes of IMU, bias and sigma per 1-s window in the
windows themselves. :class:`SequenceContext` memory-maps the arrays and keeps prefix sums of the
IMU and the temperature in RAM (another 56 bytes per sample) for O(1) history and rest means.

**Causality**: every summary here of the window starting at sample ``i`` with ``T`` samples reads
samples ``< i + T`` only (its own window and what came before it), never later ones.

Rest detection (:func:`detect_rests`): the record is cut into blocks of ``block_s``; a block is
at rest when every gyro channel's std is below ``gyro_std_max`` and every accelerometer channel's
below ``acc_std_max``, and its mean differs from the previous rest block's by less than
``gyro_step_max`` / ``acc_step_max``. Runs of at least ``min_rest_s`` of rest blocks are rests
(the last block of each run is dropped as a margin before the motion starts).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.files.atomic import atomic_dir
from pipeline.errors import DataError, InputFormatError
from pipeline.ingest import load
from pipeline.store import is_store, read_store
from training.data.dataset import WindowManifest, read_manifest
from training.data.windows import WindowConfig, WindowSource, build_window_dataset, resample_imu

log = logging.getLogger(__name__)

__all__ = ["CONTEXT_DIR", "RestConfig", "SequenceContext", "detect_rests", "has_context", "open_context",
           "write_context", "write_window_dataset"]

#: Folder of the sequence records inside a window dataset.
CONTEXT_DIR = "context"


@dataclass(frozen=True)
class RestConfig:
    """Thresholds of :func:`detect_rests` (see the module docstring)."""

    block_s: float = 0.25
    gyro_std_max: float = 0.02  # rad/s (the vibration of idling rotors passes; hand-held motion does not)
    acc_std_max: float = 0.35  # m/s^2
    gyro_step_max: float = 0.01  # rad/s
    acc_step_max: float = 0.15  # m/s^2
    min_rest_s: float = 0.5


def detect_rests(imu: np.ndarray, rate_hz: float, config: RestConfig = RestConfig()) -> list[tuple[int, int]]:
    """Rest spans ``[(first, stop), ...]`` (sample indices, ``stop`` exclusive) of a record [N, 6].

    See the module docstring for the rule.
    """
    n = max(1, int(round(config.block_s * rate_hz)))
    nb = len(imu) // n
    if nb == 0:
        return []
    blocks = np.asarray(imu[:nb * n], dtype=np.float64).reshape(nb, n, 6)
    std, mean = blocks.std(axis=1), blocks.mean(axis=1)
    quiet = (std[:, :3].max(1) < config.gyro_std_max) & (std[:, 3:].max(1) < config.acc_std_max)
    steady = np.ones(nb, dtype=bool)
    steady[1:] = ((np.abs(np.diff(mean[:, :3], axis=0)).max(1) < config.gyro_step_max)
                  & (np.abs(np.diff(mean[:, 3:], axis=0)).max(1) < config.acc_step_max))
    rests, start = [], None
    need = int(np.ceil(config.min_rest_s / config.block_s)) + 1  # + the margin block
    for b in range(nb + 1):
        at_rest = b < nb and quiet[b] and (start is None or steady[b])
        if at_rest and start is None:
            start = b
        elif not at_rest and start is not None:
            if b - start >= need:
                rests.append((start * n, (b - 1) * n))
            start = b if b < nb and quiet[b] else None
    return rests


@dataclass
class SequenceContext:
    """One sequence's record (module docstring) with causal summaries.

    Attributes:
        name: Sequence name.
        imu: [N, 6] gyro (rad/s) then acc (m/s^2).
        t_ns: [N] stamps.
        temperature_degc: [N] or None.
        rate_hz: Nominal rate.
        rests: Rest spans (:func:`detect_rests`).
    """

    name: str
    imu: np.ndarray
    t_ns: np.ndarray
    temperature_degc: np.ndarray | None
    rate_hz: float
    rests: list[tuple[int, int]] = dataclasses.field(default_factory=list)
    _cum: np.ndarray | None = None
    _tcum: np.ndarray | None = None
    #: Arrays derived from the record once per process (e.g. :func:`training.rows.bias_filter.track_of`), by key.
    derived: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def open(cls, dataset_dir: str | Path, name: str, rest: RestConfig = RestConfig()) -> SequenceContext:
        """Memory-map ``DATASET/context/<name>``.

        Raises:
            InputFormatError: The dataset has no record of ``name``.
        """
        folder = Path(dataset_dir) / CONTEXT_DIR / name
        if not (folder / "imu.npy").is_file():
            raise InputFormatError(f"the window dataset has no sequence record of '{name}'", path=folder,
                                   hint="write it with training.data.records.write_context(DATASET) "
                                        "(benchmarks/learning/context_euroc.py does)")
        imu = np.load(folder / "imu.npy", mmap_mode="r")
        t_ns = np.load(folder / "t_ns.npy")
        temp = np.load(folder / "temperature_degc.npy", mmap_mode="r") if (folder / "temperature_degc.npy").is_file() else None
        rate = 1e9 / float(np.median(np.diff(t_ns))) if len(t_ns) > 1 else 1.0
        return cls(name, imu, t_ns, temp, rate, detect_rests(np.asarray(imu), rate, rest))

    def index(self, t0_ns: np.ndarray | int) -> np.ndarray:
        """Sample index of each window's first stamp ``t0_ns`` [B] (the stamp itself must be in the record).

        Raises:
            DataError: A stamp not in the record.
        """
        t0 = np.atleast_1d(np.asarray(t0_ns, dtype=np.int64))
        i = np.searchsorted(self.t_ns, t0)
        bad = (i >= len(self.t_ns)) | (self.t_ns[np.minimum(i, len(self.t_ns) - 1)] != t0)
        if bad.any():
            raise DataError(f"window stamp {int(t0[bad][0])} is not a sample of the record of '{self.name}'",
                            hint="re-write the dataset's context with training.data.records.write_context")
        return i

    def _prefix(self) -> np.ndarray:
        if self._cum is None:
            x = np.asarray(self.imu, dtype=np.float64)
            self._cum = np.concatenate([np.zeros((1, 6)), np.cumsum(x, axis=0)])
        return self._cum

    def history_mean(self, stop: np.ndarray, samples: int | None) -> tuple[np.ndarray, np.ndarray]:
        """Mean IMU [B, 6] over the ``samples`` samples before each ``stop`` [B] (None: since the
        start), and the fraction [B] of those samples that exist (0: no history, mean 0)."""
        cum = self._prefix()
        stop = np.asarray(stop, dtype=np.int64)
        first = np.zeros_like(stop) if samples is None else np.maximum(stop - samples, 0)
        count = stop - first
        mean = (cum[stop] - cum[first]) / np.maximum(count, 1)[:, None]
        full = np.full(len(stop), 1.0) if samples is None else count / float(samples)
        return np.where(count[:, None] > 0, mean, 0.0), np.where(count > 0, full, 0.0)

    def rest_span(self, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The first rest of the record as seen by windows ending before ``stop`` [B]:
        ``(first, end)`` [B] each, ``end - first < min`` (or 0) when none is seen yet. The rest is
        cut at ``stop`` (causal); a rest cut below half a second counts as none."""
        stop = np.asarray(stop, dtype=np.int64)
        first = np.zeros_like(stop)
        end = np.zeros_like(stop)
        min_len = int(0.5 * self.rate_hz)
        for a, b in self.rests:
            seen = (end == 0) & (np.minimum(b, stop) - a >= min_len)
            first[seen], end[seen] = a, np.minimum(b, stop[seen])
        return first, end

    def rest_mean(self, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Mean IMU [B, 6] over the first rest seen before each ``stop`` [B] (:meth:`rest_span`), whether
        one is seen [B] (bool; where not, the mean is 0), and the mean temperature there [B] (or None)."""
        first, end = self.rest_span(stop)
        cum = self._prefix()
        found = end > first
        mean = (cum[end] - cum[first]) / np.maximum(end - first, 1)[:, None]
        temp = None
        if self.temperature_degc is not None:
            if self._tcum is None:
                self._tcum = np.concatenate([[0.0], np.cumsum(np.asarray(self.temperature_degc, dtype=np.float64))])
            tc = self._tcum
            temp = np.where(found, (tc[end] - tc[first]) / np.maximum(end - first, 1), np.nan)
        return np.where(found[:, None], mean, 0.0), found, temp


def open_context(root: str | Path, name: str) -> SequenceContext:
    """The record of ``name`` in the dataset at ``root``, opened once per process (cached)."""
    return _open_cached(str(Path(root).resolve()), name)


@functools.lru_cache(maxsize=64)
def _open_cached(root: str, name: str) -> SequenceContext:
    return SequenceContext.open(root, name)


def has_context(dataset_dir: str | Path) -> bool:
    """Whether ``dataset_dir`` holds sequence records (:func:`write_context`)."""
    return (Path(dataset_dir) / CONTEXT_DIR).is_dir()


def _store_dir(info: dict, dataset_dir: Path, base_dir: Path | None, name: str) -> Path:
    rel = info.get("store_dir")
    if not rel:
        raise InputFormatError(f"the manifest names no store of '{name}' (info.store_dir)",
                               path=dataset_dir / "manifest.json",
                               hint="re-create the dataset with this version's 'biasgt windows'")
    bases = [Path(rel)] if Path(rel).is_absolute() else [
        b / rel for b in ([base_dir] if base_dir else []) + [Path.cwd(), *dataset_dir.resolve().parents]]
    for cand in bases:
        if cand.exists():
            return cand
    raise InputFormatError(f"the store of '{name}' ({rel}) is not found", path=dataset_dir / "manifest.json",
                           hint="pass base_dir, the folder the workflow ran in (results/ lies under it)")


def write_window_dataset(sources: list[WindowSource], out_dir: str | Path,
                         config: WindowConfig = WindowConfig()) -> WindowManifest:
    """The window dataset (:func:`training.data.windows.build_window_dataset`) and its sequence records
    (:func:`write_context`), written as one: both land in a temporary sibling renamed onto ``out_dir`` once
    complete, so a failure in either (a full disk, a store gone) leaves ``out_dir`` as it was.

    Returns:
        The manifest.
    """
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        manifest = build_window_dataset(sources, tmp, config)
        write_context(tmp)
    return manifest


def write_context(dataset_dir: str | Path, base_dir: str | Path | None = None) -> Path:
    """Write ``DATASET/context/`` (module docstring) from the stores the manifest names.

    Args:
        dataset_dir: A window dataset.
        base_dir: Folder that the manifest's relative ``store_dir`` paths start from (default: the
            current folder, then the dataset's parent folders).

    Returns:
        The context folder (written atomically, replacing an earlier one).

    Raises:
        InputFormatError: A store not found, or the windows not on the record's stamps.
    """
    dataset_dir = Path(dataset_dir)
    manifest = read_manifest(dataset_dir)
    out = dataset_dir / CONTEXT_DIR
    with atomic_dir(out) as tmp:
        for name, entry in manifest["sequences"].items():
            info = entry.get("info") or {}
            store = _store_dir(info, dataset_dir, Path(base_dir) if base_dir else None, name)
            seq = read_store(store) if is_store(store) else load(store)
            imu = seq.imu
            if info.get("resampled"):
                imu = resample_imu(imu, float(manifest["rate_hz"]))
            folder = tmp / name
            folder.mkdir()
            np.save(folder / "imu.npy", np.hstack([imu.gyro_radps, imu.acc_mps2]).astype(np.float64))
            np.save(folder / "t_ns.npy", np.asarray(imu.t_ns, dtype=np.int64))
            temp = getattr(imu, "temperature_degc", None)
            if temp is not None:
                np.save(folder / "temperature_degc.npy", np.asarray(temp, dtype=np.float64))
            log.info("context of %s: %d samples", name, len(imu.t_ns))
    return out
