"""The verdict's comparisons with a baseline, and the rules built on them (registered in
:mod:`validation.rules`).

:func:`compare` is the one test of "worse than a baseline", for every rule that asks it: against a
constant or the dataset's bias in sample (per baseline, with the candidate's own sigma as allowance),
against the zero bias in sample and the zero or constant bias held out (without). A check takes the
:class:`validation.rules.Evidence` (and, per baseline, the baseline's metrics) and returns one text
per time its rule fires.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from validation.config import BiasSourceKind, ValidationConfig

if TYPE_CHECKING:
    from validation.metrics import SourceMetrics
    from validation.rules import Evidence

__all__ = ["Comparison", "against_baseline", "compare", "indistinguishable", "no_better", "paired_p_value",
           "too_uncertain", "within_sigma_of_zero", "worse_than"]


def paired_p_value(cand: np.ndarray, base: np.ndarray, stride: int) -> float:
    """One-sided p-value of "the candidate's window errors are larger" (paired t-test).

    Windows that share samples are correlated: only every ``stride``-th window enters (with 50 %
    overlap, the non-overlapping ones).
    """
    from scipy.stats import ttest_rel

    d = cand[::stride] - base[::stride]
    if len(d) < 3 or not np.any(d):
        return 1.0
    if np.ptp(d) <= 1e-12 * np.max(np.abs(d)):  # the same difference in every window: no spread to test
        return 0.0 if d[0] > 0 else 1.0
    return float(ttest_rel(cand[::stride], base[::stride], alternative="greater").pvalue)


@dataclass(frozen=True)
class Comparison:
    """A candidate's errors against a baseline's on the same windows, on one metric (:func:`compare`).

    Attributes:
        label / unit: ``PRMSE`` (m) or ``ROE`` (deg).
        cand / base: The two metric values.
        outcome: None (equal up to the tie and the candidate's own sigma), ``within`` (worse, within
            the margin), ``not_significant`` (beyond the margin, but the paired test does not say
            worse) or ``worse`` (beyond the margin and significantly: the only one that counts as worse).
        p_value: The paired test's, where it ran.
    """

    label: str
    unit: str
    cand: float
    base: float
    outcome: str | None
    p_value: float | None = None

    @property
    def text(self) -> str:
        rel = (self.cand / self.base - 1.0) * 100.0 if self.base > 0 else float("inf")
        return f"{self.label} {self.cand:.4g} {self.unit} is {rel:+.1f} % against {self.base:.4g} {self.unit}"


def compare(label: str, cand_err: np.ndarray, base_err: np.ndarray, config: ValidationConfig, stride: int,
            sigma: float = 0.0) -> Comparison:
    """The one test of "worse than a baseline", for every rule that asks it (a constant or dataset bias in
    sample; the zero bias in sample; the zero or constant bias held out).

    ``cand_err`` / ``base_err``: per-window end errors on the same windows, [W] (m for PRMSE, deg for
    ROE). The candidate is equal up to ``sqrt(base^2 + sigma^2) + tie`` (PRMSE) or ``base + sigma + tie``
    (ROE), ``sigma`` being what its own sigma explains (0: no allowance); worse within the margin up to
    ``(1 + margin)`` times the baseline's part; beyond that it is worse only when a paired one-sided
    t-test over non-overlapping windows (every ``stride``-th) says so at ``significance``.
    """
    if label == "PRMSE":
        unit, c, b, tie = "m", _rms(cand_err), _rms(base_err), config.tie_prmse_m
        allowed = [float(np.hypot(b * f, sigma)) + tie for f in (1.0, 1.0 + config.margin)]
        tested = (np.square(cand_err), np.square(base_err))
    else:
        unit, c, b, tie = "deg", float(np.mean(cand_err)), float(np.mean(base_err)), config.tie_roe_deg
        allowed = [b * f + sigma + tie for f in (1.0, 1.0 + config.margin)]
        tested = (cand_err, base_err)
    if c <= allowed[0]:
        return Comparison(label, unit, c, b, None)
    if c <= allowed[1]:
        return Comparison(label, unit, c, b, "within")
    p_value = paired_p_value(*tested, stride)
    return Comparison(label, unit, c, b, "worse" if p_value < config.significance else "not_significant", p_value)


def _errors(m: SourceMetrics | tuple, label: str) -> np.ndarray:
    """A source's per-window errors of ``label``: m for PRMSE, deg for ROE."""
    if isinstance(m, tuple):  # (kind, pos_err_m, rot_err_deg) of HeldOut.others
        return m[1] if label == "PRMSE" else m[2]
    return m.pos_err_m if label == "PRMSE" else m.rot_err_deg


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def within_sigma_of_zero(m: SourceMetrics, label: str, k: float) -> bool:
    """Whether ``m``'s mean bias is within ``k`` of its own sigmas of zero on every axis that ``label``
    depends on (ROE: the gyro; PRMSE: gyro and accelerometer); False for a source without sigma."""
    if m.mean_bias is None or m.mean_std is None:
        return False
    axes = slice(0, 3) if label == "ROE" else slice(0, 6)
    bias, std = np.asarray(m.mean_bias, float)[axes], np.asarray(m.mean_std, float)[axes]
    return bool(np.all(np.isfinite(std)) and np.all(std > 0) and np.all(np.abs(bias) <= k * std))


