"""The one shape of the project's registries (readers, networks, reference rows, verdict rules).

A :class:`Registry` is a ``dict`` of entries by name in registration order (the order CLI help,
detection, Table I and the verdict's reasons follow), with :meth:`Registry.add` and
:meth:`Registry.remove`. Entries name their implementations as ``"module:attribute"`` strings,
imported on first use by :func:`resolve`, so that a registry costs no import of what it lists.
"""

from __future__ import annotations

import importlib
from typing import Any, TypeVar

__all__ = ["Registry", "resolve"]

T = TypeVar("T")


class Registry(dict[str, T]):
    """Entries by name, in registration order.

    Args:
        kind: What an entry is, for messages ("network", "reference row", ...).
    """

    def __init__(self, kind: str) -> None:
        super().__init__()
        self.kind = kind

    def add(self, name: str, entry: T, *, before: str | None = None) -> T:
        """Register ``entry`` as ``name``: at the end, or just before the entry ``before``; returns it.

        Raises:
            ValueError: ``name`` is taken, or ``before`` is not registered.
        """
        if name in self:
            raise ValueError(f"a {self.kind} named '{name}' is already registered")
        if before is not None and before not in self:
            raise ValueError(f"no {self.kind} '{before}' to register '{name}' before")
        items = list(self.items())
        at = len(items) if before is None else [n for n, _ in items].index(before)
        items.insert(at, (name, entry))
        self.clear()
        self.update(items)
        return entry

    def remove(self, name: str) -> None:
        """Unregister ``name`` (nothing when it is not registered)."""
        self.pop(name, None)


def resolve(ref: Any) -> Any:
    """The object a ``"module:attribute"`` reference names (imported now); anything else as it is."""
    if not isinstance(ref, str):
        return ref
    module, _, attr = ref.partition(":")
    return getattr(importlib.import_module(module), attr)
