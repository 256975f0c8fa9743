"""Building typed config dataclasses from plain mappings (YAML sections, CLI dicts).

Every stage's options live in one frozen dataclass (the field, its type and its default, once);
:func:`dataclass_from_mapping` is the one place that checks a mapping against it: unknown keys
(named, with a close match and the allowed ones), values of the wrong type, enum values.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
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
        return isinstance(value, (list, tuple))
    return True  # enums are checked by value; other types by the dataclass


def _type_name(kind: Any) -> str:
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(k) for k in typing.get_args(kind))
    return {type(None): "null", float: "a number", int: "an integer", bool: "true/false", str: "a string"}.get(
        kind, "a list" if typing.get_origin(kind) in (list, tuple) else getattr(kind, "__name__", str(kind)))


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
    for key, value in options.items():
        kind = hints.get(key)
        if isinstance(kind, type) and issubclass(kind, enum.Enum):
            if not isinstance(value, kind):
                try:
                    options[key] = kind(value)
                except ValueError:
                    raise ConfigError(f"{key} {value!r} is not one of {', '.join(str(m.value) for m in kind)}",
                                      field=f"{field}.{key}") from None
        elif kind is not None and not _type_ok(value, kind):
            raise ConfigError(f"{key} must be {_type_name(kind)}, got {value!r}", field=f"{field}.{key}")
    try:
        return cls(**options)
    except BiasgtError as exc:
        # a field the dataclass already names from the section down ('training.methods') keeps its path
        inner = exc.field or ""
        path = field if not inner else inner if inner == field or inner.startswith(f"{field}.") else f"{field}.{inner}"
        raise ConfigError(exc.problem, field=path, hint=exc.hint) from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"invalid {what}s: {exc}", field=field) from None


def dataclass_to_mapping(obj: Any) -> dict[str, Any]:
    """A config dataclass as a plain mapping (enums as values, tuples as lists): what
    :func:`dataclass_from_mapping` reads back into an equal object."""
    return to_plain(dataclasses.asdict(obj))
