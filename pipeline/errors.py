"""One exception tree for biasgt.

Every error a user can cause by giving bad input is a :class:`BiasgtError`. Its
message names the file (and line or field where known), says what is wrong and
how to fix it. The CLI prints ``str(error)`` on one line and exits non-zero;
anything that is not a ``BiasgtError`` is a bug and keeps its traceback.
"""

from __future__ import annotations

from pathlib import Path


class BiasgtError(Exception):
    """Base class of every known, user-facing error.

    Args:
        problem: What is wrong, in a few words.
        path: The file or folder concerned, if any.
        line: 1-based line number in ``path``, if known.
        field: Column, key or topic concerned, if any.
        hint: How to fix the input (an imperative sentence).
    """

    exit_code = 2

    def __init__(
        self,
        problem: str,
        *,
        path: str | Path | None = None,
        line: int | None = None,
        field: str | None = None,
        hint: str | None = None,
    ) -> None:
        self.problem = problem
        self.path = None if path is None else str(path)
        self.line = line
        self.field = field
        self.hint = hint
        super().__init__(self._format())

    def _format(self) -> str:
        where = ""
        if self.path is not None:
            where = self.path
            if self.line is not None:
                where += f":{self.line}"
            where += ": "
        what = self.problem
        if self.field is not None:
            what = f"{what} (field '{self.field}')"
        text = f"{where}{what}"
        if self.hint:
            text += f"; {self.hint}"
        # One line, always: the CLI prints exactly this.
        return " ".join(text.split())


class InputFormatError(BiasgtError):
    """A file cannot be parsed as the format it claims to be."""


class UnsupportedInputError(BiasgtError):
    """The input is not of a kind biasgt can read."""


class AmbiguousInputError(BiasgtError):
    """Several streams or topics fit and the user must choose one."""


class DataError(BiasgtError):
    """Parsed data is inconsistent (shapes, units, time order, overlap)."""


class FatalCheckError(DataError):
    """An input check found a problem that forbids writing the sequence."""


class ConfigError(BiasgtError):
    """A configuration file or option is invalid."""


class RegistryError(ConfigError):
    """A registry (readers, networks, reference rows, verdict rules: :mod:`pipeline.registry`) refuses an
    entry, has no entry of a name, or cannot load a plugin's."""


class RecoveryError(BiasgtError):
    """Bias recovery cannot produce a trustworthy result from this input."""


class ValidationError(BiasgtError):
    """Validation cannot be run on this input."""


class OutputLocationError(BiasgtError):
    """The output path cannot be written (a read-only folder, a parent that is a file)."""


class NoSpaceError(OutputLocationError):
    """The disk (or quota) holding the output is full: the output could not be written."""
