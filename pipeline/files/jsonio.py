"""One encoder for every JSON (and YAML) file biasgt writes: numpy, enums, paths and NaN.

Non-finite floats become ``null`` in JSON (strict JSON, readable by any tool); readers of a typed
record turn ``null`` back into NaN where a number is expected.
"""

from __future__ import annotations

import enum
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import InputFormatError


class JsonRecord:
    """Base of the typed record of a JSON file: typed fields for what code reads, plus ``data``,
    the whole object, which ``record["key"]`` and ``record.get("key")`` read (display code)."""

    data: Mapping[str, Any]

    def __getitem__(self, key: str) -> Any:
        return self.data[key]

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str, default: Any = None) -> Any:
        return self.data.get(key, default)


def to_plain(obj: Any, *, finite_only: bool = False) -> Any:
    """``obj`` as plain Python (dict, list, str, int, float, bool, None).

    Mappings get string keys; tuples, lists and numpy arrays become lists; numpy scalars Python
    scalars; enums their value; paths strings.

    Args:
        obj: Any nesting of the above.
        finite_only: Non-finite floats become ``None`` (strict JSON); else they stay (YAML keeps them).
    """
    if isinstance(obj, dict):
        return {str(to_plain(k)): to_plain(v, finite_only=finite_only) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_plain(v, finite_only=finite_only) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_plain(obj.tolist(), finite_only=finite_only)
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, enum.Enum):
        return to_plain(obj.value, finite_only=finite_only)
    if isinstance(obj, Path):
        return str(obj)
    if finite_only and isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps(obj: Any, *, indent: int | None = 2) -> str:
    """Strict JSON text of ``obj`` (see :func:`to_plain`), ending in a newline."""
    return json.dumps(to_plain(obj, finite_only=True), indent=indent, allow_nan=False) + "\n"


def read_json_object(path: str | Path, *, hint: str) -> dict[str, Any]:
    """The JSON object in ``path``.

    Raises:
        InputFormatError: Missing, unreadable, not JSON or not an object (``hint`` says how to fix it).
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputFormatError("does not exist", path=path, hint=hint) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFormatError(f"cannot read JSON ({exc})", path=path, hint=hint) from None
    if not isinstance(data, dict):
        raise InputFormatError("not a JSON object", path=path, hint=hint)
    return data


def number(value: Any) -> float:
    """A JSON number as float; ``null`` (a non-finite value when written) as NaN."""
    return math.nan if value is None else float(value)
