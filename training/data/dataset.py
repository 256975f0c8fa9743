"""The versioned window dataset on disk, and its lazy ``torch.utils.data.Dataset``.

Layout (``biasgt windows`` writes it atomically)::

    DATASET/
      manifest.json                       format version, config + its hash, code version,
                                          per-sequence split and window counts, normaliser stats
      sequences/<name>/imu.npy            [W, T, 6] gyro (rad/s) then acc (m/s^2), float64
      sequences/<name>/bias.npy           [W, T, 6] interpolated bias, same order and units
      sequences/<name>/bias_std.npy       [W, T, 6] its standard deviation
      sequences/<name>/t_ns.npy           [W, T]    int64 IMU stamps
      sequences/<name>/start_R.npy        [W, 3, 3] reference world-from-imu at the first stamp
      sequences/<name>/start_v.npy        [W, 3]    (m/s)   start_p.npy [W, 3] (m)
      sequences/<name>/end_R.npy, end_v.npy, end_p.npy   the same at the last stamp
      sequences/<name>/temperature_degc.npy [W, T] IMU temperature (degC); only when every
                                          sequence carries one (manifest: has_temperature)
      sequences/<name>/state_bias.npy     [W, T, 6] the ground-truth state's own bias (e.g. EuRoC's),
                                          when the sequence has one; for the evaluation only

Arrays are plain ``.npy`` files so that :class:`WindowDataset` memory-maps them: a dataset
larger than RAM is read window by window. The split is a property of a *sequence*; a
sequence appears in exactly one split, so train and test never share windows of one
recording. Normalisation statistics come from the train split only.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pipeline import __version__
from pipeline.files.atomic import atomic_dir
from pipeline.errors import ConfigError, DataError, InputFormatError
from pipeline.files.jsonio import JsonRecord, dumps, read_json_object, to_plain
from pipeline.types import Split

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
_SAFE_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
MANIFEST = "manifest.json"
ARRAYS = ("imu", "bias", "bias_std", "t_ns", "start_R", "start_v", "start_p", "end_R", "end_v", "end_p")
#: The optional array: the IMU temperature [W, T] (degC).
TEMPERATURE = "temperature_degc"
#: The optional array of the evaluation: the dataset's own ground-truth-state bias (EuRoC's
#: ``state_groundtruth_estimate0``) at the window stamps, [W, T, 6]; NaN outside its span. Read by
#: the evaluation only (the random-walk oracle's start bias and the dataset-bias row), never trained on.
STATE_BIAS = "state_bias"


@dataclass
class SequenceWindows:
    """All windows of one sequence (shapes as in the module docstring).

    Attributes:
        name: Sequence name.
        split: Split of the whole sequence.
        arrays: ``ARRAYS`` name -> array, and ``TEMPERATURE`` when the IMU carries one.
        dropped: Reason -> number of windows dropped (a window counts under every reason that
            applies, so the reasons may add up to more than ``candidates - len(self)``).
        candidates: Windows planned before dropping (0: unknown, taken as ``len(self)``).
        info: JSON-serialisable provenance stored in the manifest entry (rates, reference kind,
            input folders).
    """

    name: str
    split: Split
    arrays: dict[str, np.ndarray]
    dropped: dict[str, int] = field(default_factory=dict)
    candidates: int = 0
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        missing = [a for a in ARRAYS if a not in self.arrays]
        if missing:
            raise DataError(f"windows of {self.name} lack arrays {missing}")
        n = {len(self.arrays[a]) for a in (*ARRAYS, TEMPERATURE, STATE_BIAS) if a in self.arrays}
        if len(n) != 1:
            raise DataError(f"windows of {self.name} have inconsistent counts {sorted(n)}")
        self.split = Split(self.split)
        self.candidates = max(int(self.candidates), len(self))

    def __len__(self) -> int:
        return len(self.arrays["imu"])


def config_hash(config: dict[str, Any]) -> str:
    """Stable short hash of a JSON-serialisable config."""
    text = json.dumps(to_plain(config, finite_only=True), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


#: Windows per chunk when statistics are computed (bounds the memory of a pass).
_STATS_CHUNK = 4096


def normalization_stats(windows: Iterable[SequenceWindows]) -> dict[str, list[float]]:
    """Per-channel mean and std of IMU and bias over the given (train) windows.

    Every sample of every window counts (a sample shared by two overlapping windows counts
    twice, as the model sees it): ``mean = x.reshape(-1, 6).mean(0)``,
    ``std = x.reshape(-1, 6).std(0, ddof=1)`` (floored at 1e-12) with ``x`` all train windows
    stacked. Two passes over chunks of windows, so memory-mapped arrays are never loaded whole.

    Returns:
        ``imu_mean``, ``imu_std``, ``bias_mean``, ``bias_std``: lists of 6 floats each
        (gyro x, y, z in rad/s then acc x, y, z in m/s^2); when every window set carries
        ``TEMPERATURE``, also ``temperature_mean`` and ``temperature_std`` (lists of 1 float, degC).

    Raises:
        DataError: No train window.
    """
    windows = [w for w in windows if len(w)]
    if not windows:
        raise DataError("no training windows to compute normalisation statistics from",
                        hint="assign at least one sequence with windows to split 'train'")

    def chunks(key: str, width: int) -> Iterator[np.ndarray]:
        for w in windows:
            a = w.arrays[key]
            for i in range(0, len(a), _STATS_CHUNK):
                yield np.asarray(a[i:i + _STATS_CHUNK], dtype=np.float64).reshape(-1, width)

    channels = {"imu": 6, "bias": 6}
    if all(TEMPERATURE in w.arrays for w in windows):
        channels["temperature"] = 1
    stats: dict[str, list[float]] = {}
    for name, width in channels.items():
        key = TEMPERATURE if name == "temperature" else name
        total, s = 0, np.zeros(width)
        for c in chunks(key, width):
            total += len(c)
            s += c.sum(axis=0)
        mean = s / total
        sq = np.zeros(width)
        for c in chunks(key, width):
            sq += ((c - mean) ** 2).sum(axis=0)
        std = np.sqrt(sq / max(total - 1, 1))
        stats[f"{name}_mean"] = mean.tolist()
        stats[f"{name}_std"] = np.maximum(std, 1e-12).tolist()
    return stats




def _load_arrays(folder: Path, temperature: bool = False) -> dict[str, np.ndarray]:
    """The arrays of one sequence folder (with ``TEMPERATURE`` if asked), memory-mapped read-only."""
    keys = (*ARRAYS, TEMPERATURE) if temperature else ARRAYS
    try:
        return {k: np.load(folder / f"{k}.npy", mmap_mode="r") for k in keys}
    except (OSError, ValueError) as exc:
        raise InputFormatError(f"cannot read window arrays ({exc})", path=folder,
                               hint="re-create the dataset with 'biasgt windows'") from None


#: Windows read at a time when checking an array (bounds the memory of the check).
_CHECK_CHUNK_WINDOWS = 1024


#: Arrays where NaN means "unknown" (a recovery without marginals has no bias std); inf is refused there too.
NAN_ALLOWED = ("bias_std",)


def check_finite_arrays(arrays: Mapping[str, np.ndarray], folder: Path) -> None:
    """Refuse a sequence whose floating arrays hold NaN or inf (:data:`NAN_ALLOWED`: inf), naming the
    file and the first bad window.

    The arrays are read in chunks of windows, so a memory-mapped dataset larger than RAM is checked too.

    Raises:
        DataError: ``folder/<array>.npy``: the first window with a non-finite value.
    """
    for key, array in arrays.items():
        if not np.issubdtype(array.dtype, np.floating):
            continue
        for start in range(0, len(array), _CHECK_CHUNK_WINDOWS):
            chunk = np.asarray(array[start:start + _CHECK_CHUNK_WINDOWS]).reshape(min(_CHECK_CHUNK_WINDOWS,
                                                                                      len(array) - start), -1)
            bad = (np.isinf(chunk) if key in NAN_ALLOWED else ~np.isfinite(chunk)).any(axis=1)
            if bad.any():
                first = start + int(np.argmax(bad))
                raise DataError(f"array '{key}' holds non-finite values (NaN or inf), first in window {first} of "
                                f"{len(array)}", path=folder / f"{key}.npy",
                                hint="re-create the dataset with 'biasgt windows' from finite inputs")


def write_dataset(
    sequences: Iterable[SequenceWindows],
    out_dir: str | Path,
    *,
    config: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> WindowManifest:
    """Write a window dataset atomically and return its manifest.

    ``sequences`` may be a generator: each sequence is written to the temporary folder as it
    comes and may then be freed, and the normalisation statistics are computed afterwards from
    the memory-mapped train arrays, so the dataset never has to fit in memory at once. An
    exception anywhere (also inside the generator) removes the temporary folder: ``out_dir`` is
    left as it was (absent, or the previous complete dataset).

    Args:
        sequences: Windows per sequence, each with its split.
        out_dir: Destination folder (replaced only once complete).
        config: The resolved windowing config (stored, and hashed into ``config_hash``).
        extra: More JSON-serialisable top-level manifest entries (e.g. ``rate_hz``).

    Returns:
        The manifest (also ``out_dir/manifest.json``): ``format_version``, ``code_version``,
        ``config``, ``config_hash``, ``window_samples`` (T), ``rate_hz``, ``splits`` (split ->
        sequence names), ``sequences`` (name -> split, windows, candidates, dropped, path,
        info), ``totals`` (split -> sequences, windows, candidates, dropped),
        ``normalization`` (train-split statistics, see :func:`normalization_stats`),
        ``has_temperature`` (every sequence carries ``TEMPERATURE``: its arrays are written;
        otherwise none are).

    Raises:
        ConfigError: A sequence name used twice or unsafe as a folder name.
        DataError: Windows of different lengths; no train window.
    """
    manifest: dict[str, Any] = {
        "format_version": FORMAT_VERSION,
        "code_version": __version__,
        "config": to_plain(config),
        "config_hash": config_hash(config),
        "window_samples": 0,
        "rate_hz": None,
        "splits": {},
        "sequences": {},
        "totals": {},
    }
    if extra:
        manifest.update(to_plain(extra))
    with atomic_dir(out_dir) as tmp:
        lengths: dict[int, str] = {}
        without_temperature: list[str] = []
        for seq in sequences:
            _check_sequence(seq, manifest, lengths)
            _write_arrays(tmp / "sequences" / seq.name, seq)
            if TEMPERATURE not in seq.arrays:
                without_temperature.append(seq.name)
            manifest["sequences"][seq.name] = {
                "split": seq.split.value,
                "windows": len(seq),
                "candidates": seq.candidates,
                "dropped": {k: int(v) for k, v in seq.dropped.items()},
                "path": f"sequences/{seq.name}",
                "info": to_plain(seq.info),
            }
            manifest["splits"].setdefault(seq.split.value, []).append(seq.name)
            log.info("%s (%s): %d windows kept of %d", seq.name, seq.split.value, len(seq), seq.candidates)
        manifest["window_samples"] = next(iter(lengths), 0)
        manifest["has_temperature"] = _keep_temperature(tmp, manifest, without_temperature)
        manifest["totals"] = _split_totals(manifest)
        train = [
            SequenceWindows(name, Split.TRAIN, _load_arrays(tmp / manifest["sequences"][name]["path"],
                                                            manifest["has_temperature"]))
            for name in manifest["splits"].get(Split.TRAIN.value, [])
        ]
        manifest["normalization"] = normalization_stats(train)
        del train  # close the memory maps before the folder is renamed
        (tmp / MANIFEST).write_text(dumps(manifest), encoding="utf-8")
    return WindowManifest.from_json(manifest)


def _check_sequence(seq: SequenceWindows, manifest: dict[str, Any], lengths: dict[int, str]) -> None:
    """Check one sequence against those before it (name once and safe, same window length), noting
    its window length in ``lengths`` and the first rate in ``manifest["rate_hz"]``.

    Raises:
        ConfigError: A sequence name used twice or unsafe as a folder name.
        DataError: Windows of different lengths.
    """
    if seq.name in manifest["sequences"]:
        other = manifest["sequences"][seq.name]["split"]
        raise ConfigError(f"sequence '{seq.name}' is given twice (splits {other} and {seq.split.value})",
                          field=seq.name, hint="list every sequence once, in exactly one split")
    if not _SAFE_NAME.match(seq.name):
        raise ConfigError(f"sequence name '{seq.name}' cannot be a folder name", field=seq.name,
                          hint="use letters, digits, '_', '-' and '.'")
    if len(seq):
        length = int(seq.arrays["imu"].shape[1])
        lengths.setdefault(length, seq.name)
        if len(lengths) > 1:
            (l0, n0), = [(k, v) for k, v in lengths.items() if k != length]
            raise DataError(
                f"windows of '{seq.name}' have {length} samples but those of '{n0}' have {l0} "
                "(IMU rates differ)",
                hint="resample every sequence onto one rate (--resample-hz HZ)")
        if manifest["rate_hz"] is None and seq.info.get("rate_hz") is not None:
            manifest["rate_hz"] = float(seq.info["rate_hz"])


def _write_arrays(folder: Path, seq: SequenceWindows) -> None:
    """The sequence's arrays as ``<key>.npy`` files in a new ``folder``."""
    folder.mkdir(parents=True)
    for key in (*ARRAYS, TEMPERATURE, STATE_BIAS):
        if key in seq.arrays:
            np.save(folder / f"{key}.npy", np.ascontiguousarray(seq.arrays[key]))