def _outcome(ev: Evidence, base: SourceMetrics, label: str) -> tuple[str | None, str]:
    """``(outcome, text)`` of the candidate against the baseline ``base`` (:func:`compare`, with the
    allowance of its own sigma)."""
    cand, config = ev.cand, ev.config
    sigma = config.sigma_k * (cand.sigma_prmse_m if label == "PRMSE" else cand.sigma_roe_deg)
    cmp = compare(label, _errors(cand, label), _errors(base, label), config, ev.stride, sigma)
    margin = f"the {config.margin:.0%} margin"
    if cmp.outcome == "within":
        return "within", f"{cmp.text}: worse beyond its own sigma, within {margin}"
    if cmp.outcome == "worse":
        return "worse", f"{cmp.text}: worse by more than {margin} and its own sigma (paired test p = {cmp.p_value:.2g})"
    if cmp.outcome == "not_significant":
        return "not_significant", (f"{cmp.text}: worse by more than {margin}, but not significantly over these "
                                   f"windows (paired test p = {cmp.p_value:.2g} >= {config.significance:g})")
    return None, ""



# ----------------------------------------------------------------------------- the comparison rules


def _against_zero_or_constant(ev: Evidence) -> list[tuple[str, Comparison, str, bool]]:
    """``(where, comparison, baseline, within_sigma_of_zero)`` of every comparison with the zero bias (in
    sample and held out) and with the constant bias (held out; in sample it is a baseline), by the one
    :func:`compare` without sigma allowance, where the candidate is worse than the baseline beyond the
    tie; ``within_sigma_of_zero`` for a zero baseline the candidate's bias is within its sigma of."""
    k, out = ev.config.sigma_k, []
    pairs = [("", ev.cand, zero.name, zero) for zero in ev.others(BiasSourceKind.ZERO)]
    if ev.heldout is not None:
        h = ev.heldout.metrics
        pairs += [("held out: ", h, name, other) for name, other in ev.heldout.others.items()
                  if other[0] in (BiasSourceKind.ZERO, BiasSourceKind.CONSTANT_FIRST_WINDOW)]
    for where, cand, name, base in pairs:
        is_zero = (base[0] if isinstance(base, tuple) else base.kind) is BiasSourceKind.ZERO
        for label in ("PRMSE", "ROE"):
            cmp = compare(label, _errors(cand, label), _errors(base, label), ev.config, ev.stride)
            if cmp.outcome is not None:
                out.append((where, cmp, name, is_zero and within_sigma_of_zero(cand, label, k)))
    return out


