"""The input readers: one :class:`Reader` entry per format, registered in :data:`READERS` order.

Everything that lists or picks a format derives from this registry: :func:`parse_format` (names
and aliases), :func:`detect_format` (each entry's ``detect``, in registration order),
:func:`pipeline.io.load_sequence` (each entry's ``load``), :func:`supported_hint`, the CLI's
``--format`` help (:func:`format_help`) and the workflow's source kinds
(:func:`workflow_formats`, checked at start-up by ``biasgt.workflow.config``).

Adding a reader: write its module with a ``load(path, *, name, **options) -> Sequence`` (and a
``detect(path) -> bool`` when it can be recognised), then add one :class:`Reader` line to
:func:`_builtin_readers` (or call :func:`register` from outside the package). Functions are
given as callables or as ``"module:function"`` strings, imported on first use so that listing
the formats (``biasgt --help``) imports no reader.

A reader records its format in ``Sequence.metadata[SOURCE_FORMAT_KEY]`` (its name or an alias,
e.g. ``"rosbag"``); :func:`recorded_format` is the one place that reads it back.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.registry import Registry, resolve
from pipeline.errors import ConfigError, InputFormatError, UnsupportedInputError

#: ``Sequence.metadata`` key of the format that produced a sequence (a reader's name or alias).
SOURCE_FORMAT_KEY = "source_format"
#: The same, as stores written before it were keyed (ROS bags and the simulator wrote it).
LEGACY_SOURCE_FORMAT_KEY = "source_kind"


@dataclass(frozen=True)
class Reader:
    """One input format.

    Attributes:
        name: The format's name: ``--format NAME``, a workflow entry's ``source: NAME``,
            ``poses[].fmt``; lower case.
        label: A noun phrase for lists and messages (``"a ROS bag"``).
        help: One line: what is read and how it is recognised (``--format`` help, error hints).
        load: ``load(path: Path, *, name: str | None, **options) -> Sequence``, or
            ``"module:function"``; ``options`` are those of :attr:`options` that were given.
        detect: ``detect(path: Path) -> bool`` (``path`` exists: a file or a folder), or
            ``"module:function"``; ``None``: only read with ``--format NAME``. Entries are asked
            in registration order; the first that says yes reads the input.
        aliases: Other names accepted by :func:`parse_format` (``"rosbag"``, ``"euroc"``).
        options: Reader options (keyword arguments of :func:`pipeline.io.load_sequence`) this
            reader takes; giving one to a reader that does not take it is an error.
        selected_by: Options that, given for a file without ``--format``, choose this reader.
        variant: ``variant(metadata) -> str | None``, or ``"module:function"``: a finer format
            the reader recorded (a bag's storage, ``"rosbag1"``), shown by ``biasgt inspect``.
        is_store: The canonical store: checked when it was written (no reader defaults are
            added on reading) and not a source of the workflow (which writes stores).
    """

    name: str
    label: str
    help: str
    load: Callable[..., Any] | str
    detect: Callable[[Path], bool] | str | None = None
    aliases: tuple[str, ...] = ()
    options: tuple[str, ...] = ()
    selected_by: tuple[str, ...] = ()
    variant: Callable[[Mapping[str, Any]], str | None] | str | None = None
    is_store: bool = False

    def loader(self) -> Callable[..., Any]:
        """The ``load`` function (imported now when given as ``"module:function"``)."""
        return resolve(self.load)

    def detects(self, path: Path) -> bool:
        """Whether this reader recognises ``path``."""
        return self.detect is not None and bool(resolve(self.detect)(path))


def _builtin_readers() -> list[Reader]:
    """The readers biasgt ships, in detection order (a store folder first, generic CSV last)."""
    return [
        Reader("store", "a biasgt store", "a biasgt store folder (sequence.yaml)",
               load="pipeline.store:read_store", detect="pipeline.store:is_store",
               aliases=("parquet", "biasgt"), is_store=True),
        Reader("asl", "an ASL/EuRoC/TUM-VI folder or ASL CSV",
               "an ASL/EuRoC/TUM-VI folder (mav0/imu0/data.csv) or ASL CSV",
               load="pipeline.io.asl:load_asl", detect="pipeline.io.asl:detect_asl",
               aliases=("euroc", "tumvi", "tum-vi")),
        Reader("bag", "a ROS bag", "a ROS bag (.bag, .mcap, .db3 or a folder with metadata.yaml)",
               load="pipeline.io.rosbag.reader:read_bag", detect="pipeline.io.rosbag:detect_bag",
               aliases=("rosbag", "ros", "ros1", "ros2", "rosbag1", "rosbag2", "mcap", "db3"),
               options=("imu_topic", "pose_topic", "tf_parent", "tf_child", "all_pose_topics"),
               variant="pipeline.io.rosbag.reader:storage_format"),
        Reader("tum", "a TUM trajectory", "a TUM trajectory (.txt/.tum: t x y z qx qy qz qw)",
               load="pipeline.io.tum:read_tum", detect="pipeline.io.tum:detect_tum"),
        Reader("csv", "a CSV with a column mapping", "any CSV with a column mapping (--csv-mapping)",
               load="pipeline.io.csv_generic:load_csv", detect="pipeline.io.csv_generic:detect_csv",
               options=("csv_mapping",), selected_by=("csv_mapping",)),
    ]


#: The registered readers by name, in registration (= detection) order.
READERS: Registry[Reader] = Registry("reader")
for _reader in _builtin_readers():
    READERS.add(_reader.name, _reader)


def register(reader: Reader, *, before: str | None = None) -> Reader:
    """Add a reader (to the end of the detection order, or just before the reader ``before``).

    Raises:
        ConfigError: Its name or an alias is taken, or ``before`` is not registered.
    """
    taken = {n for r in READERS.values() for n in (r.name, *r.aliases)}
    clash = sorted({reader.name, *reader.aliases} & taken)
    if clash or reader.name != reader.name.lower():
        raise ConfigError(f"cannot register reader {reader.name!r}: " +
                          (f"{', '.join(clash)} already taken" if clash else "names are lower case"),
                          field="name", hint="pick another name")
    if before is not None and before not in READERS:
        raise ConfigError(f"no reader {before!r} to register {reader.name!r} before", field="before",
                          hint="registered: " + ", ".join(READERS))
    return READERS.add(reader.name, reader, before=before)


def unregister(name: str) -> None:
    """Remove a registered reader (tests clean up with it)."""
    READERS.remove(name)


def names() -> list[str]:
    """The registered format names, in registration order."""
    return list(READERS)


def workflow_formats() -> list[str]:
    """The formats a workflow entry's ``source`` may name: every reader but the store."""
    return [r.name for r in READERS.values() if not r.is_store]


def find_reader(fmt: str) -> Reader | None:
    """The reader called ``fmt`` (a name or alias, any case), or ``None``."""
    key = str(fmt).strip().lower()
    for r in READERS.values():
        if key == r.name or key in r.aliases:
            return r
    return None


def get_reader(fmt: str) -> Reader:
    """The reader called ``fmt`` (a name or alias, any case).

    Raises:
        ConfigError: Unknown format name (the message lists every name and alias).
    """
    reader = find_reader(fmt)
    if reader is None:
        accepted = sorted({n for r in READERS.values() for n in (r.name, *r.aliases)})
        raise ConfigError(f"unknown input format {fmt!r}", field="format", hint=f"use one of {', '.join(accepted)}")
    return reader


def parse_format(fmt: str) -> str:
    """The format name of ``fmt``, a name or an alias (``"rosbag"`` -> ``"bag"``), case-insensitive.

    Raises:
        ConfigError: Unknown format name.
    """
    return get_reader(fmt).name


def supported_hint() -> str:
    """``"supported inputs: ..."``, every reader's help line, for error hints."""
    lines = [r.help for r in READERS.values()]
    listed = ", ".join(lines[:-1]) + ", or " + lines[-1] if len(lines) > 1 else "".join(lines)
    return f"supported inputs: {listed}"


def readers_in_words() -> str:
    """Every reader's label in one phrase (``"a biasgt store, an ASL/... folder, ... or a CSV ..."``)."""
    labels = [r.label for r in READERS.values()]
    return ", ".join(labels[:-1]) + " or " + labels[-1] if len(labels) > 1 else "".join(labels)


def format_help() -> str:
    """Help of the CLI's ``--format``: every name with its help line, then the aliases."""
    listed = "; ".join(f"{r.name}: {r.help}" for r in READERS.values())
    aliases = ", ".join(f"{a}={r.name}" for r in READERS.values() for a in r.aliases)
    return f"input format when auto-detection is not enough: {listed} (aliases: {aliases})"


def detect_format(path: str | Path) -> str:
    """The name of the first reader, in registration order, that recognises ``path``.

    Raises:
        InputFormatError: ``path`` does not exist.
        UnsupportedInputError: No reader recognises it; the message lists what is supported.
    """
    path = Path(path)
    if not path.exists():
        raise InputFormatError("does not exist", path=path, hint="check the path")
    for reader in READERS.values():
        if reader.detects(path):
            return reader.name
    if path.is_dir():
        raise UnsupportedInputError("folder is not a recognised input", path=path, hint=supported_hint())
    suffix = path.suffix.lower()
    raise UnsupportedInputError(f"unrecognised file type '{suffix or path.name}'", path=path, hint=supported_hint())


def select_reader(path: Path, fmt: str | None, given: Mapping[str, Any]) -> Reader:
    """The reader for ``path``: ``fmt`` when given, else one chosen by a given option
    (:attr:`Reader.selected_by`, files only), else :func:`detect_format`; checked against the
    given options (``given``: option name -> value, ``None`` = not given).

    Raises:
        ConfigError: Unknown ``fmt``, or an option the chosen reader does not take.
        InputFormatError, UnsupportedInputError: As :func:`detect_format`.
    """
    given = {k: v for k, v in given.items() if v is not None}
    if fmt is not None:
        reader = get_reader(fmt)
    else:
        chosen = [r for r in READERS.values() if path.is_file() and set(r.selected_by) & set(given)]
        reader = chosen[0] if chosen else READERS[detect_format(path)]
    for owner in READERS.values():
        for option in owner.options:
            if option in given and option not in reader.options:
                raise ConfigError(f"option {option} applies to {owner.name} input only, but {path.name} is {reader.name}",
                                  field=option, hint=f"drop the option, or pass {owner.label} (--format {owner.name})")
    return reader


def recorded_format(metadata: Mapping[str, Any], *, variant: bool = False) -> str | None:
    """The format recorded in a sequence's metadata (:data:`SOURCE_FORMAT_KEY`, or the key of
    stores written before it), ``None`` when there is none.

    Args:
        metadata: ``Sequence.metadata``.
        variant: Give the reader's finer format where it recorded one (a bag's ``"rosbag1"``).
    """
    value = metadata.get(SOURCE_FORMAT_KEY)
    if not isinstance(value, str):
        value = metadata.get(LEGACY_SOURCE_FORMAT_KEY)
    if not isinstance(value, str):
        return None
    reader = find_reader(value) if variant else None
    if reader is not None and reader.variant is not None:
        return resolve(reader.variant)(metadata) or value
    return value
