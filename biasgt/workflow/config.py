"""Reading a workflow config: :func:`load_config` / :func:`validate_schema` / :func:`check_config`.

Apply the JSON schema (``workflow/schemas/config.schema.yaml``, with its defaults, exactly as
``snakemake.utils.validate`` does) and check what a schema cannot say (each entry's source and
pose format among the registered readers, unique names, existing input paths, simulator
settings, the stage sections). Errors are
:class:`~pipeline.errors.ConfigError` naming the config file and the sequence entry. Also where
the workflow's files are (:data:`SNAKEFILE`, :data:`SCHEMA_FILE`, :data:`DEFAULT_CONFIG`,
:data:`PROFILES_DIR`).
"""

from __future__ import annotations

import copy
import difflib
import importlib.resources
import re
from collections.abc import Collection, Iterable, Mapping
from pathlib import Path
from typing import Any

import jsonschema
import yaml
from jsonschema import Draft202012Validator, validators

from pipeline.configs import unknown_keys_message
from pipeline.errors import ConfigError
from pipeline.sim.config import SimConfig
from pipeline.types import Split
from biasgt.workflow.params import STAGE_CONFIGS, check_ingest_settings, check_stage_settings, resolved_section
from biasgt.workflow.table import (
    SIMULATE,
    SequenceEntry,
    WorkflowConfig,
    sim_dict,
    data_root,
    resolve_input_path,
    source_kind,
    source_kinds,
)
from pipeline.io.registry import names as reader_names


def _workflow_root() -> Path:
    """The folder holding the Snakefile, ``workflow/`` and ``config/config.yaml``: the copy an
    installed package ships (``biasgt/workflow_files``, see setup.py), else the source checkout
    the package runs from (an editable install or ``PYTHONPATH``)."""
    shipped = importlib.resources.files("biasgt") / "workflow_files"
    if shipped.joinpath("Snakefile").is_file():
        return Path(str(shipped))
    return Path(__file__).resolve().parents[2]


WORKFLOW_ROOT = _workflow_root()
SNAKEFILE = WORKFLOW_ROOT / "Snakefile"
SCHEMA_FILE = WORKFLOW_ROOT / "workflow" / "schemas" / "config.schema.yaml"
DEFAULT_CONFIG = WORKFLOW_ROOT / "config" / "config.yaml"
#: Snakemake profiles shipped with the workflow (``biasgt run --profile NAME``), e.g. ``slurm``.
PROFILES_DIR = WORKFLOW_ROOT / "workflow" / "profiles"

NAME_PATTERN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


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
        close = difflib.get_close_matches(str(error.instance), [str(v) for v in error.validator_value], n=1)
        if close:
            message += f" (did you mean '{close[0]}'?)"
    elif error.validator == "pattern":
        message = (f"{error.instance!r} is not a valid name: use letters, digits, '_', '.', '-' "
                   "and do not start with '.' or '-'")
    return where, message


def reader_name_errors(data: dict[str, Any], config_file: str | Path | None) -> list[ConfigError]:
    """What the schema leaves to the reader registry: each entry's ``source`` is one of
    :func:`~biasgt.workflow.table.source_kinds` and each ``poses[j].fmt`` a reader's name
    (:func:`pipeline.io.registry.names`); other types are left to the schema.

    Returns:
        One error per wrong field: ``sequences[i].source (sequence 'name'): 'x' is not one of ...``.
    """
    errors: list[ConfigError] = []
    sequences = data.get("sequences")
    for i, entry in enumerate(sequences if isinstance(sequences, list) else []):
        if not isinstance(entry, dict):
            continue
        label = f" (sequence '{entry['name']}')" if "name" in entry else ""
        fields = [(f"sequences[{i}].source", entry.get("source"), source_kinds(), "source",
                   "'simulate' or an input format (biasgt inspect --help lists them under --format)")]
        poses = entry.get("poses")
        for j, pose in enumerate(poses if isinstance(poses, list) else []):
            if isinstance(pose, dict):
                fields.append((f"sequences[{i}].poses[{j}].fmt", pose.get("fmt"), reader_names(), "fmt",
                               "an input format (biasgt inspect --help lists them under --format), or leave it out"))
        for where, value, allowed, field, hint in fields:
            if isinstance(value, str) and value not in allowed:
                errors.append(ConfigError(f"{where}{label}: {value!r} is not one of {', '.join(allowed)}",
                                          path=config_file, field=field, hint=hint))
    return errors