def _split_totals(manifest: dict[str, Any]) -> dict[str, dict[str, int]]:
    """Per split: sequences, kept windows, candidates and dropped windows."""
    totals: dict[str, dict[str, int]] = {}
    for split, names in manifest["splits"].items():
        entries = [manifest["sequences"][n] for n in names]
        kept = sum(e["windows"] for e in entries)
        cand = sum(e["candidates"] for e in entries)
        totals[split] = {"sequences": len(names), "windows": kept, "candidates": cand,
                         "dropped": cand - kept}
    return totals


def _keep_temperature(tmp: Path, manifest: dict[str, Any], without: list[str]) -> bool:
    """Whether the dataset keeps the temperature: only when no sequence lacks it (else its files go)."""
    if not without:
        return bool(manifest["sequences"])
    for entry in manifest["sequences"].values():
        (tmp / entry["path"] / f"{TEMPERATURE}.npy").unlink(missing_ok=True)
    if len(without) < len(manifest["sequences"]):
        log.info("IMU temperature left out of the dataset: no temperature in %s", ", ".join(without))
    return False


@dataclass(frozen=True)
class ManifestEntry:
    """One sequence of the manifest: its split, kept / planned windows and its folder (relative)."""

    split: Split
    windows: int
    candidates: int
    path: str


