"""The parsed workflow config: the sequence table (:class:`WorkflowConfig`, :class:`SequenceEntry`),
where each source's data comes from, and how an entry's paths resolve (:func:`data_root`,
:func:`resolve_input_path`).
"""

from __future__ import annotations

import copy
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.errors import ConfigError
from pipeline.io.asl import ASL_FORMAT
from pipeline.io.registry import workflow_formats
from pipeline.types import Split

# SimConfig fields set by an entry's shorthand keys; ``overrides`` must not set them again.
_SIM_SHORTHANDS = {
    ("name",): "name",
    ("duration_s",): "duration_s",
    ("seed",): "seed",
    ("motion", "preset"): "preset",
    ("poses", "format"): "pose_format",
}


#: The one source kind that is not a reader: the built-in simulator, which writes an ASL folder.
SIMULATE = "simulate"
#: The reader of what the simulator writes (the ``fmt`` its sequences are ingested with).
SIMULATED_FORMAT = ASL_FORMAT


def source_kinds() -> list[str]:
    """Where a sequence's data may come from: :data:`SIMULATE`, then every reader of
    :func:`pipeline.io.registry.workflow_formats` (a workflow entry's ``source:``)."""
    return [SIMULATE, *workflow_formats()]


def source_kind(value: str) -> str:
    """``value`` if it is one of :func:`source_kinds`.

    Raises:
        ConfigError: It is not (the message lists them).
    """
    kinds = source_kinds()
    if value not in kinds:
        raise ConfigError(f"{value!r} is not one of {', '.join(kinds)}", field="source",
                          hint="'simulate' or an input format (biasgt inspect --help lists them under --format)")
    return value


def reader_format(source: str) -> str:
    """The ``fmt`` given to :func:`pipeline.io.load_sequence` for a sequence from ``source``."""
    return SIMULATED_FORMAT if source == SIMULATE else source


@dataclass(frozen=True)
class SequenceEntry:
    """One entry of the ``sequences:`` list, checked.

    Attributes:
        name: Sequence name (safe for paths).
        source: Where the data comes from: one of :func:`source_kinds`.
        split: Train / test / none.
        index: Position in the ``sequences:`` list (0-based), for error messages.
        path: Resolved input file or folder (real sources), ``None`` for simulated ones.
        raw: The entry as validated (schema defaults filled in).
    """

    name: str
    source: str
    split: Split
    index: int
    path: Path | None
    raw: dict[str, Any] = field(repr=False, compare=False)

    @property
    def is_simulated(self) -> bool:
        return self.source == SIMULATE

    @property
    def where(self) -> str:
        """``sequences[i] ('name')``, for messages."""
        return f"sequences[{self.index}] ('{self.name}')"


@dataclass(frozen=True)
class WorkflowConfig:
    """A checked workflow config.

    Attributes:
        data: The config dict with schema defaults filled in.
        config_file: The file it was read from (relative paths are resolved against its folder),
            ``None`` when built from a dict alone (paths then resolve against the current folder).
        sequences: The sequence table, in config order.
    """

    data: dict[str, Any]
    config_file: Path | None
    sequences: tuple[SequenceEntry, ...]

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.sequences]

    def select(
        self, *, splits: Iterable[Split | str] | None = None, sources: Iterable[str] | None = None
    ) -> list[SequenceEntry]:
        """Entries whose split and source are among the given ones (``None``: any)."""
        split_set = None if splits is None else {Split(s) for s in splits}
        source_set = None if sources is None else {source_kind(s) for s in sources}
        return [
            s for s in self.sequences
            if (split_set is None or s.split in split_set) and (source_set is None or s.source in source_set)
        ]

    def sequence(self, name: str) -> SequenceEntry:
        """The entry called ``name``.

        Raises:
            ConfigError: No such sequence.
        """
        for s in self.sequences:
            if s.name == name:
                return s
        raise ConfigError(
            f"no sequence named '{name}'", path=self.config_file, field="sequences",
            hint=f"configured sequences: {', '.join(self.names) or '(none)'}",
        )

    def section(self, name: str) -> dict[str, Any]:
        """A top-level section (``ingest``, ``recovery``, ...), ``{}`` when absent."""
        return dict(self.data.get(name) or {})


def _expand(raw: str) -> Path:
    return Path(os.path.expandvars(os.path.expanduser(raw)))


def data_root(data: dict[str, Any], config_file: str | Path | None) -> Path:
    """Absolute folder that relative input paths are resolved against."""
    base = Path(config_file).resolve().parent if config_file is not None else Path.cwd()
    root = _expand(str(data.get("data_root", ".")))
    return Path(os.path.normpath(root if root.is_absolute() else base / root))


def resolve_input_path(raw: str, root: Path) -> Path:
    """``raw`` with ``~`` and ``$VARS`` expanded, made absolute against ``root``."""
    p = _expand(raw)
    return Path(os.path.normpath(p if p.is_absolute() else root / p))


def deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def sim_dict(entry: dict[str, Any], root: Path, config_file: Path | None, where: str) -> dict[str, Any]:
    overrides = entry.get("overrides") or {}
    for keys, shorthand in _SIM_SHORTHANDS.items():
        node: Any = overrides
        for k in keys:
            node = node.get(k) if isinstance(node, dict) else None
        if node is not None:
            raise ConfigError(
                f"{where}: overrides.{'.'.join(keys)} repeats the entry's '{shorthand}'",
                path=config_file, field=f"overrides.{'.'.join(keys)}",
                hint=f"set it with '{shorthand}:' only" if shorthand != "name" else "the name is the entry's 'name'",
            )
    base = {
        "name": entry["name"],
        "duration_s": entry.get("duration_s", 60),
        "seed": entry.get("seed", 0),
        "motion": {"preset": entry.get("preset", "handheld")},
        "poses": {"format": entry.get("pose_format", "mocap")},
    }
    sim = deep_merge(base, overrides)
    gt = (sim.get("motion") or {}).get("ground_truth_path")
    if gt is not None:
        sim["motion"]["ground_truth_path"] = str(resolve_input_path(str(gt), root))
    return sim
