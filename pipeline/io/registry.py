"""The input readers: one :class:`Reader` entry per format, registered in :data:`READERS` order.

Everything that lists or picks a format derives from this registry: :func:`parse_format` (names
and aliases), :func:`detect_format` (each entry's ``detect``, in registration order),
:func:`pipeline.io.load_sequence` (each entry's ``load``), :func:`supported_hint`, the CLI's
``--format`` help (:func:`format_help`) and the workflow's source kinds
(:func:`workflow_formats`, checked at start-up by ``biasgt.workflow.config``).

The registry's form is :mod:`pipeline.registry`'s: the :data:`BUILTIN` tuple, :func:`register` and
:func:`unregister`, plugins found through the ``biasgt.readers`` entry points. Adding a reader:
write its module with a ``load(path, *, name, **options) -> Sequence`` (and a ``detect(path) ->
bool`` when it can be recognised), then add one :class:`Reader` line to :data:`BUILTIN` (or install
it as a plugin). Functions are given as callables or as ``"module:function"`` strings, imported on
first use so that listing the formats (``biasgt --help``) imports no reader.

A reader records its format in ``Sequence.metadata[SOURCE_FORMAT_KEY]`` (its name or an alias,
e.g. ``"rosbag"``); :func:`recorded_format` is the one place that reads it back.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.errors import ConfigError, InputFormatError, RegistryError, UnsupportedInputError
from pipeline.io.rosbag import BAG_SUFFIXES
from pipeline.registry import Registry, resolve

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
        before: Where :func:`register` puts it when not told (a plugin's reader): just before this
            reader in the detection order (e.g. ``"csv"``, which takes any ``.csv``); None: the end.
        recognised / reads / notes: docs/inputs.md's formats table (how it is recognised, what is read,
            notes); empty: the help line says it.
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
    before: str | None = None
    recognised: str = ""
    reads: str = ""
    notes: str = ""

    def loader(self) -> Callable[..., Any]:
        """The ``load`` function (imported now when given as ``"module:function"``)."""
        return resolve(self.load)

    def detects(self, path: Path) -> bool:
        """Whether this reader recognises ``path``."""
        return self.detect is not None and bool(resolve(self.detect)(path))


#: The readers biasgt ships, in detection order (a store folder first, generic CSV last).
BUILTIN = (
    Reader("store", "a biasgt store", "a biasgt store folder (sequence.yaml)",
           load="pipeline.store:read_store", detect="pipeline.store:is_store",
           aliases=("parquet", "biasgt"), is_store=True,
           recognised="a folder with `sequence.yaml`",
           reads="`sequence.yaml` + Parquet (written by `convert` / the workflow)",
           notes="lossless round trip, int64 ns"),
    Reader("asl", "an ASL/EuRoC/TUM-VI folder or ASL CSV",
           "an ASL/EuRoC/TUM-VI folder (mav0/imu0/data.csv) or ASL CSV",
           load="pipeline.io.asl:load_asl", detect="pipeline.io.asl:detect_asl",
           aliases=("euroc", "tumvi", "tum-vi"),
           recognised="a folder with `mav0/` (or its streams), or a CSV whose header is an ASL layout",
           reads="`mav0/imu0/data.csv`, `vicon0`, `mocap0` (6-DoF), `leica0` (position only), "
                 "`state_groundtruth_estimate0` / `gt0` (full state with bias), `sensor.yaml` (Kalibr/EuRoC style "
                 "incl. `%YAML:1.0`, `T_BS`, noise parameters); an optional last IMU column `temperature [degC]` "
                 "(biasgt's own addition, written by the simulator)",
           notes="pose stream default priority: streams added with `--add-poses` > vicon0 > mocap0 > leica0 > "
                 "other mocap > position trackers > VIO > ground truth; choose with `--poses NAME`"),
    Reader("bag", "a ROS bag", f"a ROS bag ({', '.join(BAG_SUFFIXES)} or a folder with metadata.yaml)",
           load="pipeline.io.rosbag.reader:read_bag", detect="pipeline.io.rosbag:detect_bag",
           aliases=("rosbag", "ros", "ros1", "ros2", "rosbag1", "rosbag2", "mcap", "db3"),
           options=("imu_topic", "pose_topic", "tf_parent", "tf_child", "all_pose_topics"),
           variant="pipeline.io.rosbag.reader:storage_format",
           recognised=f"a {' or '.join(f'`{s}`' for s in BAG_SUFFIXES)} file (bz2/lz4 chunks too), or a folder with "
                      "`metadata.yaml`",
           reads="`sensor_msgs/Imu`, `geometry_msgs/PoseStamped`, `PoseWithCovarianceStamped`, `TransformStamped`, "
                 "`nav_msgs/Odometry`, `/tf` (+`/tf_static`) with `--tf-parent/--tf-child`",
           notes="topics auto-detected by type; ambiguity errors list the candidates and the option to pick one. "
                 "**Header stamps are used, not bag receive times.** `inspect` shows the storage (`rosbag1`, "
                 "`rosbag2-sqlite3`, `rosbag2-mcap`)"),
    Reader("tum", "a TUM trajectory", "a TUM trajectory (.txt/.tum: t x y z qx qy qz qw)",
           load="pipeline.io.tum:read_tum", detect="pipeline.io.tum:detect_tum",
           recognised="a `.txt`/`.tum` file whose first data line has 8 numbers", reads="`t[s] x y z qx qy qz qw`",
           notes="stamps parsed exactly to ns; evo-compatible writer"),
    Reader("csv", "a CSV with a column mapping", "any CSV with a column mapping (--csv-mapping)",
           load="pipeline.io.csv_generic:load_csv", detect="pipeline.io.csv_generic:detect_csv",
           options=("csv_mapping",), selected_by=("csv_mapping",),
           recognised="any other `.csv`/`.txt`/`.tsv`/`.tum`/`.dat` file, or any file given with `--csv-mapping`",
           reads="any columns, via a YAML mapping (`--csv-mapping`): time column and unit (s/ms/us/ns/auto), gyro/acc "
                 "(rad/s or deg/s, m/s² or g), position, quaternion order"),
)


def _check_names(reader: Reader, entries: Mapping[str, Reader]) -> None:
    """A reader's name and aliases are lower case and taken by no other reader."""
    taken = {n for r in entries.values() for n in (r.name, *r.aliases)}
    clash = sorted({reader.name, *reader.aliases} & taken)
    if clash or reader.name != reader.name.lower():
        raise RegistryError(f"cannot register reader {reader.name!r}: " +
                            (f"{', '.join(clash)} already taken" if clash else "names are lower case"),
                            field="name", hint="pick another name")


#: The registered readers by name, in registration (= detection) order.
READERS: Registry[Reader] = Registry("reader", BUILTIN, entry_type=Reader, check=_check_names, noun="input format")


def register(reader: Reader, *, before: str | None = None) -> Reader:
    """Add a reader: just before the reader ``before`` (else its own :attr:`Reader.before`), or at the
    end of the detection order.

    Raises:
        RegistryError: Its name or an alias is taken, or ``before`` is not registered.
    """
    return READERS.register(reader, before=before if before is not None else reader.before)


def unregister(name: str) -> None:
    """Remove a registered reader (nothing when it is not registered)."""
    READERS.unregister(name)


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
        RegistryError: Unknown format name (the message lists every name and alias).
    """
    reader = find_reader(fmt)
    if reader is None:
        accepted = sorted({n for r in READERS.values() for n in (r.name, *r.aliases)})
        raise RegistryError(f"unknown input format {fmt!r}", field="format", hint=f"use one of {', '.join(accepted)}")
    return reader


def parse_format(fmt: str) -> str:
    """The format name of ``fmt``, a name or an alias (``"rosbag"`` -> ``"bag"``), case-insensitive.

    Raises:
        RegistryError: Unknown format name.
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