@dataclass(frozen=True, eq=False)  # holds arrays: compare .data / the fields
class WindowManifest(JsonRecord):
    """``manifest.json`` of a window dataset: the typed fields plus the whole object.

    Attributes:
        data: The whole JSON object (see :func:`write_dataset`); ``manifest["key"]`` reads it.
        config_hash: Hash of the windowing config.
        window_samples: Samples per window (T).
        rate_hz: IMU rate of every window.
        sequences: Name -> entry, in the order written.
        normalization: ``imu_mean``, ``imu_std``, ``bias_mean``, ``bias_std`` -> [6] (train split).
    """

    data: Mapping[str, Any]
    config_hash: str
    window_samples: int
    rate_hz: float | None
    sequences: dict[str, ManifestEntry]
    normalization: dict[str, np.ndarray]

    def names(self, split: Split | str) -> list[str]:
        """The sequences of ``split``, in manifest order."""
        split = Split(split)
        return [name for name, entry in self.sequences.items() if entry.split is split]

    @classmethod
    def from_json(cls, data: Mapping[str, Any], path: str | Path | None = None) -> WindowManifest:
        """Parse the JSON object.

        Raises:
            InputFormatError: Another format version, or a malformed field.
        """
        if data.get("format_version") != FORMAT_VERSION:
            raise InputFormatError(f"unsupported dataset format {data.get('format_version')}", path=path,
                                   hint="re-create the dataset with this version's 'biasgt windows'")
        try:
            sequences = {str(name): ManifestEntry(Split(e["split"]), int(e["windows"]), int(e["candidates"]),
                                                  str(e["path"])) for name, e in data["sequences"].items()}
            _check_splits(data.get("splits"), sequences, path)
            norm = {str(k): np.asarray(v, dtype=np.float64) for k, v in (data.get("normalization") or {}).items()}
            rate = data.get("rate_hz")
            return cls(dict(data), str(data["config_hash"]), int(data["window_samples"]),
                       None if rate is None else float(rate), sequences, norm)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputFormatError(f"malformed manifest ({type(exc).__name__}: {exc})", path=path,
                                   hint="re-create the dataset with 'biasgt windows'") from None


