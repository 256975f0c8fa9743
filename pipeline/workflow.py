"""Snakemake glue: config loading and checks, the sequence table, path helpers, step functions.

Everything the workflow (``Snakefile`` and ``workflow/rules/*.smk``) needs lives here as plain,
importable and unit-tested Python, so that the ``.smk`` files only wire rules together:

* :func:`load_config` / :func:`validate_schema` / :func:`check_config`: read a workflow config,
  apply the JSON schema (``workflow/schemas/config.schema.yaml``, with its defaults, exactly as
  ``snakemake.utils.validate`` does) and check what a schema cannot say (unique names, existing
  input paths, simulator settings). Errors are :class:`~pipeline.errors.ConfigError` naming the
  config file and the sequence entry.
* :class:`WorkflowConfig` / :class:`SequenceEntry`: the parsed sequence table.
* :func:`stage_dir` / :func:`log_file` / :func:`ingest_input` / :func:`simulate_settings` /
  :func:`ingest_settings` / :func:`recovery_settings` / :func:`interpolation_settings` /
  :func:`validation_settings` / :func:`windows_settings` / :func:`windows_inputs` /
  :func:`final_outputs`: what the ``get_*`` input functions return. Each rule's ``params`` hold
  only its own config section (merged with the entry's overrides) and what it depends on, so
  that Snakemake's params trigger reruns exactly the affected jobs.
* :func:`run_step` / :func:`simulate_step` / :func:`ingest_step` / :func:`recover_step` /
  :func:`interpolate_step` / :func:`validate_step` / :func:`windows_step` / :func:`report_step`:
  what the thin scripts under ``workflow/scripts/`` call.
* :func:`snakemake_command` / :func:`run_workflow`: ``biasgt run`` (Snakemake in a subprocess);
  :func:`resolve_profile`: its ``--profile`` (``workflow/profiles/<name>``, e.g. ``slurm``).

Layout of a workflow run (relative to the working directory)::

    results/<folder>/<sequence>/...  one folder per stage and sequence (:attr:`Stage.folder`:
                                     simulate, ingest, recovery, interpolation, validation, report)
    results/windows/dataset/         the window dataset of the train / val / test sequences
    logs/<folder>/<sequence>.log     the log of that job (logs/windows/dataset.log)
"""

from __future__ import annotations

import copy
import importlib.resources
import enum
import logging
import os
import re
import signal
import socket
import subprocess
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import jsonschema
import yaml
from jsonschema import Draft202012Validator, validators

from interpolation.config import InterpolationConfig
from pipeline.checks import CheckOptions, parse_repairs
from pipeline.configs import dataclass_from_mapping, dataclass_to_mapping, unknown_keys_message
from pipeline.errors import BiasgtError, ConfigError
from pipeline.ingest import READER_KWARGS, ingest
from pipeline.process_group import exclusive_lock, start_group, stop_group
from pipeline.layout import (  # noqa: F401  (the .smk files read these as wf.<name>)
    LOGS_DIR,
    RESULTS_DIR,
    WINDOWS_DATASET,
    Stage,
    interpolated_bias_path,
    log_file,
    report_path,
    stage_dir,
    windows_dataset_dir,
)
from pipeline.sim.config import SimConfig
from pipeline.store import read_store
from pipeline.types import Split
from recovery.config import RecoveryConfig
from training.config import EvaluationConfig, TrainingPlan
from training.windows_config import WindowConfig
from validation.config import ValidationConfig

log = logging.getLogger(__name__)



def _workflow_root() -> Path:
    """The folder holding the Snakefile, ``workflow/`` and ``config/config.yaml``: the copy an
    installed package ships (``pipeline/workflow_files``, see setup.py), else the source checkout
    the package runs from (an editable install or ``PYTHONPATH``)."""
    shipped = importlib.resources.files("pipeline") / "workflow_files"
    if shipped.joinpath("Snakefile").is_file():
        return Path(str(shipped))
    return Path(__file__).resolve().parents[1]


WORKFLOW_ROOT = _workflow_root()
SNAKEFILE = WORKFLOW_ROOT / "Snakefile"
SCHEMA_FILE = WORKFLOW_ROOT / "workflow" / "schemas" / "config.schema.yaml"
DEFAULT_CONFIG = WORKFLOW_ROOT / "config" / "config.yaml"
#: Snakemake profiles shipped with the workflow (``biasgt run --profile NAME``), e.g. ``slurm``.
PROFILES_DIR = WORKFLOW_ROOT / "workflow" / "profiles"

NAME_PATTERN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")

# SimConfig fields set by an entry's shorthand keys; ``overrides`` must not set them again.
_SIM_SHORTHANDS = {
    ("name",): "name",
    ("duration_s",): "duration_s",
    ("seed",): "seed",
    ("motion", "preset"): "preset",
    ("poses", "format"): "pose_format",
}


class SourceKind(str, enum.Enum):
    """Where a sequence's data comes from."""

    SIMULATE = "simulate"  # the built-in simulator writes an ASL folder
    ASL = "asl"  # EuRoC / ASL ``mav0`` folder
    TUM = "tum"  # TUM pose text ("t tx ty tz qx qy qz qw")
    CSV = "csv"  # generic CSV with a column mapping
    BAG = "bag"  # ROS1 .bag, ROS2 bag folder, .db3 or .mcap


#: The ``fmt`` given to :func:`pipeline.io.load_sequence` for each source.
READER_FORMAT: dict[SourceKind, str] = {
    SourceKind.SIMULATE: "asl",  # the simulator writes an ASL folder
    SourceKind.ASL: "asl",
    SourceKind.TUM: "tum",
    SourceKind.CSV: "csv",
    SourceKind.BAG: "rosbag",
}


@dataclass(frozen=True)
class SequenceEntry:
    """One entry of the ``sequences:`` list, checked.

    Attributes:
        name: Sequence name (safe for paths).
        source: Where the data comes from.
        split: Train / test / none.
        index: Position in the ``sequences:`` list (0-based), for error messages.
        path: Resolved input file or folder (real sources), ``None`` for simulated ones.
        raw: The entry as validated (schema defaults filled in).
    """

    name: str
    source: SourceKind
    split: Split
    index: int
    path: Path | None
    raw: dict[str, Any] = field(repr=False, compare=False)

    @property
    def is_simulated(self) -> bool:
        return self.source is SourceKind.SIMULATE

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
        self, *, splits: Iterable[Split | str] | None = None, sources: Iterable[SourceKind | str] | None = None
    ) -> list[SequenceEntry]:
        """Entries whose split and source are among the given ones (``None``: any)."""
        split_set = None if splits is None else {Split(s) for s in splits}
        source_set = None if sources is None else {SourceKind(s) for s in sources}
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


