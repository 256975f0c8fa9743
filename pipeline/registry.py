"""The one form of the project's registries: input readers, networks, reference rows, verdict rules.

Each registry module declares its entries the same way:

* a ``BUILTIN`` tuple of entries (frozen dataclasses), in the registry's order (the order CLI
  help, detection, Table I and the verdict's reasons follow);
* a :class:`Registry` over them, read like a mapping of names to entries;
* ``register(entry, *, before=None)`` and ``unregister(name)``, the same two functions everywhere;
* every error a :class:`pipeline.errors.RegistryError` (a ``ConfigError``) with a fix-it hint.

Entries name their implementations as ``"module:attribute"`` strings, imported on first use by
:func:`resolve`, so that reading a registry (``biasgt --help``, the workflow's start-up checks)
imports nothing that it lists.

**Plugins.** A distribution installed beside biasgt adds entries without an edit inside the
package, the way Snakemake finds its executor plugins: an ``importlib.metadata`` entry point in the
registry's group (:data:`GROUPS`) names an entry, or a tuple of entries, of the registry's type::

    # the plugin's pyproject.toml
    [project.entry-points."biasgt.readers"]
    imu_ms_g = "biasgt_imu_ms_g:READER"

Plugins are loaded when a registry is first read, after the built-in entries and before those a
program registers itself; an entry whose type has a ``before`` field (a reader's place in the
detection order) goes just before that entry.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from types import MappingProxyType
from typing import Any, Generic, TypeVar

from pipeline.errors import RegistryError

__all__ = ["GROUPS", "Registry", "RegistryError", "reference_name", "resolve"]

T = TypeVar("T")

#: The entry-point group of each registry (the registry's ``kind`` -> group).
GROUPS = {"reader": "biasgt.readers", "network": "biasgt.networks", "reference row": "biasgt.references",
          "rule": "biasgt.rules"}


class Registry(Generic[T]):
    """Entries by name, in order: the built-in ones, the plugins', then those registered.

    Args:
        kind: What an entry is, for messages and the plugin group (a key of :data:`GROUPS`).
        builtin: The registry module's ``BUILTIN`` entries.
        entry_type: The entries' class (a plugin's object is checked against it).
        key: An entry's name (``entry.name``; a rule's ``code``).
        check: ``check(entry, entries)``: further checks of an entry against those registered before it
            (raises :class:`RegistryError`).
        noun: How an unknown name is called in :meth:`lookup`'s message (default ``kind``).
    """

    def __init__(self, kind: str, builtin: Iterable[T], *, entry_type: type, key: Callable[[T], str] | None = None,
                 check: Callable[[T, Mapping[str, T]], None] | None = None, noun: str | None = None) -> None:
        self.kind = kind
        self.group = GROUPS[kind]
        self.entry_type = entry_type
        self.noun = noun or kind
        self._key = key or (lambda e: e.name)
        self._check = check
        self._entries: dict[str, T] = {}
        self._plugins_loaded = False
        for entry in builtin:
            self._add(entry, None)

    # -- reading (every read loads the plugins first) ------------------------------------------------
    def _all(self) -> dict[str, T]:
        if not self._plugins_loaded:
            self._plugins_loaded = True
            self._load_plugins()
        return self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._all()))

    def __len__(self) -> int:
        return len(self._all())

    def __contains__(self, name: object) -> bool:
        return name in self._all()

    def __getitem__(self, name: str) -> T:
        return self._all()[name]

    def get(self, name: str, default: T | None = None) -> T | None:
        return self._all().get(name, default)

    def names(self) -> tuple[str, ...]:
        """Every name, in order."""
        return tuple(self._all())

    def items(self) -> list[tuple[str, T]]:
        return list(self._all().items())

    def values(self) -> list[T]:
        return list(self._all().values())

    def lookup(self, name: Any, *, field: str | None = None) -> T:
        """The entry ``name`` (an enum's value is read as its value).

        Raises:
            RegistryError: No such entry; the hint lists the registered names.
        """
        key = str(getattr(name, "value", name))
        entries = self._all()
        if key not in entries:
            raise RegistryError(f"unknown {self.noun} '{key}'", field=field,
                                hint=f"choose one of {', '.join(entries) or '(none registered)'}")
        return entries[key]

    # -- changing ------------------------------------------------------------------------------------
    def register(self, entry: T, *, before: str | None = None) -> T:
        """Add ``entry``: at the end, or just before the entry ``before``; returns it.

        Raises:
            RegistryError: Not an entry of this registry, its name is taken, ``before`` is not
                registered, or the registry's own checks refuse it.
        """
        self._all()
        return self._add(entry, before)

    def unregister(self, name: str) -> None:
        """Remove the entry ``name`` (nothing when it is not registered)."""
        self._all().pop(name, None)

    def _add(self, entry: T, before: str | None) -> T:
        if not isinstance(entry, self.entry_type):
            raise RegistryError(f"cannot register {type(entry).__name__} {entry!r} as a {self.kind}",
                                hint=f"give a {self.entry_type.__module__}.{self.entry_type.__name__}")
        name = self._key(entry)
        if name in self._entries:
            raise RegistryError(f"cannot register {self.kind} '{name}': {name} already taken", field="name",
                                hint=f"pick a name other than {', '.join(self._entries)}")
        if before is not None and before not in self._entries:
            raise RegistryError(f"no {self.kind} '{before}' to register '{name}' before", field="before",
                                hint=f"registered: {', '.join(self._entries)}")
        if self._check is not None:
            self._check(entry, MappingProxyType(self._entries))
        items = list(self._entries.items())
        at = len(items) if before is None else [n for n, _ in items].index(before)
        items.insert(at, (name, entry))
        self._entries = dict(items)
        return entry

    def _load_plugins(self) -> None:
        """Add the entries of every installed distribution's entry points in :attr:`group`."""
        from importlib.metadata import entry_points

        for point in sorted(entry_points(group=self.group), key=lambda p: p.name):
            dist = getattr(point.dist, "name", None) or "an installed distribution"
            try:
                obj = point.load()
            except Exception as exc:  # a plugin's own error: named, with the way out
                raise RegistryError(f"cannot load the {self.kind} plugin '{point.name}' ({point.value}) of {dist}: "
                                    f"{type(exc).__name__}: {exc}", field=self.group,
                                    hint=f"fix that distribution or uninstall it (pip uninstall {dist})") from None
            for entry in obj if isinstance(obj, (tuple, list)) else (obj,):
                try:
                    self._add(entry, getattr(entry, "before", None))
                except RegistryError as exc:
                    raise RegistryError(f"{self.kind} plugin '{point.name}' of {dist}: {exc.problem}",
                                        field=self.group, hint=exc.hint) from None


def resolve(ref: Any) -> Any:
    """The object a ``"module:attribute"`` reference names (imported now); anything else as it is.

    Raises:
        RegistryError: The module or the attribute does not exist.
    """
    if not isinstance(ref, str):
        return ref
    module, _, attr = ref.partition(":")
    try:
        obj: Any = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as exc:
        raise RegistryError(f"cannot import '{ref}': {exc}", hint="check the registry entry's 'module:attribute' "
                            "reference (the module must be importable, the attribute defined in it)") from None
    return obj


def reference_name(ref: Any) -> str:
    """The attribute's name of a ``"module:attribute"`` reference, or an object's ``__name__``,
    without importing anything (for docs and help)."""
    if isinstance(ref, str):
        return ref.rpartition(":")[2]
    return getattr(ref, "__name__", type(ref).__name__)