def _check_splits(splits: Any, sequences: Mapping[str, ManifestEntry], path: str | Path | None) -> None:
    """``splits`` (split -> names) must list every sequence under the split its entry names, and nothing else.

    Raises:
        InputFormatError: Naming both fields (``sequences.NAME.split`` and ``splits.SPLIT``).
    """
    if splits is None:
        return
    hint = "the manifest was edited by hand: re-create the dataset with 'biasgt windows' (or restore manifest.json)"
    listed: dict[str, str] = {}
    for split, names in dict(splits).items():
        for name in names or []:
            listed[str(name)] = str(split)
            if str(name) not in sequences:
                raise InputFormatError(f"splits.{split} lists sequence '{name}', which sequences does not hold",
                                       path=path, field=f"splits.{split}", hint=hint)
    for name, entry in sequences.items():
        if listed.get(name) != entry.split.value:
            other = (f"splits.{entry.split.value} does not list it" if name not in listed
                     else f"splits.{listed[name]} lists it")
            raise InputFormatError(f"the manifest disagrees with itself: sequences.{name}.split is "
                                   f"'{entry.split.value}' but {other}", path=path,
                                   field=f"sequences.{name}.split / splits.{entry.split.value}", hint=hint)


def read_manifest(root: str | Path) -> WindowManifest:
    """Load and check a dataset manifest (``root/manifest.json``).

    Raises:
        InputFormatError: Not a dataset, unreadable, or another format version.
    """
    path = Path(root) / MANIFEST
    if not path.is_file():
        raise InputFormatError("not a biasgt window dataset (no manifest.json)", path=root,
                               hint="create one with 'biasgt windows'")
    return WindowManifest.from_json(read_json_object(path, hint="re-create the dataset with 'biasgt windows'"), path)


