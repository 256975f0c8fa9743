"""Rule parameters: what the ``get_*`` input functions in ``workflow/rules/common.smk`` return.

Each rule's ``params`` hold only its own config section (merged with the entry's overrides) and
what it depends on, so that Snakemake's params trigger reruns exactly the affected jobs. The
``.smk`` files read this module as ``wf`` (the path helpers of :mod:`pipeline.layout` included).
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from interpolation.config import InterpolationConfig
from pipeline.checks.options import CheckOptions
from pipeline.checks.repairs import parse_repairs
from pipeline.configs import dataclass_from_mapping, dataclass_to_mapping, unknown_keys_message
from pipeline.errors import ConfigError
from pipeline.ingest import READER_KWARGS
from pipeline.layout import (  # noqa: F401  (the .smk files read these as wf.<name>)
    LOGS_DIR,
    RESULTS_DIR,
    WINDOWS_DATASET,
    Stage,
    dataset_report_path,
    interpolated_bias_path,
    log_file,
    report_path,
    stage_dir,
    windows_dataset_dir,
)
from pipeline.types import Split
from biasgt.workflow.table import (  # noqa: F401  (source_kind: the .smk files read it as wf.source_kind)
    SequenceEntry,
    WorkflowConfig,
    deep_merge,
    sim_dict,
    data_root,
    reader_format,
    resolve_input_path,
    source_kind,
)
from recovery.config import RecoveryConfig
from training.config import EvaluationConfig, TrainingPlan
from training.data.windows_config import WindowConfig
from validation.config import ValidationConfig

log = logging.getLogger(__package__)  # job logs name the workflow glue as one: 'biasgt.workflow'


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
        raise ConfigError(f"{entry.where} is not simulated (source '{entry.source}')",
                          path=cfg.config_file, field="source")
    return sim_dict(entry.raw, data_root(cfg.data, cfg.config_file), cfg.config_file, entry.where)


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
        :func:`pipeline.io.load_sequence` (``fmt`` from the source, the simulator's reader for simulated
        sequences; ``name``; the entry's ``reader`` options), the allowed repairs (the entry's
        list, else ``ingest.repairs``) and the check options (``ingest.check_options`` updated by
        the entry's), all plain JSON-like values.
    """
    entry = cfg.sequence(sequence)
    section = cfg.section("ingest")
    repairs = entry.raw.get("repairs")
    if repairs is None:
        repairs = section.get("repairs") or []
    check_options = deep_merge(section.get("check_options") or {}, entry.raw.get("check_options") or {})
    reader_kwargs: dict[str, Any] = dict(entry.raw.get("reader") or {})
    reader_kwargs.update(fmt=reader_format(entry.source), name=entry.name)
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
    """A :class:`pipeline.checks.options.CheckOptions` from a config mapping.

    Raises:
        ConfigError: Unknown key or invalid value.
    """
    kwargs = dict(options)
    if "ignore" in kwargs:
        ignore = kwargs["ignore"]
        kwargs["ignore"] = frozenset([ignore] if isinstance(ignore, str) else ignore or [])
    return dataclass_from_mapping(CheckOptions, kwargs, what="check option", field="check_options")


def check_ingest_settings(cfg: WorkflowConfig, entry: SequenceEntry) -> None:
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
    return deep_merge(cfg.section(section), entry.raw.get(section) or {})


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


def check_stage_settings(cfg: WorkflowConfig, entry: SequenceEntry, check_paths: bool = True) -> None:
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
        sources: Only sequences from these sources (:func:`~biasgt.workflow.table.source_kinds`; ``None``: all).
    """

    stage: str
    pattern: str | Callable[[WorkflowConfig], list[str]]
    splits: tuple[Split, ...] | None = None
    sources: tuple[str, ...] | None = None

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


def dataset_report_inputs(cfg: WorkflowConfig) -> dict[str, list[str]]:
    """Inputs of rule ``dataset_report``: every sequence's ``recoveries``, ``validations`` and
    ``reports`` (the page links them), and the window dataset when one is built (``windows``)."""
    return {"recoveries": [stage_dir(Stage.RECOVER, n) for n in cfg.names],
            "validations": [stage_dir(Stage.VALIDATE, n) for n in cfg.names],
            "reports": [report_path(n) for n in cfg.names],
            "windows": window_outputs(cfg)}


def dataset_report_settings(cfg: WorkflowConfig) -> dict[str, Any]:
    """Parameters of rule ``dataset_report``: ``{"sequences": [[name, split], ...]}`` in config order."""
    return {"sequences": [[s.name, Split(s.split).value] for s in cfg.sequences]}