def load_schema(schema_file: str | Path = SCHEMA_FILE) -> dict[str, Any]:
    """The workflow config JSON schema (YAML file) as a dict."""
    return yaml.safe_load(Path(schema_file).read_text(encoding="utf-8"))


def _json_path(parts: Iterable[Any]) -> str:
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "(top level)"


def _schema_keys(schema: Mapping[str, Any]) -> set[str]:
    """Every key a schema object may hold: its ``properties`` and those of its sub-schemas
    (``allOf`` / ``anyOf`` / ``oneOf`` / ``then`` / ``else``), the candidates of a did-you-mean."""
    keys = set(schema.get("properties") or {})
    for sub in [*schema.get("allOf", []), *schema.get("anyOf", []), *schema.get("oneOf", []),
                *(schema[k] for k in ("then", "else") if isinstance(schema.get(k), Mapping))]:
        keys |= _schema_keys(sub)
    return keys


def _schema_error_message(error: Any, data: dict[str, Any]) -> tuple[str, str]:
    """(field, problem) of a jsonschema error, naming the sequence where there is one."""
    where = _json_path(error.absolute_path)
    parts = list(error.absolute_path)
    if len(parts) >= 2 and parts[0] == "sequences" and isinstance(parts[1], int):
        seqs = data.get("sequences") or []
        entry = seqs[parts[1]] if parts[1] < len(seqs) else None
        if isinstance(entry, dict) and "name" in entry:
            where += f" (sequence '{entry['name']}')"
    message = error.message
    if error.validator == "additionalProperties" and isinstance(error.instance, dict):
        allowed = set(error.schema.get("properties") or {})
        unknown = unknown_keys_message(error.instance, allowed)
        if unknown:
            message = f"{unknown}: " + (f"allowed here: {', '.join(sorted(allowed))}" if allowed
                                        else "this section has no options")
    if error.validator == "unevaluatedProperties" and isinstance(error.instance, dict):
        allowed = _schema_keys(error.schema)
        unknown = unknown_keys_message([k for k in error.instance if k not in allowed], allowed)
        if unknown:
            message = f"{unknown}: allowed here: {', '.join(sorted(allowed))}"
    if error.validator == "enum":
        message = f"{error.instance!r} is not one of {', '.join(map(str, error.validator_value))}"
    elif error.validator == "pattern":
        message = (f"{error.instance!r} is not a valid name: use letters, digits, '_', '.', '-' "
                   "and do not start with '.' or '-'")
    return where, message


def validate_schema(
    data: Any, *, config_file: str | Path | None = None, schema_file: str | Path = SCHEMA_FILE
) -> dict[str, Any]:
    """Validate ``data`` against the workflow schema and fill in its defaults, in place.

    Same semantics as ``snakemake.utils.validate(config, schema)`` (draft 2020-12, defaults of
    ``properties`` set before validating), usable without Snakemake.

    Args:
        data: The parsed config.
        config_file: Named in the error message.
        schema_file: The schema.

    Returns:
        ``data`` with defaults filled in.

    Raises:
        ConfigError: The first (most relevant) schema violation, with its location.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"the config must be a mapping, got {type(data).__name__}", path=config_file,
                          hint="see config/config.yaml for an example")
    schema = load_schema(schema_file)
    validate_properties = Draft202012Validator.VALIDATORS["properties"]

    def set_defaults(validator: Any, properties: dict, instance: Any, schema_: dict) -> Iterable[Any]:
        if isinstance(instance, dict):
            for prop, sub in properties.items():
                if "default" in sub:
                    instance.setdefault(prop, copy.deepcopy(sub["default"]))
        yield from validate_properties(validator, properties, instance, schema_)

    validator_cls = validators.extend(Draft202012Validator, {"properties": set_defaults})
    errors = list(validator_cls(schema).iter_errors(data))
    if errors:
        # An unknown key is reported only when nothing else is wrong: with an invalid 'source',
        # for example, the source's own keys also look "unevaluated".
        primary = [e for e in errors if e.validator != "unevaluatedProperties"] or errors
        best = jsonschema.exceptions.best_match(primary)
        where, message = _schema_error_message(best, data)
        raise ConfigError(f"{where}: {message}", path=config_file,
                          hint="see workflow/schemas/config.schema.yaml for the allowed keys and values")
    return data


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


def _deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _sim_dict(entry: dict[str, Any], root: Path, config_file: Path | None, where: str) -> dict[str, Any]:
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
    sim = _deep_merge(base, overrides)
    gt = (sim.get("motion") or {}).get("ground_truth_path")
    if gt is not None:
        sim["motion"]["ground_truth_path"] = str(resolve_input_path(str(gt), root))
    return sim


def check_config(
    data: dict[str, Any], config_file: str | Path | None = None, *, check_paths: bool = True
) -> WorkflowConfig:
    """Check a schema-valid config for what the schema cannot express and build the table.

    Checks: unique sequence names; real sources' paths exist (when ``check_paths``); simulated
    entries make a valid :class:`pipeline.sim.config.SimConfig` (and semi-real ground-truth
    files exist); reader options, repairs and check options are known to the ingest stage.

    Args:
        data: Config already passed through :func:`validate_schema`.
        config_file: The config file; relative paths resolve against its folder.
        check_paths: Check that input paths exist (also switched off by the config's
            ``check_input_paths: false``).

    Returns:
        The checked config.

    Raises:
        ConfigError: Naming the config file, the entry (``sequences[i] ('name')``) and the field.
    """
    config_file = None if config_file is None else Path(config_file)
    check_paths = check_paths and bool(data.get("check_input_paths", True))
    root = data_root(data, config_file)
    seen: dict[str, int] = {}
    entries: list[SequenceEntry] = []
    for i, raw in enumerate(data.get("sequences") or []):
        name = raw["name"]
        where = f"sequences[{i}] ('{name}')"
        if not NAME_PATTERN.match(name):  # also enforced by the schema
            raise ConfigError(f"{where}: invalid sequence name", path=config_file, field="name",
                              hint="use letters, digits, '_', '.', '-'")
        if name in seen:
            raise ConfigError(
                f"{where}: duplicate sequence name '{name}' (also sequences[{seen[name]}])",
                path=config_file, field="name", hint="give every sequence a unique name",
            )
        seen[name] = i
        source = SourceKind(raw["source"])
        path = None
        if source is SourceKind.SIMULATE:
            sim = _sim_dict(raw, root, config_file, where)
            _check_sim_config(sim, config_file, where, check_paths)
        else:
            path = resolve_input_path(raw["path"], root)
            extra = [resolve_input_path(p["path"], root) for p in raw.get("poses") or []]
            for field_name, p in [("path", path)] + [(f"poses[{j}].path", e) for j, e in enumerate(extra)]:
                if check_paths and not p.exists():
                    raise ConfigError(
                        f"{where}: input path {p} does not exist", path=config_file, field=field_name,
                        hint=f"fix '{field_name}' (relative paths are resolved against data_root = {root})",
                    )
        entries.append(SequenceEntry(name, source, Split(raw.get("split", "none")), i, path, raw))
    for section in STAGE_CONFIGS:  # the top-level sections first, so that their errors name them
        try:
            data[section] = resolved_section(section, data.get(section) or {})
        except ConfigError as exc:
            raise ConfigError(f"{section}: {exc.problem}", path=config_file, field=exc.field, hint=exc.hint) from None
    cfg = WorkflowConfig(data, config_file, tuple(entries))
    for entry in cfg.sequences:
        _check_ingest_settings(cfg, entry)
        _check_stage_settings(cfg, entry, check_paths)
    return cfg


def config_warnings(cfg: WorkflowConfig) -> list[str]:
    """What a valid config silently leaves out of the run, said once when ``biasgt run`` checks it.

    Today: windowed sequences (split train / val / test) without all three splits, so that no
    model is trained or evaluated.
    """
    present = {s.split for s in cfg.sequences if s.split.windowed}
    missing = [split.value for split in (Split.TRAIN, Split.VAL, Split.TEST) if split not in present]
    if not present or not missing:
        return []
    return [f"no sequence in split {', '.join(repr(m) for m in missing)}: no model is trained or evaluated "
            "(training needs train and val sequences, Table I test ones); set 'split:' on the sequences that "
            "should form them"]


def _check_sim_config(sim: dict[str, Any], config_file: Path | None, where: str, check_paths: bool) -> None:
    try:
        cfg = SimConfig.from_dict(sim)
    except ConfigError as exc:
        raise ConfigError(f"{where}: simulator setting: {exc.problem}", path=config_file,
                          field=exc.field, hint=exc.hint) from None
    gt = cfg.motion.ground_truth_path
    if check_paths and gt is not None and not Path(gt).is_file():
        raise ConfigError(f"{where}: ground-truth file {gt} does not exist", path=config_file,
                          field="overrides.motion.ground_truth_path",
                          hint="fix the path (relative paths are resolved against data_root)")


def read_config_file(path: str | Path) -> Any:
    """Parse a YAML (or JSON) config file.

    Raises:
        ConfigError: Missing file or invalid YAML.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError("config file not found", path=path,
                          hint="give an existing file with --config (see config/config.yaml)") from None
    except IsADirectoryError:
        raise ConfigError("config path is a folder, not a file", path=path) from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise ConfigError(f"not valid YAML: {getattr(exc, 'problem', exc)}", path=path,
                          line=None if mark is None else mark.line + 1) from None