def with_state_labels(root: str | Path, out_dir: str | Path) -> Path:
    """A copy of the dataset at ``root`` whose labels (``bias.npy``) are the ground-truth state's own bias
    (:data:`STATE_BIAS`, EuRoC's) where a sequence has it finite throughout; every other file (the
    manifest with its normalisation, the records) is linked, not copied. Written atomically.

    Raises:
        InputFormatError: ``root`` is not a window dataset.
    """
    root, out_dir = Path(root).resolve(), Path(out_dir)
    manifest = read_manifest(root)
    with atomic_dir(out_dir) as tmp:
        for entry in root.iterdir():
            if entry.name != "sequences":
                (tmp / entry.name).symlink_to(entry)
        for name, seq in manifest.sequences.items():
            src, dst = root / seq.path, tmp / seq.path
            dst.mkdir(parents=True)
            state = np.load(src / f"{STATE_BIAS}.npy") if (src / f"{STATE_BIAS}.npy").is_file() else None
            relabel = state is not None and bool(np.all(np.isfinite(state)))
            for f in src.iterdir():
                if f.name == "bias.npy" and relabel:
                    np.save(dst / f.name, state.astype(np.float64, copy=False))
                else:
                    (dst / f.name).symlink_to(f)
            log.info("%s: labels %s", name, f"from {STATE_BIAS}" if relabel else "kept")
    return out_dir


