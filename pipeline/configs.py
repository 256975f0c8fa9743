"""Building typed config dataclasses from plain mappings (YAML sections, CLI dicts)."""

from __future__ import annotations

import dataclasses
import enum
import typing
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

from pipeline.errors import BiasgtError, ConfigError

T = TypeVar("T")


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
        field: Config field named in errors (``"check_options"``).
        also_allowed: Keys the caller handles itself (listed as allowed in the hint).

    Raises:
        ConfigError: Unknown key (listing the allowed ones), a value not of an enum field's values
            (listing them), or a value the dataclass rejects.
    """
    options = dict(options or {})
    known = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(options) - known)
    if unknown:
        raise ConfigError(f"unknown {what}(s) {', '.join(unknown)}", field=field,
                          hint=f"allowed: {', '.join(sorted(known | set(also_allowed)))}")
    hints = typing.get_type_hints(cls)
    for key, value in options.items():
        kind = hints.get(key)
        if isinstance(kind, type) and issubclass(kind, enum.Enum) and not isinstance(value, kind):
            try:
                options[key] = kind(value)
            except ValueError:
                raise ConfigError(f"unknown {field} {key} {value!r}", field=f"{field}.{key}",
                                  hint="use one of: " + ", ".join(str(m.value) for m in kind)) from None
    try:
        return cls(**options)
    except BiasgtError as exc:
        raise ConfigError(exc.problem, field=exc.field or field, hint=exc.hint) from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"invalid {what}s: {exc}", field=field) from None
