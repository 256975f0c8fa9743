"""Building typed config dataclasses from plain mappings (YAML sections, CLI dicts).

Every stage's options live in one frozen dataclass (the field, its type and its default, once);
:func:`dataclass_from_mapping` is the one place that checks a mapping against it: unknown keys
(named, with a close match and the allowed ones), values of the wrong type, enum values.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import re
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

from pipeline.errors import BiasgtError, ConfigError
from pipeline.files.jsonio import to_plain

T = TypeVar("T")


def unknown_keys_message(keys: Iterable[Any], allowed: Iterable[str]) -> str | None:
    """``unknown key 'x' (did you mean 'y'?)`` for the ``keys`` not in ``allowed``; None when all are known."""
    allowed = sorted(set(allowed))
    extra = [k for k in keys if k not in allowed]
    if not extra:
        return None
    named = []
    for k in extra:
        close = difflib.get_close_matches(str(k), allowed, n=1)
        named.append(f"'{k}' (did you mean '{close[0]}'?)" if close else f"'{k}'")
    return f"unknown key{'s' if len(extra) > 1 else ''} {', '.join(named)}"


def _type_ok(value: Any, kind: Any) -> bool:
    """Whether ``value`` (from YAML / JSON) fits the annotation ``kind`` (scalars, X | None, lists)."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, k) for k in typing.get_args(kind))
    if kind is type(None):
        return value is None
    if kind is bool:
        return isinstance(value, bool)
    if kind is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if kind is str:
        return isinstance(value, str)
    if origin in (list, tuple) or kind in (list, tuple):
        args = [a for a in typing.get_args(kind) if a is not Ellipsis]
        item = args[0] if len(args) == 1 else None  # list[X] / tuple[X, ...]: every item an X
        return isinstance(value, (list, tuple)) and (item is None or all(_type_ok(v, item) for v in value))
    return True  # enums are checked by value; other types by the dataclass


def _type_name(kind: Any) -> str:
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(k) for k in typing.get_args(kind))
    args = [a for a in typing.get_args(kind) if a is not Ellipsis]
    if typing.get_origin(kind) in (list, tuple) and len(args) == 1 and args[0] in (int, float, str, bool):
        return f"a list of {_type_name(args[0]).removeprefix('an ').removeprefix('a ')}s"
    return {type(None): "null", float: "a number", int: "an integer", bool: "true/false", str: "a string"}.get(
        kind, "a list" if typing.get_origin(kind) in (list, tuple) else getattr(kind, "__name__", str(kind)))


def _number_as_text_hint(value: Any) -> str | None:
    """The fix for a number YAML 1.1 reads as text (``1e-7``, ``1.5e7``: its floats need a point and a signed
    exponent), else None."""
    match = isinstance(value, str) and re.fullmatch(r"([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))[eE]([-+]?)([0-9]+)",
                                                    value.strip())
    if not match:
        return None
    mantissa, sign, exponent = match.groups()
    written = f"{mantissa if '.' in mantissa else mantissa + '.0'}e{sign or '+'}{exponent}"
    return f"YAML reads {value} as text: write it with a point and a signed exponent, {written}"


def _numbers(value: Any) -> Any:
    """``value`` with the numbers YAML 1.1 reads as text (``1e-7``), in it or its list, as floats."""
    if isinstance(value, list):
        return [_numbers(v) for v in value]
    return float(value) if _number_as_text_hint(value) else value


def several(errors: list[ConfigError]) -> ConfigError:
    """One :class:`ConfigError` standing for ``errors`` (itself when there is one): its ``errors`` attribute
    lists them, so that a caller gathering every problem of a config lists each
    (:func:`biasgt.workflow.config.combine_errors`)."""
    if len(errors) == 1:
        return errors[0]
    out = ConfigError("; ".join(e.problem + (f" (field '{e.field}')" if e.field else "") for e in errors),
                      field=None, hint=errors[0].hint)
    out.errors = list(errors)  # type: ignore[attr-defined]
    return out