def worse_than(ev: Evidence, held_out: bool) -> list[str]:
    """Worse than the zero (or, held out, the constant) bias: beyond the margin and significantly."""
    out = []
    for where, cmp, name, _ in _against_zero_or_constant(ev):
        if cmp.outcome != "worse" or bool(where) != held_out:
            continue
        who = ev.heldout.metrics.name if held_out else ev.candidate
        n = len(ev.heldout.metrics.pos_err_m) if held_out else ev.cand.windows
        text = (f"{where}'{who}' {cmp.text} for the '{name}' bias on the same {n} windows: worse by more than the "
                f"{ev.config.margin:.0%} margin, significantly (paired test p = {cmp.p_value:.2g})")
        out.append(text + (": on poses it was not fitted to the recovered bias does worse than that bias (it absorbed "
                           "errors of the poses it saw)" if held_out else
                           ": subtracting it makes the integration worse than no bias estimate at all"))
    return out


def _tie_words(cmp: Comparison, config: ValidationConfig) -> str:
    if cmp.outcome == "within":
        return f"within the {config.margin:.0%} margin"
    return f"not significantly (paired test p = {cmp.p_value:.2g} >= {config.significance:g})"


def no_better(ev: Evidence, held_out: bool) -> list[str]:
    """Worse than the zero (or, held out, the constant) bias, but tied: within the margin or not
    significantly; a candidate within its own sigma of zero is :func:`indistinguishable` instead."""
    out = []
    for where, cmp, name, near_zero in _against_zero_or_constant(ev):
        if cmp.outcome == "worse" or near_zero or bool(where) != held_out:
            continue
        who = ev.heldout.metrics.name if held_out else ev.candidate
        out.append(f"{where}'{who}' {cmp.text} for the '{name}' bias, {_tie_words(cmp, ev.config)}: no better than "
                   "that bias")
    return out


def indistinguishable(ev: Evidence) -> list[str]:
    """A candidate (or its held-out version) within its own sigma of zero that ties the zero bias."""
    k = ev.config.sigma_k
    return [f"{where}'{ev.heldout.metrics.name if where else ev.candidate}' is indistinguishable from zero at its "
            f"sigma: its mean bias is within {k:g} of its sigmas of zero and its {cmp.text} for the zero bias, "
            f"{_tie_words(cmp, ev.config)}" for where, cmp, _, near_zero in _against_zero_or_constant(ev)
            if near_zero and cmp.outcome != "worse"]


def too_uncertain(ev: Evidence, base: SourceMetrics, label: str) -> list[str]:
    """The candidate's own sigma exceeds ``base``'s error: it excuses the candidate's error but leaves it
    too uncertain to be useful beside that baseline (an unobservable position-only recovery, say), when
    the candidate is also materially worse: by more than ``margin`` of what the baseline gains over the
    zero bias (a near-perfect baseline, a simulator's truth, makes any relative margin moot; without a
    zero row any excess counts)."""
    cand, config, zero = ev.cand, ev.config, ev.zero
    unit, attr, tie = ("m", "prmse_m", config.tie_prmse_m) if label == "PRMSE" else ("deg", "roe_deg", config.tie_roe_deg)
    k = config.sigma_k
    s = k * (cand.sigma_prmse_m if label == "PRMSE" else cand.sigma_roe_deg)
    c, b = getattr(cand, attr), getattr(base, attr)
    z = None if zero is None else getattr(zero, attr)
    material = z is None or c - b > config.margin * max(z - b, 0.0)
    if s > b + tie and c > b + tie and material:
        return [f"its own {k:g} sigma ({s:.4g} {unit} of {label}) exceed that baseline's error "
                f"({b:.4g} {unit}): too uncertain to tell it from the baseline"]
    return []


def against_baseline(ev: Evidence, base: SourceMetrics, label: str, outcome: str) -> list[str]:
    got, text = _outcome(ev, base, label)
    return [text] if got == outcome else []