def validate_schema(
    data: Any, *, config_file: str | Path | None = None, schema_file: str | Path = SCHEMA_FILE
) -> dict[str, Any]:
    """Validate ``data`` against the workflow schema and fill in its defaults, in place.

    Same semantics as ``snakemake.utils.validate(config, schema)`` (draft 2020-12, defaults of
    ``properties`` set before validating), usable without Snakemake; first the names the schema
    leaves to the reader registry (each entry's ``source`` and ``poses[].fmt``).

    Args:
        data: The parsed config.
        config_file: Named in the error message.
        schema_file: The schema.

    Returns:
        ``data`` with defaults filled in.

    Raises:
        ConfigError: Every schema violation, each field once with its location (:func:`combine_errors`).
    """
    if not isinstance(data, dict):
        raise ConfigError(f"the config must be a mapping, got {type(data).__name__}", path=config_file,
                          hint="see config/config.yaml for an example")
    errors = reader_name_errors(data, config_file) + schema_errors(data, schema_file)
    if errors:
        raise combine_errors(errors, config_file)
    return data


def schema_errors(data: dict[str, Any], schema_file: str | Path = SCHEMA_FILE) -> list[ConfigError]:
    """Every schema violation of ``data``, one per field (its most relevant one), in field order;
    fills in the schema's defaults in place (as :func:`validate_schema`)."""
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
    # An unknown key is reported only when nothing else is wrong: with an invalid 'source',
    # for example, the source's own keys also look "unevaluated".
    # An unknown key of an entry (or section) without another error is reported all the same.
    others = {tuple(e.absolute_path)[:2] for e in errors if e.validator != "unevaluatedProperties"}
    primary = [e for e in errors if e.validator != "unevaluatedProperties"
               or tuple(e.absolute_path)[:2] not in others] or errors
    found: dict[str, str] = {}  # every field once: the most relevant error of each
    for error in sorted(primary, key=lambda e: [str(p) for p in e.absolute_path]):
        where, message = _schema_error_message(jsonschema.exceptions.best_match([error]), data)
        found.setdefault(where, message)
    hint = "see workflow/schemas/config.schema.yaml for the allowed keys and values"
    return [ConfigError(f"{where}: {message}", field=None, hint=hint) for where, message in found.items()]


def combine_errors(errors: list[ConfigError], config_file: str | Path | None) -> ConfigError:
    """One :class:`ConfigError` for every problem found, on one line: ``N problems: [1] ...; [2] ...``
    (each with its field and hint); a single problem is itself, naming ``config_file``."""
    errors = [inner for e in errors for inner in (getattr(e, "errors", None) or [e])]  # several (pipeline.configs)
    if len(errors) == 1:
        e = errors[0]
        return ConfigError(e.problem, path=e.path or config_file, line=e.line, field=e.field, hint=e.hint)
    items, hints = [], set()
    for i, e in enumerate(errors, 1):
        text = e.problem + (f" (field '{e.field}')" if e.field else "")
        if e.hint and e.hint not in hints:  # a hint shared by several problems is said once
            text += f": {e.hint}"
            hints.add(e.hint)
        items.append(f"[{i}] {text}")
    out = ConfigError(f"{len(errors)} problems: " + "; ".join(items), path=config_file)
    out.errors = errors  # type: ignore[attr-defined]  # a caller gathering more lists each once
    return out


