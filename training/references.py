"""The reference-row registry: the evaluation's rows that need no training, one :class:`ReferenceRow` each.

An entry owns everything that names a row: its name (``biasgt evaluate --reference``, the
workflow's ``evaluation.references``, folder names), its Table I label, whether it is an oracle
(uses ground truth at test time: a bound, not ranked), a help line, whether the workflow evaluates
it by default, its implementation and the inputs that implementation needs. Table I lists the
rows in registration order, after the learned methods (:mod:`training.networks`).

The registry's form is :mod:`pipeline.registry`'s: the :data:`BUILTIN` tuple, :func:`register` and
:func:`unregister`, plugins found through the ``biasgt.references`` entry points. Adding a row: a
function ``bias(items, **inputs) -> [B, 1, T, 6]`` (rad/s, m/s^2) in its own module of
:mod:`training.rows`, then one entry in :data:`BUILTIN` below (``default=False`` unless every
workflow's Table I should show it). The function is named as ``"module:attr"`` and imported only
when the row is evaluated, so that this module (read by the workflow at start-up) imports no torch.

Inputs (``needs``): the evaluation gives the function ``items`` (the collated float64 window
items of one test sequence: ``imu`` [B, T, 6], ``bias`` [B, T, 6], ``dt_s`` [B, T-1], ``start_*``,
``end_*``, ``t0_ns``) and, as keywords, each input it declares:

``bias_mean``
    The train split's mean bias, [6].
``bias_std``
    The train split's bias standard deviation (the manifest's normalisation), [6].
``random_walk``
    The bias random-walk strengths of the windows' sequence, [B, 6] (NaN when unknown; the
    evaluation's ``oracle_random_walk`` choice).
``gravity_mps2``
    Gravity in the world frame of the windows' sequence, [3] (the evaluation's ``gravity`` choice).
``rng``
    A ``numpy.random.Generator`` seeded from the evaluation seed and the batch.
``context``
    The sequence's whole IMU record (:class:`training.data.records.SequenceContext`; the dataset needs
    ``context/``, :func:`training.data.records.write_context`).
``sequence_dir``
    The sequence's windows folder (``DATASET/sequences/<seq>``, a ``pathlib.Path``).
``info.<key>``
    The sequence's value ``<key>`` in the dataset manifest's ``info`` (``None`` when it has none),
    given as the keyword ``<key>``.
any other name
    The per-window dataset array ``<name>`` (``sequences/<seq>/<name>.npy``, [B, ...] float64;
    NaN for a sequence without the file).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pipeline.registry import Registry, resolve

__all__ = ["BUILTIN", "EVALUATION_INPUTS", "REFERENCES", "ReferenceRow", "get_reference", "reference_names", "register",
           "unregister"]

#: Inputs the evaluation computes itself (see the module docstring); ``info.<key>`` and array names aside.
EVALUATION_INPUTS = ("bias_mean", "bias_std", "random_walk", "gravity_mps2", "rng", "context", "sequence_dir")


@dataclass(frozen=True)
class ReferenceRow:
    """One reference row.

    Attributes:
        name: Row name.
        label: Name in Table I and the reports.
        help: One line for ``biasgt evaluate --help``.
        bias: ``"module:attr"`` (or the callable) ``bias(items, **inputs) -> [B, 1, T, 6]``.
        oracle: Uses ground truth at test time (a bound: not ranked, kind "oracle").
        needs: Inputs ``bias`` takes as keywords (see the module docstring).
        default: Evaluated by the workflow unless its ``evaluation.references`` says otherwise.
        note: ``"module:attr"`` (or the callable) ``note(summaries) -> str | None``: a footnote of
            Table I when the row is in it.
    """

    name: str
    label: str
    help: str
    bias: str | Callable[..., Any]
    oracle: bool = False
    needs: tuple[str, ...] = ()
    default: bool = True
    note: str | Callable[[list[Any]], str | None] | None = None

    @property
    def arrays(self) -> tuple[str, ...]:
        """The per-window dataset arrays among ``needs``."""
        return tuple(n for n in self.needs if n not in EVALUATION_INPUTS and not n.startswith("info."))

    def predict(self, items: dict[str, Any], inputs: dict[str, Any]) -> Any:
        """The row's bias [B, 1, T, 6] for ``items``, given the ``inputs`` it declared."""
        return resolve(self.bias)(items, **{n.removeprefix("info."): inputs[n] for n in self.needs})

    def footnote(self, summaries: list[Any]) -> str | None:
        """The row's footnote of a Table I of ``summaries``; None when the row is not among them."""
        if self.note is None or not any(getattr(s, "method", None) == self.name for s in summaries):
            return None
        return resolve(self.note)(summaries)