def load_config(path: str | Path, *, check_paths: bool = True) -> WorkflowConfig:
    """Read, schema-validate (with defaults) and check a workflow config file."""
    path = Path(path)
    data = read_config_file(path)
    validate_schema(data, config_file=path)
    return check_config(data, path, check_paths=check_paths)


# --------------------------------------------------------------------------------------------
# Paths and rule parameters (what the get_* functions in workflow/rules/common.smk return)
# --------------------------------------------------------------------------------------------


def workdir_relative(path: str | Path, workdir: str | Path | None = None) -> str:
    """``path`` relative to ``workdir`` when it lies inside it, else absolute (as a string)."""
    path = Path(path)
    wd = Path(workdir or Path.cwd()).resolve()
    absolute = path if path.is_absolute() else wd / path
    absolute = Path(os.path.normpath(absolute))
    try:
        return absolute.relative_to(wd).as_posix()
    except ValueError:
        return str(absolute)


def names_regex(names: Iterable[str]) -> str:
    """A regex matching exactly the given names (a never-matching one for none)."""
    names = list(names)
    return "|".join(re.escape(n) for n in names) if names else "(?!)"


def simulate_settings(cfg: WorkflowConfig, sequence: str) -> dict[str, Any]:
    """The :class:`pipeline.sim.config.SimConfig` dict of a simulated sequence.

    Raises:
        ConfigError: ``sequence`` is not a simulated sequence.
    """
    entry = cfg.sequence(sequence)
    if not entry.is_simulated:
        raise ConfigError(f"{entry.where} is not simulated (source '{entry.source.value}')",
                          path=cfg.config_file, field="source")
    return _sim_dict(entry.raw, data_root(cfg.data, cfg.config_file), cfg.config_file, entry.where)


def simulate_inputs(cfg: WorkflowConfig, sequence: str, workdir: str | Path | None = None) -> list[str]:
    """Files the simulation reads (the semi-real ground-truth file, if any)."""
    gt = simulate_settings(cfg, sequence)["motion"].get("ground_truth_path")
    return [] if gt is None else [workdir_relative(gt, workdir)]


def ingest_input(cfg: WorkflowConfig, sequence: str, workdir: str | Path | None = None) -> str:
    """What rule ``ingest`` reads: the simulation's ASL folder or the configured input path."""
    entry = cfg.sequence(sequence)
    if entry.is_simulated:
        return stage_dir(Stage.SIMULATE, sequence)
    assert entry.path is not None
    return workdir_relative(entry.path, workdir)


def ingest_extra_inputs(cfg: WorkflowConfig, sequence: str, workdir: str | Path | None = None) -> list[str]:
    """The entry's extra pose inputs (``poses:``), for rule ``ingest``'s dependency tracking."""
    entry = cfg.sequence(sequence)
    root = data_root(cfg.data, cfg.config_file)
    return [workdir_relative(resolve_input_path(p["path"], root), workdir) for p in entry.raw.get("poses") or []]