def check_config(
    data: dict[str, Any], config_file: str | Path | None = None, *, check_paths: bool = True,
    skip_entries: Collection[int] = (), skip_sections: Collection[str] = (),
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
        skip_entries / skip_sections: Sequence entries (indices) and stage sections not to check (the
            schema already faulted them: :func:`load_config` lists every error at once).

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
    problems: list[ConfigError] = []
    for i, raw in enumerate(data.get("sequences") or []):
        if i in skip_entries or not isinstance(raw, dict):
            if isinstance(raw, dict) and isinstance(raw.get("name"), str):
                seen.setdefault(raw["name"], i)  # a later entry of the same name is still a duplicate
            continue
        entry, errors = _checked_entry(i, raw, seen, root, config_file, check_paths)
        problems += errors
        if entry is not None:
            entries.append(entry)
    sections = section_errors(data, config_file, resolve=True, skip=skip_sections)
    problems += sections
    if not sections and not skip_sections:  # the entries' stage settings merge into valid sections: checked in the same pass
        problems += _stage_setting_errors(WorkflowConfig(data, config_file, tuple(entries)), check_paths)
    if problems:
        raise combine_errors(problems, config_file)
    return WorkflowConfig(data, config_file, tuple(entries))


def _stage_setting_errors(cfg: WorkflowConfig, check_paths: bool) -> list[ConfigError]:
    """Every entry's ingest and stage settings errors (each entry's own sections merged into the config's)."""
    problems = []
    for entry in cfg.sequences:
        for check in (check_ingest_settings, lambda c, e: check_stage_settings(c, e, check_paths)):
            try:
                check(cfg, entry)
            except ConfigError as exc:
                problems += getattr(exc, "errors", None) or [exc]
    return problems


def _checked_entry(i: int, raw: dict[str, Any], seen: dict[str, int], root: Path, config_file: Path | None,
                   check_paths: bool) -> tuple[SequenceEntry | None, list[ConfigError]]:
    """The table row of ``sequences[i]`` (its name recorded in ``seen``), or None, and every error of the entry."""
    name = raw["name"]
    where = f"sequences[{i}] ('{name}')"
    errors = []
    if not NAME_PATTERN.match(name):  # also enforced by the schema
        errors.append(ConfigError(f"{where}: invalid sequence name", path=config_file, field="name",
                                  hint="use letters, digits, '_', '.', '-'"))
    if name in seen:
        errors.append(ConfigError(f"{where}: duplicate sequence name '{name}' (also sequences[{seen[name]}])",
                                  path=config_file, field="name", hint="give every sequence a unique name"))
    seen.setdefault(name, i)
    source = source_kind(raw["source"])  # checked by reader_name_errors
    path = None
    if source == SIMULATE:
        try:
            _check_sim_config(sim_dict(raw, root, config_file, where), config_file, where, check_paths)
        except ConfigError as exc:
            errors.append(exc)
    else:
        path = resolve_input_path(raw["path"], root)
        extra = [resolve_input_path(p["path"], root) for p in raw.get("poses") or []]
        for field_name, p in [("path", path)] + [(f"poses[{j}].path", e) for j, e in enumerate(extra)]:
            if check_paths and not p.exists():
                errors.append(ConfigError(
                    f"{where}: input path {p} does not exist", path=config_file, field=field_name,
                    hint=f"fix '{field_name}' (relative paths are resolved against data_root = {root})"))
    if errors:
        return None, errors
    return SequenceEntry(name, source, Split(raw.get("split", "none")), i, path, raw), []


def section_errors(data: dict[str, Any], config_file: str | Path | None, *, resolve: bool = False,
                   skip: Iterable[str] = ()) -> list[ConfigError]:
    """The errors of the top-level stage sections (:data:`STAGE_CONFIGS`), each naming its field once.

    With ``resolve`` each valid section is replaced in ``data`` by its resolved form (defaults filled
    in); sections in ``skip`` (already reported) are left out.
    """
    out = []
    for section in STAGE_CONFIGS:
        options = data.get(section) or {}
        if section in skip or not isinstance(options, Mapping):
            continue
        try:
            resolved = resolved_section(section, options)
        except ConfigError as exc:
            for e in getattr(exc, "errors", None) or [exc]:
                # the field names the section ('training.methods'): no second 'training:' in front
                prefix = "" if (e.field or "").startswith(f"{section}.") else f"{section}: "
                out.append(ConfigError(f"{prefix}{e.problem}", path=config_file, field=e.field, hint=e.hint))
            continue
        if resolve:
            data[section] = resolved
    return out


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
    if isinstance(data, dict) and (errors := reader_name_errors(data, path) + schema_errors(data)):
        # every error in one pass: beside the schema's, those of check_config in the stage sections and
        # sequence entries the schema found nothing wrong with
        faulted = {e.problem.split(":")[0] for e in errors}
        sections = {w.split(".")[0] for w in faulted} & set(STAGE_CONFIGS)
        entries = {int(m.group(1)) for w in faulted if (m := re.match(r"sequences\[(\d+)\]", w))}
        if not any(w == "sequences" for w in faulted):
            try:
                check_config(copy.deepcopy(data), path, check_paths=check_paths, skip_entries=entries,
                             skip_sections=sections)
            except ConfigError as exc:
                errors += getattr(exc, "errors", None) or [exc]
        raise combine_errors(errors, path)
    validate_schema(data, config_file=path)
    return check_config(data, path, check_paths=check_paths)