# ----------------------------------------------------------------------------- built-in rows (Table I order)

_B = "training.rows.baselines"
BUILTIN = (
    ReferenceRow("zero", "Zero bias", "no bias correction: the raw readings integrated", f"{_B}:zero_bias"),
    ReferenceRow("train_mean", "Train-mean bias", "the train split's mean bias, held constant",
                 f"{_B}:train_mean_bias", needs=("bias_mean",)),
    ReferenceRow("state_bias", "Dataset GT-state bias", "the dataset's own ground-truth-state bias (EuRoC's "
                 "state_groundtruth_estimate0)", f"{_B}:state_bias", oracle=True, needs=("state_bias",),
                 default=False),
    ReferenceRow("ground_truth", "Recovered GT bias", "the recovered ground-truth bias itself (what the labels "
                 "allow)", f"{_B}:ground_truth_bias", oracle=True),
    ReferenceRow("random_walk_oracle", "Random walk (oracle)", "ground-truth bias at each window start plus 50 "
                 "random walks, the best chosen with the ground-truth end pose",
                 f"{_B}:random_walk_oracle", oracle=True, needs=("random_walk", "gravity_mps2", "rng", "state_bias"),
                 note=f"{_B}:oracle_note"),
    ReferenceRow("random_walk_paper", "Random walk (oracle, paper's walks)", "the same oracle with the walks the "
                 "paper's random-walk column implies", f"{_B}:random_walk_paper", oracle=True,
                 needs=("random_walk", "gravity_mps2", "rng", "state_bias"), default=False,
                 note=f"{_B}:paper_walk_note"),
    ReferenceRow("start_rest", "Start-rest bias", "from the IMU alone: the gyro mean over the record's first rest, "
                 "the accelerometer's bias along gravity there (the train mean across it), held constant",
                 "training.rows.start_rest:start_rest_row", needs=("context", "bias_mean", "gravity_mps2"),
                 default=False, note="training.rows.start_rest:start_rest_note"),
    ReferenceRow("sequence_mean", "Sequence-mean bias (oracle)", "each test sequence's own mean dataset bias, held "
                 "constant: the best one constant per sequence", "training.rows.sequence_mean:sequence_mean_row",
                 oracle=True, needs=("sequence_dir",), default=False,
                 note="training.rows.sequence_mean:sequence_mean_note"),
    ReferenceRow("bias_filter", "Bias filter", "from the IMU alone: a causal error-state Kalman filter over the "
                 "record (rests and bounded motion), its estimate at each window's end",
                 "training.rows.bias_filter:bias_filter_row", needs=("context", "bias_mean", "bias_std", "gravity_mps2"),
                 default=False, note="training.rows.bias_filter:bias_filter_note"),
)


#: The registered rows by name, in registration (Table I) order.
REFERENCES: Registry[ReferenceRow] = Registry("reference row", BUILTIN, entry_type=ReferenceRow)


def register(row: ReferenceRow, *, before: str | None = None) -> ReferenceRow:
    """Add ``row`` (at the end, or just before ``before``: its place in Table I).

    Raises:
        RegistryError: Its name is taken, or ``before`` is not registered.
    """
    return REFERENCES.register(row, before=before)


def unregister(name: str) -> None:
    """Remove a registered row (nothing when it is not registered)."""
    REFERENCES.unregister(name)


def reference_names(*, default_only: bool = False) -> tuple[str, ...]:
    """Registered row names in registration (Table I) order (``default_only``: the workflow's default ones)."""
    return tuple(n for n, r in REFERENCES.items() if r.default or not default_only)


def get_reference(name: Any, *, field: str = "reference") -> ReferenceRow:
    """The registered row ``name``.

    Raises:
        RegistryError: No row of that name (the hint lists the registered ones).
    """
    return REFERENCES.lookup(name, field=field)