def ingest_settings(cfg: WorkflowConfig, sequence: str) -> dict[str, Any]:
    """Parameters of rule ``ingest`` for one sequence (the rule's ``params``).

    Returns:
        ``{"reader_kwargs", "repairs", "check_options"}``: keyword arguments of
        :func:`pipeline.io.load_sequence` (``fmt`` from the source, ``asl`` for simulated
        sequences; ``name``; the entry's ``reader`` options), the allowed repairs (the entry's
        list, else ``ingest.repairs``) and the check options (``ingest.check_options`` updated by
        the entry's), all plain JSON-like values.
    """
    entry = cfg.sequence(sequence)
    section = cfg.section("ingest")
    repairs = entry.raw.get("repairs")
    if repairs is None:
        repairs = section.get("repairs") or []
    check_options = _deep_merge(section.get("check_options") or {}, entry.raw.get("check_options") or {})
    reader_kwargs: dict[str, Any] = dict(entry.raw.get("reader") or {})
    reader_kwargs.update(fmt=READER_FORMAT[entry.source], name=entry.name)
    root = data_root(cfg.data, cfg.config_file)
    extra = [dict(p, path=str(resolve_input_path(p["path"], root))) for p in entry.raw.get("poses") or []]
    if extra:
        reader_kwargs["extra_poses"] = extra
    return {
        "reader_kwargs": {k: v for k, v in reader_kwargs.items() if v is not None},
        "repairs": [str(r) for r in repairs],
        "check_options": check_options,
    }


def make_check_options(options: dict[str, Any]) -> Any:
    """A :class:`pipeline.checks.CheckOptions` from a config mapping.

    Raises:
        ConfigError: Unknown key or invalid value.
    """
    kwargs = dict(options)
    if "ignore" in kwargs:
        ignore = kwargs["ignore"]
        kwargs["ignore"] = frozenset([ignore] if isinstance(ignore, str) else ignore or [])
    return dataclass_from_mapping(CheckOptions, kwargs, what="check option", field="check_options")


def _check_ingest_settings(cfg: WorkflowConfig, entry: SequenceEntry) -> None:
    """Raise a ConfigError naming the entry when its ingest settings are invalid."""
    reader = entry.raw.get("reader") or {}
    reserved = sorted({"fmt", "name"} & set(reader))
    if reserved:
        raise ConfigError(f"{entry.where}: reader option(s) {', '.join(reserved)} cannot be set here",
                          path=cfg.config_file, field="reader",
                          hint="'source' sets the format and 'name' the sequence name")
    allowed = [k for k in READER_KWARGS if k not in ("fmt", "name")]
    unknown = unknown_keys_message(reader, allowed)
    if unknown:
        raise ConfigError(f"{entry.where}: reader option: {unknown}", path=cfg.config_file, field="reader",
                          hint="allowed: " + ", ".join(allowed))
    settings = ingest_settings(cfg, entry.name)
    try:
        parse_repairs(settings["repairs"])
        make_check_options(settings["check_options"])
    except ConfigError as exc:
        raise ConfigError(f"{entry.where}: {exc.problem}", path=cfg.config_file, field=exc.field,
                          hint=exc.hint) from None


# --------------------------------------------------------------------------------------------
# Parameters of the later stages (recover, interpolate, validate, windows, report)
# --------------------------------------------------------------------------------------------

#: The config dataclass of each stage section of the workflow config: the one source of the
#: section's options and their defaults (the schema leaves these sections open). check_config
#: checks each section with it (an unknown key is named, with the allowed ones) and fills in every
#: default, so the rules' params hold the whole resolved config. A stage adds its section with one
#: line here (each dataclass module is light: no torch at import).
STAGE_CONFIGS: dict[str, type] = {
    "recovery": RecoveryConfig,
    "interpolation": InterpolationConfig,
    "validation": ValidationConfig,
    "windows": WindowConfig,
    "training": TrainingPlan,
    "evaluation": EvaluationConfig,
}
#: Keys of a stage section that the workflow reads itself (not options of its dataclass), with defaults.
SECTION_EXTRA_KEYS: dict[str, dict[str, Any]] = {
    "recovery": {"pose_stream": None},
    "validation": {"poses": None, "gravity_mps2": None, "bias": {}},
}
#: Sections a sequence entry may override (merged over the top-level section of the same name).
ENTRY_OVERRIDE_SECTIONS = ("recovery", "validation")


def stage_config(section: str, options: Mapping[str, Any]) -> Any:
    """The config dataclass of stage section ``section`` (:data:`STAGE_CONFIGS`) from ``options``;
    the section's extra keys (:data:`SECTION_EXTRA_KEYS`) are left out.

    Raises:
        ConfigError: Unknown key (naming it and the allowed ones) or an invalid value.
    """
    extra = SECTION_EXTRA_KEYS.get(section, {})
    return dataclass_from_mapping(STAGE_CONFIGS[section], {k: v for k, v in options.items() if k not in extra},
                                  what=f"{section} option", field=section, also_allowed=extra)