class WindowDataset(torch.utils.data.Dataset):
    """Windows of one split, memory-mapped; a ``torch.utils.data.Dataset``.

    The ``.npy`` arrays are opened with ``np.load(..., mmap_mode="r")`` (``np.memmap``): only
    the windows asked for are read from disk, so the dataset may be larger than RAM.

    Items are dicts: ``imu`` [T, 6] (gyro rad/s, acc m/s^2), ``bias`` [T, 6], ``bias_std``
    [T, 6], ``dt_s`` [T-1], ``start_R`` [3, 3], ``start_v`` [3], ``start_p`` [3], ``end_R``
    [3, 3], ``end_v`` [3], ``end_p`` [3], and ``temperature_degc`` [T] when the dataset has
    it (:attr:`has_temperature`) (tensors of ``dtype``), plus ``t0_ns`` (int) and
    ``sequence`` (str). A ``DataLoader`` with ``batch_size=B`` stacks them to [B, T, 6], ...,
    ``t0_ns`` [B] (int64) and a list of B names.

    Args:
        root: Dataset folder.
        split: Which split to serve (a sequence belongs to exactly one).
        dtype: Floating dtype of the returned tensors (default float32).

    Raises:
        InputFormatError: No dataset, another format, unreadable arrays.
        DataError: An array holds NaN or inf (:func:`check_finite_arrays`), found when opened.
    """

    def __init__(self, root: str | Path, split: Split | str = Split.TRAIN, dtype: Any = None) -> None:
        self.root = Path(root)
        self.split = Split(split)
        self.manifest = read_manifest(self.root)
        self.dtype = dtype or torch.float32
        self.normalization = dict(self.manifest.normalization)
        self.window_samples = self.manifest.window_samples
        self.has_temperature = bool(self.manifest.get("has_temperature", False))
        self._arrays: list[dict[str, np.ndarray]] = []
        self._names: list[str] = []
        index: list[tuple[int, int]] = []
        for name in self.manifest.names(self.split):
            entry = self.manifest.sequences[name]
            if entry.windows == 0:
                continue
            arrays = _load_arrays(self.root / entry.path, self.has_temperature)
            check_finite_arrays(arrays, self.root / entry.path)
            if len(arrays["imu"]) != entry.windows:
                raise InputFormatError(f"sequence '{name}' holds {len(arrays['imu'])} windows, the manifest says "
                                       f"{entry.windows}", path=self.root / entry.path,
                                       hint="re-create the dataset with 'biasgt windows'")
            self._arrays.append(arrays)
            self._names.append(name)
            index.extend((len(self._arrays) - 1, i) for i in range(entry.windows))
        self._index = index

    def __getstate__(self) -> dict[str, Any]:
        # Pickled for DataLoader workers started by 'spawn': re-open the memory maps there
        # instead of copying every array into the pickle.
        state = dict(self.__dict__)
        state["_arrays"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        seqs = self.manifest.sequences
        self._arrays = [_load_arrays(self.root / seqs[name].path, self.has_temperature) for name in self._names]

    @property
    def sequences(self) -> list[str]:
        return list(self._names)

    def arrays(self, sequence: str) -> dict[str, np.ndarray]:
        """The memory-mapped arrays of one sequence of this split (``ARRAYS`` name -> [W, ...])."""
        return self._arrays[self._names.index(sequence)]

    def __len__(self) -> int:
        return len(self._index)

    def __getitem__(self, item: int) -> dict[str, Any]:
        s, i = self._index[item]
        return self._item(self._arrays[s], i, self._names[s])

    def __getitems__(self, items: list[int]) -> list[dict[str, Any]]:
        """The items of a batch (``DataLoader`` calls this): one read per sequence and array of
        the rows asked for (in file order) instead of one per window and array, which is several
        times faster on memory maps. Equal to ``[self[i] for i in items]``."""
        out: list[Any] = [None] * len(items)
        by_seq: dict[int, list[tuple[int, int]]] = {}
        for pos, item in enumerate(items):
            s, i = self._index[item]
            by_seq.setdefault(s, []).append((pos, i))
        for s, members in by_seq.items():
            members.sort(key=lambda m: m[1])
            rows = np.array([i for _, i in members])
            loaded = {k: np.asarray(v[rows]) for k, v in self._arrays[s].items()}
            for j, (pos, _) in enumerate(members):
                out[pos] = self._item(loaded, j, self._names[s])
        return out

    def _item(self, a: dict[str, np.ndarray], i: int, name: str) -> dict[str, Any]:
        """Item ``i`` of one sequence's arrays ``a``."""
        t_ns = np.asarray(a["t_ns"][i])
        out: dict[str, Any] = {
            k: torch.as_tensor(np.array(a[k][i]), dtype=self.dtype)
            for k in a if k != "t_ns"
        }
        out["dt_s"] = torch.as_tensor(np.diff(t_ns) * 1e-9, dtype=self.dtype)
        out["t0_ns"] = int(t_ns[0])
        out["sequence"] = name
        return out