def dataclass_from_mapping(
    cls: type[T],
    options: Mapping[str, Any] | None,
    *,
    what: str,
    field: str,
    also_allowed: Iterable[str] = (),
) -> T:
    """``cls(**options)`` with one-line :class:`ConfigError` messages.

    Args:
        cls: A dataclass.
        options: Keyword values (a partial mapping; missing keys take the defaults).
        what: What the options are, for messages (``"check option"``).
        field: Config field named in errors (``"check_options"``, a workflow section name).
        also_allowed: Keys the caller handles itself (listed as allowed in the hint).

    A field whose metadata holds ``"check"`` (a function of the value returning a :class:`ConfigError` or
    None) is checked by it instead of by its type. Every key's error is found in one pass
    (:func:`several`); the dataclass's own checks run once the keys are fine.

    Raises:
        ConfigError: Unknown key (naming it and the allowed ones), a value of the wrong type or not
            one of an enum field's values (listing them), or a value the dataclass rejects.
    """
    options = dict(options or {})
    known = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = unknown_keys_message(options, known | set(also_allowed))
    if unknown:
        raise ConfigError(unknown, field=field, hint=f"allowed: {', '.join(sorted(known | set(also_allowed)))}")
    hints = typing.get_type_hints(cls)
    checks = {f.name: f.metadata["check"] for f in dataclasses.fields(cls) if "check" in f.metadata}  # type: ignore[arg-type]
    errors = []  # every key's error at once (combine_errors lists them on one line)
    for key, value in options.items():
        kind = hints.get(key)
        if key in checks:  # the field's own check (metadata {"check": value -> ConfigError | None}): its words
            if (problem := checks[key](value)) is not None:
                errors.append(problem)
        elif isinstance(kind, type) and issubclass(kind, enum.Enum):
            if not isinstance(value, kind):
                try:
                    options[key] = kind(value)
                except ValueError:
                    errors.append(ConfigError(f"{key} {value!r} is not one of "
                                              f"{', '.join(str(m.value) for m in kind)}", field=f"{field}.{key}"))
        elif kind is not None and not _type_ok(value, kind):
            errors.append(ConfigError(f"{key} must be {_type_name(kind)}, got {value!r}", field=f"{field}.{key}",
                                      hint=_number_as_text_hint(value)))
    if errors:
        raise several(errors)
    try:
        return cls(**options)
    except BiasgtError as exc:
        # a field the dataclass already names from the section down ('training.methods') keeps its path
        def under(e: BiasgtError) -> ConfigError:
            inner = e.field or ""
            path = field if not inner else inner if inner == field or inner.startswith(f"{field}.") else f"{field}.{inner}"
            return ConfigError(e.problem, field=path, hint=e.hint)

        raise several([under(e) for e in getattr(exc, "errors", None) or [exc]]) from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"invalid {what}s: {exc}", field=field) from None


def dataclass_to_mapping(obj: Any) -> dict[str, Any]:
    """A config dataclass as a plain mapping (enums as values, tuples as lists): what
    :func:`dataclass_from_mapping` reads back into an equal object."""
    return to_plain(dataclasses.asdict(obj))


def assignments_to_mapping(items: Iterable[str], *, option: str = "--set") -> dict[str, Any]:
    """``["key=value", ...]`` (command-line overrides, values in YAML; ``1e-7`` a number, as YAML 1.2 reads it)
    as ``{key: value}``.

    Raises:
        ConfigError: An item without ``=``, or with a value that is not YAML (the item and the fix named).
    """
    import yaml

    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{item!r} is not KEY=VALUE", field=option,
                              hint="write it as KEY=VALUE, e.g. random_walk_scales=[0.1,1,10]")
        try:
            out[key.strip()] = _numbers(yaml.safe_load(value))
        except yaml.YAMLError as exc:
            raise ConfigError(f"the value of {item!r} is not YAML ({exc.__class__.__name__})", field=option,
                              hint="quote the value or write a list in brackets") from None
    return out