def resolved_section(section: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` of a stage section, checked, with every default filled in (extra keys first)."""
    extra = SECTION_EXTRA_KEYS.get(section, {})
    return {**{k: options.get(k, default) for k, default in extra.items()},
            **dataclass_to_mapping(stage_config(section, options))}


def _merged_section(cfg: WorkflowConfig, entry: SequenceEntry, section: str) -> dict[str, Any]:
    return _deep_merge(cfg.section(section), entry.raw.get(section) or {})


def recovery_settings(cfg: WorkflowConfig, sequence: str) -> dict[str, Any]:
    """Parameters of rule ``recover`` for one sequence (the rule's ``params``).

    Returns:
        ``{"pose_stream": str | None, "config": {RecoveryConfig option: value}}``: the top-level
        ``recovery:`` section updated by the entry's own ``recovery:`` mapping (``pose_stream``:
        the pose stream to fit, ``None`` = :func:`pipeline.io.select_pose_stream`'s default,
        ``"ground_truth"`` = the ground-truth state as poses).
    """
    merged = _merged_section(cfg, cfg.sequence(sequence), "recovery")
    pose_stream = merged.pop("pose_stream", None)
    return {"pose_stream": pose_stream, "config": merged}


def interpolation_settings(cfg: WorkflowConfig, sequence: str) -> dict[str, Any]:
    """Parameters of rule ``interpolate``: ``{"method": "linear"|"cubic", "clamp": bool, "write_csv": bool}``."""
    cfg.sequence(sequence)  # a known sequence
    return resolved_section("interpolation", cfg.section("interpolation"))


def interpolation_outputs(cfg: WorkflowConfig) -> list[str]:
    """Output patterns of rule ``interpolate`` (``{sequence}`` left in): the Parquet table and,
    with ``interpolation.write_csv``, its CSV twin."""
    parquet = interpolated_bias_path("{sequence}")
    write_csv = stage_config("interpolation", cfg.section("interpolation")).write_csv
    return [parquet] + ([parquet[: -len(".parquet")] + ".csv"] if write_csv else [])


def validation_settings(cfg: WorkflowConfig, sequence: str) -> dict[str, Any]:
    """Parameters of rule ``validate`` for one sequence.

    Returns:
        ``{"poses": str | None, "gravity_mps2": [3] | None, "bias": [[name, path], ...], "config":
        {ValidationConfig option: value}}``: the top-level ``validation:`` section updated by the
        entry's ``validation:`` mapping. ``poses``: the reference pose stream (``None``: the
        ground-truth state, else the recovery's stream); ``gravity_mps2``: ``None`` = the recovery's
        estimate; ``bias``: other bias estimates of the sequence (``{name: file}``, files relative to
        ``data_root``), integrated against the same reference next to the recovered bias (sources of
        kind FILE: compared, not judged).
    """
    merged = _merged_section(cfg, cfg.sequence(sequence), "validation")
    poses = merged.pop("poses", None)
    gravity = merged.pop("gravity_mps2", None)
    return {"poses": poses, "gravity_mps2": gravity, "bias": _validation_bias_files(cfg, merged.pop("bias", None)),
            "config": merged}


def _validation_bias_files(cfg: WorkflowConfig, bias: Any) -> list[list[str]]:
    """``validation.bias`` (``{name: file}``) as ``[[name, absolute path], ...]``."""
    if bias is None:
        return []
    if not isinstance(bias, Mapping) or not all(isinstance(k, str) and isinstance(v, str) for k, v in bias.items()):
        raise ConfigError(f"validation.bias must map source names to bias files, got {bias!r}", path=cfg.config_file,
                          field="validation.bias",
                          hint="e.g. bias: {openvins: euroc/V1_01_easy/ov_data/V1_01_easy.csv}")
    root = data_root(cfg.data, cfg.config_file)
    return [[name, str(resolve_input_path(path, root))] for name, path in bias.items()]


def validation_bias_inputs(cfg: WorkflowConfig, sequence: str, workdir: str | Path | None = None) -> list[str]:
    """The entry's ``validation.bias`` files, for rule ``validate``'s dependency tracking."""
    return [workdir_relative(Path(path), workdir) for _, path in validation_settings(cfg, sequence)["bias"]]


def windowed_sequences(cfg: WorkflowConfig) -> list[SequenceEntry]:
    """The sequences whose windows form the dataset: split train, val or test, in config order."""
    return [s for s in cfg.sequences if s.split.windowed]


def windows_inputs(cfg: WorkflowConfig) -> dict[str, list[str]]:
    """Inputs of rule ``windows``: ``{"stores", "recoveries", "validations"}`` of :func:`windowed_sequences`
    (the validation verdicts decide which sequences enter the dataset)."""
    entries = windowed_sequences(cfg)
    return {"stores": [stage_dir(Stage.INGEST, s.name) for s in entries],
            "recoveries": [stage_dir(Stage.RECOVER, s.name) for s in entries],
            "validations": [stage_dir(Stage.VALIDATE, s.name) for s in entries]}


def windows_settings(cfg: WorkflowConfig) -> dict[str, Any]:
    """Parameters of rule ``windows``: ``{"sequences": [[name, split, reference pose stream], ...],
    "config": windows section}``; the reference is the validation's (``validation.poses``)."""
    return {"sequences": [[s.name, s.split.value, validation_settings(cfg, s.name)["poses"]]
                          for s in windowed_sequences(cfg)],
            "config": cfg.section("windows")}


def window_outputs(cfg: WorkflowConfig) -> list[str]:
    """Target of rule ``all`` for the windows stage: the dataset folder, or nothing when no
    sequence is in split ``train`` (the normalisation statistics come from the train split;
    val / test sequences alone make no dataset)."""
    if not any(s.split is Split.TRAIN for s in cfg.sequences):
        if windowed_sequences(cfg):
            log.warning("no sequence in split 'train': the window dataset is not built")
        return []
    return [windows_dataset_dir()]


def _check_stage_settings(cfg: WorkflowConfig, entry: SequenceEntry, check_paths: bool = True) -> None:
    """Raise a ConfigError naming the entry when its stage overrides (merged over the sections) are invalid."""
    for section in ENTRY_OVERRIDE_SECTIONS:
        try:
            resolved_section(section, _merged_section(cfg, entry, section))
        except ConfigError as exc:
            raise ConfigError(f"{entry.where}: {exc.problem}", path=cfg.config_file, field=exc.field,
                              hint=exc.hint) from None
    try:
        files = validation_settings(cfg, entry.name)["bias"]
    except ConfigError as exc:
        raise ConfigError(f"{entry.where}: {exc.problem}", path=cfg.config_file, field=exc.field,
                          hint=exc.hint) from None
    for name, path in files:
        if check_paths and not Path(path).is_file():
            raise ConfigError(f"{entry.where}: bias file {path} does not exist", path=cfg.config_file,
                              field=f"validation.bias.{name}",
                              hint="fix the path (relative paths are resolved against data_root)")


@dataclass(frozen=True)
class FinalOutput:
    """One kind of target of ``rule all``, registered by a stage's ``.smk`` file.

    Attributes:
        stage: The stage it belongs to (for listing).
        pattern: A path pattern, expanded over sequences if it holds ``{sequence}``; or a
            function ``(WorkflowConfig) -> list[str]`` for anything else.
        splits: Only sequences with these splits (``None``: all).
        sources: Only sequences from these sources (``None``: all).
    """

    stage: str
    pattern: str | Callable[[WorkflowConfig], list[str]]
    splits: tuple[Split, ...] | None = None
    sources: tuple[SourceKind, ...] | None = None

    def paths(self, cfg: WorkflowConfig) -> list[str]:
        if callable(self.pattern):
            return [str(p) for p in self.pattern(cfg)]
        if "{sequence}" not in self.pattern:
            return [self.pattern]
        return [self.pattern.format(sequence=s.name) for s in cfg.select(splits=self.splits, sources=self.sources)]


def final_outputs(registry: Iterable[FinalOutput], cfg: WorkflowConfig) -> list[str]:
    """All targets of ``rule all``: every registered output, in registration order, once each."""
    out: list[str] = []
    seen: set[str] = set()
    for item in registry:
        for p in item.paths(cfg):
            if p not in seen:
                seen.add(p)
                out.append(p)
    return out


# --------------------------------------------------------------------------------------------
# Steps (called by the thin scripts under workflow/scripts/)
# --------------------------------------------------------------------------------------------


def run_step(log_path: str | Path, func: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """Run one workflow job with the ``pipeline`` loggers writing to ``log_path``.

    A known error (:class:`BiasgtError`) is logged on one line and ends the process with the
    error's exit code (no traceback), Ctrl-C with 130; any other exception is logged with its traceback and
    re-raised.
    """
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(log_path, mode="w", encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    old_level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    slurm_job = os.environ.get("SLURM_JOB_ID")  # set inside a SLURM job (docs/cluster.md)
    log.info("job on host %s%s", socket.gethostname(), f", SLURM job {slurm_job}" if slurm_job else "")
    try:
        return func(*args, **kwargs)
    except BiasgtError as exc:
        log.error("%s", exc)
        print(f"biasgt: error: {exc}", file=sys.stderr)
        raise SystemExit(exc.exit_code) from None
    except KeyboardInterrupt:  # 'biasgt run' forwards Ctrl-C to Snakemake's process group, jobs included
        log.error("interrupted (SIGINT); nothing half-written was left")
        raise SystemExit(130) from None
    except Exception:
        log.exception("unexpected error (a bug in biasgt; please report it with this log)")
        raise
    finally:
        root.removeHandler(handler)
        root.setLevel(old_level)
        handler.close()


def simulate_step(settings: dict[str, Any], out_dir: str | Path) -> Path:
    """Simulate one sequence from a :class:`SimConfig` dict and write it as an ASL folder."""
    from pipeline.sim.simulator import simulate  # scipy.signal: only in the job that runs the step
    from pipeline.sim.writer import write_simulation  # rosbags: only in the job that runs the step

    config = SimConfig.from_dict(dict(settings))
    log.info("simulating '%s': %.1f s, preset %s, poses %s, seed %d", config.name, config.duration_s or -1,
             config.motion.preset.value, config.poses.format.value, config.seed)
    simulation = simulate(config)
    out = Path(out_dir)
    write_simulation(simulation, out)
    log.info("wrote %s", out)
    return out


def ingest_step(input_path: str | Path, out_dir: str | Path, settings: dict[str, Any]) -> Path:
    """Read, check (and, where allowed, repair) one input and write the canonical store."""
    reader_kwargs = dict(settings.get("reader_kwargs") or {})
    log.info("ingesting %s (format %s) -> %s", input_path, reader_kwargs.get("fmt", "auto"), out_dir)
    ingest(
        input_path, out_dir,
        repairs=list(settings.get("repairs") or []),
        reader_kwargs=reader_kwargs,
        check_options=make_check_options(dict(settings.get("check_options") or {})),
    )
    log.info("wrote %s", out_dir)
    return Path(out_dir)


def recover_step(store_dir: str | Path, out_dir: str | Path, settings: dict[str, Any]) -> Path:
    """Recover the bias of one canonical store and write ``bias.csv``, ``recovery.json``,
    ``trajectory_tum.txt`` (settings: :func:`recovery_settings`)."""
    from recovery.recover import recover, write_recovery  # gtsam: only in the job that runs the step

    config = stage_config("recovery", settings.get("config") or {})
    sequence = read_store(store_dir)
    log.info("recovering the bias of '%s' from pose stream %s", sequence.name,
             settings.get("pose_stream") or "(default)")
    result = recover(sequence, pose_stream=settings.get("pose_stream"), config=config)
    write_recovery(result, out_dir)
    report = result.report
    log.info("wrote %s: %s keyframes over %.1f s from '%s'", out_dir, report.get("keyframes"),
             float(report.get("duration_s") or 0.0), report.get("pose_stream"))
    for warning in result.warnings:
        log.warning("%s", warning)
    return Path(out_dir)


def interpolate_step(recovery_dir: str | Path, store_dir: str | Path, out_path: str | Path,
                     settings: dict[str, Any]) -> list[Path]:
    """Interpolate a recovery's keyframe bias to the store's IMU stamps (settings:
    :func:`interpolation_settings`)."""
    from interpolation.interpolate import interpolate_recovery  # pandas: only in the job that runs the step

    config = stage_config("interpolation", settings)
    written = interpolate_recovery(recovery_dir, store_dir, out_path, config)
    log.info("wrote %s", ", ".join(map(str, written)))
    return written


def validate_step(store_dir: str | Path, recovery_dir: str | Path, out_dir: str | Path,
                  settings: dict[str, Any]) -> Any:
    """Validate one sequence's recovered bias by 1-s integration error and write
    ``validation.json`` + ``windows.parquet`` (settings: :func:`validation_settings`).

    A FAIL verdict is a result (written, logged as a warning, returned); only bad inputs raise.

    Returns:
        The :class:`validation.validate.ValidationResult`.
    """
    from validation.validate import Verdict, validate_inputs, write_validation  # torch: only in this step's job

    config = stage_config("validation", settings.get("config") or {})
    sequence = read_store(store_dir)
    result = validate_inputs(sequence, recovery_dir=recovery_dir, pose_stream=settings.get("poses"),
                             bias_files=[(name, path) for name, path in settings.get("bias") or []],
                             gravity_mps2=settings.get("gravity_mps2"), config=config)
    write_validation(result, out_dir)
    level = logging.WARNING if result.verdict is Verdict.FAIL else logging.INFO
    log.log(level, "verdict %s for '%s'%s", result.verdict.value, result.sequence,
            "".join(f"; {r}" for r in result.reasons))
    log.info("wrote %s", out_dir)
    return result


def windows_step(stores: Sequence[str | Path], recoveries: Sequence[str | Path], validations: Sequence[str | Path],
                 out_dir: str | Path, settings: dict[str, Any]) -> Path:
    """Cut the window dataset of the train / val / test sequences whose validation verdict allows it.

    Args:
        stores / recoveries / validations: Each sequence's canonical store, recovery and validation
            folder, in the order of ``settings["sequences"]`` (:func:`windows_inputs`).
        out_dir: The dataset folder.
        settings: :func:`windows_settings`.
    """
    from training.windows import WindowSource, build_window_dataset  # torch: only in the job of this step

    named = list(settings.get("sequences") or [])
    if not (len(named) == len(stores) == len(recoveries) == len(validations)):
        raise ConfigError(f"windows: {len(named)} sequences but {len(stores)} stores, {len(recoveries)} recoveries "
                          f"and {len(validations)} validations", field="windows",
                          hint="a bug in the workflow wiring; please report it")
    sources = [WindowSource(name, split, str(store), str(rec), str(val), *reference)
               for (name, split, *reference), store, rec, val in zip(named, stores, recoveries, validations)]
    config = stage_config("windows", settings.get("config") or {})
    log.info("cutting windows of %d sequence(s): %s", len(sources),
             ", ".join(f"{s.name} ({s.split})" for s in sources))
    build_window_dataset(sources, out_dir, config)
    log.info("wrote %s", out_dir)
    return Path(out_dir)


def report_step(ingest_dir: str | Path, recovery_dir: str | Path | None, validation_dir: str | Path | None,
                out_path: str | Path) -> Path:
    """Write the quality report (one self-contained HTML file) of one sequence."""
    from reports.quality import build_quality_report  # matplotlib: only in the job that runs the step

    return build_quality_report(ingest_dir, recovery_dir=recovery_dir, validation_dir=validation_dir,
                                out_path=out_path)


# --------------------------------------------------------------------------------------------
# biasgt run: Snakemake in a subprocess
# --------------------------------------------------------------------------------------------


class WorkflowRunError(BiasgtError):
    """Snakemake failed; the message names the failed rule and its log."""


def snakemake_command(
    *,
    config_file: str | Path,
    cores: int | str = 1,
    workdir: str | Path | None = None,
    dry_run: bool = False,
    until: Sequence[str] = (),
    targets: Sequence[str] = (),
    extra: Sequence[str] = (),
    snakefile: str | Path = SNAKEFILE,
    python: str = sys.executable,
) -> list[str]:
    """The Snakemake command line ``biasgt run`` executes."""
    cmd = [
        python, "-m", "snakemake",
        "--snakefile", str(Path(snakefile).resolve()),
        "--directory", str(Path(workdir or Path.cwd()).resolve()),
        "--configfile", str(Path(config_file).resolve()),
        "--replace-workflow-config",
        "--cores", str(cores),
        "--rerun-incomplete",
        "--show-failed-logs",
    ]
    if dry_run:
        cmd.append("--dry-run")
    if until:
        cmd += ["--until", *until]
    cmd += list(extra)
    cmd += list(targets)
    return cmd


def resolve_profile(profile: str | Path) -> Path:
    """The folder of a Snakemake profile: a name under :data:`PROFILES_DIR` (``slurm``) or a path.

    Raises:
        ConfigError: Neither names a folder holding a ``config.yaml``.
    """
    for candidate in (PROFILES_DIR / str(profile), Path(profile)):
        if (candidate / "config.yaml").is_file():
            return candidate.resolve()
    shipped = sorted(p.parent.name for p in PROFILES_DIR.glob("*/config.yaml"))
    raise ConfigError(f"no Snakemake profile '{profile}'", field="--profile",
                      hint=f"use one of {', '.join(shipped) or '(none)'} or a folder holding config.yaml")


_JOB_HEADER = re.compile(r"^\s*(?:local)?(?:checkpoint|rule) ([A-Za-z0-9_]+):\s*$")


def parse_dry_run_jobs(text: str) -> list[tuple[str, dict[str, str]]]:
    """The jobs of a Snakemake dry-run printout, as ``(rule, wildcards)`` in printed order.

    Args:
        text: What ``snakemake --dry-run`` printed (stdout and stderr together).
    """
    jobs: list[tuple[str, dict[str, str]]] = []
    for line in text.splitlines():
        m = _JOB_HEADER.match(line)
        if m:
            jobs.append((m.group(1), {}))
            continue
        w = _WILDCARDS_LINE.match(line)
        if w and jobs and not jobs[-1][1]:
            for item in w.group(1).split(", "):
                key, _, value = item.partition("=")
                jobs[-1][1][key.strip()] = value.strip()
    return jobs


#: The SLURM executor plugin's line when sbatch refuses a submission (its error text in quotes).
_SBATCH_REFUSAL = re.compile(r"SLURM sbatch failed.*?The error message was '(.*?)'\.?\s*$")
_ERROR_IN_RULE = re.compile(r"^\s*Error in rule ([A-Za-z0-9_]+):")
_LOG_LINE = re.compile(r"^\s*log:\s*(\S+)")
_WILDCARDS_LINE = re.compile(r"^\s*wildcards:\s*(.+)$")
_JOBID_LINE = re.compile(r"^\s*jobid:\s*(\d+)\s*$")
_NOISE = re.compile(r"^\s*(Shutting down|Complete log|Exiting because|Removing output|Will exit after|"
                    r"Select jobs|\[.*\]$|$)")


def describe_failure(lines: Sequence[str], workdir: str | Path) -> str:
    """One line saying why Snakemake failed, from the tail of its output.

    Names the failed rule, its wildcards and log file, and the last line of that log when it
    exists; otherwise the last informative line Snakemake printed. A failed group job (several
    rules in one cluster job) lists every rule of the group as failed: the one named is the first
    whose log holds an error.
    """
    refused = next((m.group(1) for ln in lines if (m := _SBATCH_REFUSAL.search(ln))), None)
    if refused is not None:  # the job never ran (its logs are empty): SLURM's own reason is the story
        failed = _failed_jobs(lines)
        where = f"rule '{failed[0][0]}'" if failed else "a job"
        return (f"SLURM refused to queue {where}: {refused} (ask for fewer resources, e.g. a CPU-only cluster: "
                "--profile slurm-cpu)")
    failed = _failed_jobs(lines)
    if not failed:
        informative = [ln.strip() for ln in lines if not _NOISE.match(ln)]
        return informative[-1] if informative else "snakemake failed without a message"
    logs = {log_rel: Path(workdir) / log_rel for _, _, log_rel in failed if log_rel}
    rule, wildcards, log_rel = next((job for job in failed if job[2] and _logged_error(logs[job[2]])), failed[0])
    text = f"rule '{rule}'" + (f" ({wildcards})" if wildcards else "") + " failed"
    if log_rel:
        last = _last_line(logs[log_rel])
        if last:
            text += f": {last}"
        text += f" (log: {logs[log_rel]})"
    return text


def _failed_jobs(lines: Sequence[str]) -> list[tuple[str, str | None, str | None]]:
    """(rule, wildcards, log path as printed) of each 'Error in rule' block of Snakemake's output."""
    # Snakemake's error block names the job id; its wildcards are in the job's announcement.
    wildcards_of_job: dict[str, str] = {}
    current_job: str | None = None
    for line in lines:
        if (j := _JOBID_LINE.match(line)):
            current_job = j.group(1)
        elif (w := _WILDCARDS_LINE.match(line)) and current_job is not None:
            wildcards_of_job.setdefault(current_job, w.group(1).strip())
        elif _JOB_HEADER.match(line) or _ERROR_IN_RULE.match(line):
            current_job = None
    failed = []
    for i, line in enumerate(lines):
        m = _ERROR_IN_RULE.match(line)
        if not m:
            continue
        wildcards, log_rel = None, None
        for follow in lines[i + 1:i + 20]:
            if _ERROR_IN_RULE.match(follow):
                break
            if (w := _WILDCARDS_LINE.match(follow)) and wildcards is None:
                wildcards = w.group(1).strip()
            if (j := _JOBID_LINE.match(follow)) and wildcards is None:
                wildcards = wildcards_of_job.get(j.group(1))
            if (lg := _LOG_LINE.match(follow)) and log_rel is None:
                log_rel = lg.group(1).rstrip(",")  # executor plugins append their own logs
        failed.append((m.group(1), wildcards, log_rel))
    return failed


def _logged_error(path: Path) -> bool:
    """Whether a job's log holds an ERROR line (the job that failed, not one that never ran)."""
    try:
        return any(" ERROR " in ln for ln in path.read_text(encoding="utf-8", errors="replace").splitlines())
    except OSError:
        return False


def _last_line(path: Path) -> str | None:
    try:
        lines = [ln.strip() for ln in path.read_text(encoding="utf-8", errors="replace").splitlines() if ln.strip()]
    except OSError:
        return None
    if not lines:
        return None
    # Prefer the logged error line over a traceback's last frame.
    for ln in reversed(lines):
        if " ERROR " in ln:
            return ln.split(": ", 1)[-1] if ": " in ln else ln
    return lines[-1]


@dataclass(frozen=True)
class RunResult:
    """Outcome of :func:`run_workflow`.

    Attributes:
        workdir: The working directory (outputs are under ``workdir/results``).
        command: The Snakemake command that ran.
        outputs: Result folders and report files found after the run.
    """

    workdir: Path
    command: list[str]
    outputs: list[Path]


def output_locations(workdir: str | Path) -> list[Path]:
    """The stage folders under ``results/`` and any HTML reports, sorted."""
    results = Path(workdir) / RESULTS_DIR
    if not results.is_dir():
        return []
    out = sorted(p for p in results.iterdir() if p.is_dir() and not p.name.startswith("."))
    out += sorted(p for p in results.rglob("*.html") if not any(part.startswith(".") for part in p.parts))
    return out


#: Held (flock) by a running ``biasgt run`` in its working directory: a second one says so.
RUN_LOCK = Path(".snakemake") / "biasgt-run.lock"


def _run_snakemake(cmd: list[str], echo: IO[str], *, keep_all: bool, workdir: Path,
                   progress_interval_s: float) -> tuple[int, list[str]]:
    """Run Snakemake in its own process group, copying its output to ``echo`` with one line per running
    job every ``progress_interval_s`` (:mod:`pipeline.job_progress`).

    On Ctrl-C (KeyboardInterrupt), SIGTERM (the CLI's ``Terminated``) or any other exception,
    Snakemake gets SIGINT and its jobs SIGTERM; Snakemake cancels its jobs and removes their
    incomplete outputs, and only then does the exception go on
    (:func:`pipeline.process_group.stop_group`).

    Returns:
        Snakemake's exit status and the tail of its output (all of it with ``keep_all``).
    """
    from pipeline.job_progress import JobProgress

    log.info("running %s", " ".join(cmd))
    tail: list[str] = []
    proc = start_group(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
                       errors="replace")
    try:
        assert proc.stdout is not None
        with JobProgress(workdir, echo, interval_s=progress_interval_s) as jobs:
            for line in proc.stdout:
                jobs.write(line)
                tail.append(line.rstrip("\n"))
                if len(tail) > 4000 and not keep_all:  # a dry run's plan is kept whole for the caller
                    del tail[:1000]
        return proc.wait(), tail
    except BaseException:
        # Snakemake gets SIGINT for SIGTERM too (it ignores SIGTERM while SLURM jobs run; on SIGINT it
        # cancels them), its local jobs SIGTERM (a Python job stopped by SIGINT would print a
        # KeyboardInterrupt traceback from wherever it was, an import say)
        log.warning("stopping Snakemake: it cancels its jobs and removes their incomplete outputs")
        stop_group(proc, signal.SIGINT, signal.SIGTERM, echo=echo.write)
        raise
    finally:
        if proc.stdout is not None:
            proc.stdout.close()


def run_workflow(
    *,
    config_file: str | Path | None = None,
    cores: int | str = 1,
    workdir: str | Path | None = None,
    dry_run: bool = False,
    until: Sequence[str] = (),
    targets: Sequence[str] = (),
    extra: Sequence[str] = (),
    echo: IO[str] | None = None,
    progress_interval_s: float = 30.0,
) -> RunResult:
    """Check the config, then run the workflow with Snakemake in a subprocess.

    Snakemake's own output (stdout and stderr) is copied to ``echo`` (default ``sys.stderr``) as it
    comes, so that the caller's stdout holds only its result; every ``progress_interval_s`` one line
    per running job (its log's last line: :mod:`pipeline.job_progress`) goes there too.

    Args:
        config_file: Workflow config (default: the repository's ``config/config.yaml``).
        cores: Cores Snakemake may use (an int or ``"all"``).
        workdir: Working directory holding ``results/`` and ``logs/`` (default: current folder).
        dry_run: Only show what would run.
        until: Run only up to these rules or files.
        targets: Files or rules to build instead of ``rule all``.
        extra: Further Snakemake arguments, passed unchanged (e.g. ``--executor slurm``).
        echo: Where Snakemake's output is copied to.

    Returns:
        The run's working directory, command and outputs.

    Raises:
        ConfigError: The config is invalid (checked before Snakemake starts).
        WorkflowRunError: Snakemake failed; the message names the failed rule and its log.
    """
    config_file = Path(config_file or DEFAULT_CONFIG)
    workdir = Path(workdir or Path.cwd()).resolve()
    for warning in config_warnings(load_config(config_file)):  # fail early, on one line, for a bad config
        log.warning("%s: %s", config_file, warning)
    cmd = snakemake_command(config_file=config_file, cores=cores, workdir=workdir, dry_run=dry_run,
                            until=until, targets=targets, extra=extra)
    workdir.mkdir(parents=True, exist_ok=True)
    echo = echo or sys.stderr
    with exclusive_lock(workdir / RUN_LOCK) as holder:
        if holder is not None and not dry_run:
            raise WorkflowRunError(
                f"another 'biasgt run' (pid {holder or 'unknown'}) is running in {workdir}",
                hint=f"wait for it to finish, or stop it (kill -INT {holder or 'PID'}) and rerun; its outputs are "
                     "locked while it runs")
        rc, tail = _run_snakemake(cmd, echo, keep_all=dry_run, workdir=workdir, progress_interval_s=progress_interval_s)
    if rc != 0:
        raise WorkflowRunError(
            f"workflow failed (snakemake exit {rc}): {describe_failure(tail, workdir)}",
            hint="fix the cause and rerun 'biasgt run' (finished jobs are kept)",
        )
    return RunResult(workdir, cmd, [] if dry_run else output_locations(workdir))
