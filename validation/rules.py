"""Every rule of the validation's verdict, in one registry (:data:`RULES`).

A :class:`Rule` has a stable reason code, its level (what it contributes when it fires: WARN or
FAIL), one line of wording (what it checks: ``biasgt validate --help``, docs/validation.md and the
workflow's report caption list these), the next step it recommends (or none) and a check: a
function of the :class:`Evidence` that returns one text per time it fires. A rule with
``per_baseline`` is checked against each baseline (constant and dataset bias) in turn, its texts
prefixed with the candidate and the baseline.

The verdict (:func:`judge`): FAIL when a FAIL rule fires, else WARN when any rule fires, else PASS.
The reasons are the FAIL texts then the WARN texts, each in registry order (per-baseline rules next to
each other are checked baseline by baseline); ``validation.json`` holds their codes beside them
(``reason_codes``), and the next steps (:func:`next_steps_for`) and the quality report key on the
codes, never on the wording.

Adding a rule: one check function and one :func:`register` line.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.registry import Registry
from pipeline.types import Finding, Severity, Verdict
from validation.config import BiasSourceKind, ValidationConfig

if TYPE_CHECKING:  # validation.metrics imports torch, validation.plausibility scipy: off the CLI's start-up path
    from validation.metrics import SourceMetrics
    from validation.plausibility import Implausible

__all__ = ["RULES", "Evidence", "HeldOut", "Reason", "Rule", "VerdictInputs", "judge", "next_steps_for", "register",
           "rules_text", "said_once", "unregister"]


# ----------------------------------------------------------------------------- the registry's types


@dataclass(frozen=True)
class Reason:
    """One reason of a verdict: the rule's code, its level and what was found (a plain sentence)."""

    code: str
    level: Verdict
    text: str


@dataclass(frozen=True)
class HeldOut:
    """The held-out (cross-validated) candidate on the windows it covers, with the baselines' errors on
    the same windows, when it judges the verdict.

    Attributes:
        metrics: Its metrics on those windows (``mean_bias`` and ``mean_std``: the folds' bias and sigma).
        others: ``{name: (kind, pos_err_m [W], rot_err_deg [W])}`` of every other source on these windows.
    """

    metrics: SourceMetrics
    others: Mapping[str, tuple[BiasSourceKind, np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class VerdictInputs:
    """What the verdict knows beyond the integration errors (:func:`validation.validate.validate_inputs`).

    Attributes:
        findings: The input's findings (its limiting WARNINGs make a PASS a WARN).
        recovery: The recovery's ``recovery.json`` (``RecoveryOutputs.report``: ``.get(key)``), or None.
        implausible: What physics rules out in the recovery (:mod:`validation.plausibility`).
        not_independent: The reference is the stream the bias was fitted to and no held-out blocks judge.
        crossval_ran: The cross-validation ran (and could not judge: no fold recovered).
    """

    findings: tuple[Finding, ...] = ()
    recovery: Any = None
    implausible: tuple[Implausible, ...] = ()
    not_independent: bool = False
    crossval_ran: bool = False


@dataclass(frozen=True)
class Evidence:
    """Everything a rule may look at.

    Attributes:
        metrics: Per source, on the kept windows.
        candidate: The source judged.
        config: Thresholds.
        dropped_fraction: Fraction of the candidate windows dropped.
        heldout: The held-out candidate, when it judges the verdict.
        inputs: See :class:`VerdictInputs`.
        given_fails / given_limitations: Reasons found by a caller (FAIL / WARN), listed as such.
    """

    metrics: Mapping[str, SourceMetrics]
    candidate: str
    config: ValidationConfig = ValidationConfig()
    dropped_fraction: float = 0.0
    heldout: HeldOut | None = None
    inputs: VerdictInputs = VerdictInputs()
    given_fails: tuple[str, ...] = ()
    given_limitations: tuple[str, ...] = ()

    @property
    def cand(self) -> SourceMetrics:
        return self.metrics[self.candidate]

    def others(self, *kinds: BiasSourceKind) -> list[SourceMetrics]:
        """The sources other than the candidate of these kinds, in evaluation order."""
        return [m for name, m in self.metrics.items() if name != self.candidate and m.kind in kinds]

    @property
    def baselines(self) -> list[SourceMetrics]:
        return self.others(BiasSourceKind.CONSTANT_FIRST_WINDOW, BiasSourceKind.DATASET)

    @property
    def zero(self) -> SourceMetrics | None:
        return next(iter(self.others(BiasSourceKind.ZERO)), None)

    @property
    def stride(self) -> int:
        """Every ``stride``-th window is independent of the last (no shared samples)."""
        return max(1, int(round(1.0 / (1.0 - self.config.overlap))))


@dataclass(frozen=True)
class Rule:
    """One verdict rule (see the module docstring).

    Attributes:
        code: Stable reason code (``validation.json`` ``reason_codes``).
        level: WARN or FAIL: what the rule contributes when it fires.
        wording: What it checks, one line.
        check: ``(evidence) -> [text]``, or ``(evidence, baseline) -> [text]`` with ``per_baseline``.
        next_step: What the user can do when it fires (None: no step of its own).
        per_baseline: Checked against each baseline.
    """

    code: str
    level: Verdict
    wording: str
    check: Callable[..., list[str]] = field(repr=False)
    next_step: str | None = None
    per_baseline: bool = False


#: Every rule, by code, in the order the reasons are listed.
RULES: Registry[Rule] = Registry("rule")


def register(rule: Rule, *, before: str | None = None) -> Rule:
    """Add ``rule`` to :data:`RULES` (at the end, or before the rule ``before``); returns it.

    Raises:
        ValueError: Its code is taken, its level is PASS, or ``before`` is not a rule.
    """
    if rule.level is Verdict.PASS:
        raise ValueError(f"rule {rule.code!r}: a rule's level is WARN or FAIL, not PASS")
    return RULES.add(rule.code, rule, before=before)


def unregister(code: str) -> None:
    """Remove the rule ``code`` (a test's dummy rule)."""
    RULES.remove(code)


# ----------------------------------------------------------------------------- the engine


def judge(evidence: Evidence) -> tuple[Verdict, list[Reason]]:
    """The verdict and its reasons: every rule of :data:`RULES` checked on ``evidence``."""
    fired: list[Reason] = []
    rules = list(RULES.values())
    i = 0
    while i < len(rules):
        if not rules[i].per_baseline:
            fired += [Reason(rules[i].code, rules[i].level, t) for t in rules[i].check(evidence)]
            i += 1
            continue
        j = i
        while j < len(rules) and rules[j].per_baseline:
            j += 1
        for base in evidence.baselines:  # a run of per-baseline rules: baseline by baseline
            where = f"'{evidence.candidate}' against '{base.name}' ({base.kind.value})"
            for rule in rules[i:j]:
                fired += [Reason(rule.code, rule.level, f"{where}: {t}") for t in rule.check(evidence, base)]
        i = j
    fails = [r for r in fired if r.level is Verdict.FAIL]
    warns = [r for r in fired if r.level is not Verdict.FAIL]
    verdict = Verdict.FAIL if fails else Verdict.WARN if warns else Verdict.PASS
    return verdict, fails + warns


def next_steps_for(codes: Sequence_[str]) -> list[str]:
    """The next steps of the rules ``codes`` (each said once, in the registry's order of first mention;
    a step another repeats with more words is kept the longer way)."""
    first: dict[str, int] = {}
    for i, rule in enumerate(RULES.values()):
        if rule.next_step:
            first.setdefault(rule.next_step, i)
    steps = {RULES[c].next_step for c in codes if c in RULES and RULES[c].next_step}
    return said_once(sorted(steps, key=first.__getitem__))


def said_once(steps: Sequence_[str]) -> list[str]:
    """``steps`` without repeats: a step that another repeats with more words is kept the longer way."""
    steps = list(dict.fromkeys(steps))
    return [s for s in steps if not any(o != s and o.startswith(s) for o in steps)]


def rules_text(width: int = 100) -> str:
    """The rules as help text: one ``CODE (LEVEL): wording`` entry per rule, wrapped to ``width``."""
    import textwrap

    return "\n".join(textwrap.fill(f"{r.code} ({r.level.value}): {r.wording}", width, initial_indent="  ",
                                   subsequent_indent="      ") for r in RULES.values())


# ----------------------------------------------------------------------------- shared tests


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


# ----------------------------------------------------------------------------- rule checks


def _given_fails(ev: Evidence) -> list[str]:
    return list(ev.given_fails)


def _given_limitations(ev: Evidence) -> list[str]:
    return list(ev.given_limitations)


def _implausible(check: str, ev: Evidence) -> list[str]:
    return [x.text for x in ev.inputs.implausible if x.check == check]


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


def _worse_than(ev: Evidence, held_out: bool) -> list[str]:
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


def _no_better(ev: Evidence, held_out: bool) -> list[str]:
    """Worse than the zero (or, held out, the constant) bias, but tied: within the margin or not
    significantly; a candidate within its own sigma of zero is :func:`_indistinguishable` instead."""
    out = []
    for where, cmp, name, near_zero in _against_zero_or_constant(ev):
        if cmp.outcome == "worse" or near_zero or bool(where) != held_out:
            continue
        who = ev.heldout.metrics.name if held_out else ev.candidate
        out.append(f"{where}'{who}' {cmp.text} for the '{name}' bias, {_tie_words(cmp, ev.config)}: no better than "
                   "that bias")
    return out


def _indistinguishable(ev: Evidence) -> list[str]:
    """A candidate (or its held-out version) within its own sigma of zero that ties the zero bias."""
    k = ev.config.sigma_k
    return [f"{where}'{ev.heldout.metrics.name if where else ev.candidate}' is indistinguishable from zero at its "
            f"sigma: its mean bias is within {k:g} of its sigmas of zero and its {cmp.text} for the zero bias, "
            f"{_tie_words(cmp, ev.config)}" for where, cmp, _, near_zero in _against_zero_or_constant(ev)
            if near_zero and cmp.outcome != "worse"]


def _input_finding(code: str, ev: Evidence) -> list[str]:
    return [f"input: {f.message}" for f in ev.inputs.findings if f.code == code and f.severity is Severity.WARNING]


def _random_walks(ev: Evidence) -> list[tuple[str, bool, float, list]]:
    """``(axis, at_edge, scale, grid)`` of each finite random-walk scale of the recovery."""
    report = ev.inputs.recovery or {}
    noise = report.get("noise") if isinstance(report.get("noise"), Mapping) else {}
    grid = (report.get("config") or {}).get("random_walk_scales") or []
    out = []
    for axis in ("gyro", "acc"):
        scale = noise.get(f"{axis}_random_walk_scale")
        if isinstance(scale, (int, float)) and math.isfinite(scale):
            out.append((axis, bool(noise.get("method") == "evidence" and grid and scale >= max(grid)), scale, grid))
    return out


def _random_walk_at_edge(ev: Evidence) -> list[str]:
    # Only the upper edge limits the bias: a walk that wants to be looser than the search allows means
    # the bias absorbs other errors. At the lower edge (a nearly constant bias, e.g. the semi-real
    # sequences' EuRoC bias) the recovered bias is only a little less smooth than it could be, and its
    # sigma errs on the safe side.
    return [f"the {axis} bias random walk was chosen at the upper edge of its search ({scale:g}x the "
            f"calibration; searched {min(grid):g}x-{max(grid):g}x): the bias may absorb other errors"
            for axis, edge, scale, grid in _random_walks(ev) if edge]


def _random_walk_far(ev: Evidence) -> list[str]:
    k = ev.config.max_random_walk_scale
    return [f"the {axis} bias random walk is {scale:.3g}x the calibration's: the bias likely absorbs unmodelled "
            "errors (scale, misalignment, pose artefacts) or the datasheet is off"
            for axis, edge, scale, _ in _random_walks(ev) if not edge and not 1.0 / k <= scale <= k]


def _extrinsic_differs(ev: Evidence) -> list[str]:
    diff = ((ev.inputs.recovery or {}).get("extrinsic") or {}).get("difference_from_calibration") or {}
    if not diff.get("exceeds"):
        return []
    return [f"the extrinsic T_imu_pose estimated from the data differs from the calibration's by "
            f"{diff['rotation_deg']:.2f} deg and {100 * diff['translation_m']:.1f} cm, beyond "
            f"{diff['max_sigmas']:g} of its sigmas: the calibration file is off (or the tracked body moved); the "
            "bias is the one consistent with the estimate"]


def _extrinsic_unobservable(ev: Evidence) -> list[str]:
    if (ev.inputs.recovery or {}).get("extrinsic_rotation_observable") is not False:
        return []
    return ["the rotation between the pose frame and the IMU was not observable (too little rotation): the "
            "calibration's or the identity was used, and the bias absorbs any error in it"]


def _not_independent(ev: Evidence) -> list[str]:
    if not ev.inputs.not_independent:
        return []
    return ["not an independent test: the reference poses are those the recovery fitted, so pose errors that the "
            "bias absorbed are not seen" + (" (and no cross-validation fold could be recovered)"
                                            if ev.inputs.crossval_ran else "")]


def _too_uncertain(label: str, ev: Evidence, base: SourceMetrics) -> list[str]:
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


def _against_baseline(label: str, outcome: str, ev: Evidence, base: SourceMetrics) -> list[str]:
    got, text = _outcome(ev, base, label)
    return [text] if got == outcome else []


def _flagged(ev: Evidence) -> list[str]:
    cand, limit = ev.cand, ev.config.warn_flagged_fraction
    if not cand.windows or not float(np.mean(cand.flagged)) > limit:
        return []
    frac = float(np.mean(cand.flagged))
    return [f"{int(cand.flagged.sum())} of {cand.windows} windows ({frac:.1%}) of '{ev.candidate}' are flagged as "
            f"outliers (more than {limit:.0%})"]


def _dropped(ev: Evidence) -> list[str]:
    limit = ev.config.warn_dropped_fraction
    if not ev.dropped_fraction > limit:
        return []
    return [f"{ev.dropped_fraction:.1%} of the windows were dropped (more than {limit:.0%}): the validation covers "
            "only part of the sequence"]


def _no_baseline(ev: Evidence) -> list[str]:
    return [] if ev.baselines else [f"no baseline (constant or dataset bias) to compare '{ev.candidate}' with"]


# ----------------------------------------------------------------------------- the rules, in reason order

_NOISE_STEP = ("check the IMU noise values of the calibration (sensor.yaml: random walks) against the datasheet, and "
               "the pose stream for artefacts (biasgt report's residual plot)")
_POSITION_STEP = ("position error: record more varied motion (accelerate along and rotate about every axis) so the "
                  "accelerometer bias separates from attitude and gravity; prefer a 6-DoF pose source (motion "
                  "capture) to position-only; check the accelerometer units ('biasgt inspect')")
_ROTATION_STEP = ("rotation error: check the gyro units and the pose-to-IMU rotation (recovery.json T_imu_pose), and "
                  "rotate more about every axis")
_HELDOUT_STEP = ("held out the bias does no better than a simpler one: look for pose artefacts the bias absorbed "
                 "(biasgt report's residual plot), and validate against an independent reference if there is one")
_ZERO_STEP = ("the bias does no better than none: check the IMU units and the pose-to-IMU frame ('biasgt inspect', "
              "recovery.json T_imu_pose), and whether the IMU's bias is measurable at all in this recording")
#: Input findings that limit what a bias recovered from that input is good for: (what, next step).
_LIMITING_FINDINGS = {
    "POSE_RATE_LOW": ("the pose stream is slow",
                      "use a faster pose stream (motion capture at 100 Hz or more) if the recording has one"),
    "CALIBRATION_DEFAULTED": ("the IMU noise values are defaults",
                              "give the IMU's own noise values (sensor.yaml or the recovery config) and recover again"),
    "SATURATION": ("the IMU saturates", "record with a larger sensor range, or drop the saturated stretches"),
    "STAMP_UNIT_GUESSED": ("the stamps' unit was guessed",
                           "write the stamps as integer nanoseconds so that their unit is not guessed"),
    "IMU_RATE_MISMATCH": ("the IMU runs off the calibration's rate",
                          "resample the IMU to the calibration's rate (biasgt convert --resample-hz) or correct "
                          "rate_hz in sensor.yaml, and recover again"),
}
#: The next step of a bias beyond the sensor's range.
BIAS_RANGE_STEP = ("if the sensor's bias range is larger, give it in sensor.yaml (gyroscope_bias_max [rad/s], "
                   "accelerometer_bias_max [m/s^2]); else check the pose-to-IMU frame")
#: The next step of a frame mismatch.
FRAME_STEP = ("check the pose-to-IMU rotation: give the IMU's mounting (T_imu_<frame> in the calibration, e.g. "
               "from the URDF or a Kalibr run) and recover again, or recover with --extrinsic estimate so that the "
               "rotation is estimated; a pose stream that lacks rotation about some axis (planar wheel odometry) "
               "cannot give a bias ground truth")


#: The plausibility checks (validation.plausibility.PlausibilityCheck values): (what, next step).
_IMPLAUSIBLE_WORDS = {
    "bias_range": ("a bias beyond the sensor's bias range", BIAS_RANGE_STEP),
    "gravity_tilt": ("gravity tilted in a level pose frame, or changing direction", FRAME_STEP),
    "rotation_residual": ("the recovered attitude far off the poses'", FRAME_STEP),
    "frame_swap": ("a gyro axis reading another axis's rate (a swapped frame)", FRAME_STEP),
}

register(Rule("GIVEN_FAIL", Verdict.FAIL, "a reason for a FAIL found by the caller", _given_fails))
for _check, (_what, _step) in _IMPLAUSIBLE_WORDS.items():
    register(Rule(f"IMPLAUSIBLE_{_check.upper()}", Verdict.FAIL, f"physically impossible: {_what}, whatever the "
                  "integration errors", partial(_implausible, _check), _step))
register(Rule("HELDOUT_WORSE", Verdict.FAIL, "held out (the reference is the stream the bias was fitted to): worse "
              "than the zero or the constant bias on the held-out windows by more than the margin and significantly "
              "(paired t-test)", partial(_worse_than, held_out=True), _HELDOUT_STEP))
register(Rule("HELDOUT_NO_BETTER", Verdict.WARN, "held out: worse than the zero or the constant bias on the "
              "held-out windows, but within the margin or not significantly: no better than that bias",
              partial(_no_better, held_out=True), _HELDOUT_STEP))
for _code, (_what, _step) in _LIMITING_FINDINGS.items():
    register(Rule(f"INPUT_{_code}", Verdict.WARN, f"limitation: {_what} (input finding {_code})",
                  partial(_input_finding, _code), _step))
register(Rule("RANDOM_WALK_AT_EDGE", Verdict.WARN, "limitation: a bias random walk chosen at the upper edge of "
              "its evidence search", _random_walk_at_edge,
              _NOISE_STEP + "; widen recovery.random_walk_scales only if the calibration is known to be wrong"))
register(Rule("RANDOM_WALK_FAR", Verdict.WARN, "limitation: a bias random walk more than max_random_walk_scale "
              "times off the calibration's", _random_walk_far, _NOISE_STEP))
register(Rule("EXTRINSIC_DIFFERS", Verdict.WARN, "limitation: the extrinsic estimated from the data differs from "
              "the calibration's beyond its sigmas", _extrinsic_differs,
              "if the tracked body was not moved, put the estimate (recovery.json T_imu_pose) into the calibration "
              "file; else check the mount and recover again"))
register(Rule("EXTRINSIC_UNOBSERVABLE", Verdict.WARN, "limitation: the pose-to-IMU rotation was not observable",
              _extrinsic_unobservable,
              "record a stretch rotating about every axis, or give T_imu_pose in the calibration and recover "
              "with --extrinsic known"))
register(Rule("NOT_INDEPENDENT", Verdict.WARN, "limitation: the reference is the pose stream the bias was fitted "
              "to and no held-out blocks judge", _not_independent,
              "validate against another pose stream or a ground truth (--poses STREAM, --add-poses FILE:KIND), or "
              "cross-validate (--crossval on)"))
register(Rule("GIVEN_LIMITATION", Verdict.WARN, "a limitation found by the caller", _given_limitations))
for _label, _step in (("PRMSE", _POSITION_STEP), ("ROE", _ROTATION_STEP)):
    register(Rule(f"{_label}_TOO_UNCERTAIN", Verdict.WARN, f"{_label}: its own sigma exceeds a baseline's error "
                  "and it is materially worse: too uncertain to tell from the baseline",
                  partial(_too_uncertain, _label), _step, per_baseline=True))
for _label, _step in (("PRMSE", _POSITION_STEP), ("ROE", _ROTATION_STEP)):
    register(Rule(f"{_label}_WORSE_THAN_BASELINE", Verdict.FAIL, f"{_label} worse than a baseline (constant or "
                  "dataset bias) by more than its own sigma and the margin, significantly (paired t-test over "
                  "non-overlapping windows)", partial(_against_baseline, _label, "worse"), _step, per_baseline=True))
for _label, _step in (("PRMSE", _POSITION_STEP), ("ROE", _ROTATION_STEP)):
    register(Rule(f"{_label}_WITHIN_MARGIN", Verdict.WARN, f"{_label} worse than a baseline beyond its own sigma, "
                  "within the margin", partial(_against_baseline, _label, "within"), _step, per_baseline=True))
    register(Rule(f"{_label}_NOT_SIGNIFICANT", Verdict.WARN, f"{_label} worse than a baseline by more than the "
                  "margin, not significantly", partial(_against_baseline, _label, "not_significant"), _step,
                  per_baseline=True))
register(Rule("WORSE_THAN_ZERO", Verdict.FAIL, "PRMSE or ROE worse than the zero bias by more than the margin "
              "and significantly (paired t-test), whatever its sigma", partial(_worse_than, held_out=False),
              _ZERO_STEP))
register(Rule("NO_BETTER_THAN_ZERO", Verdict.WARN, "PRMSE or ROE worse than the zero bias, but within the margin or "
              "not significantly: no better than no bias estimate", partial(_no_better, held_out=False), _ZERO_STEP))
register(Rule("INDISTINGUISHABLE_FROM_ZERO", Verdict.WARN, "the candidate (or its held-out version) is within its "
              "own sigma of zero and ties the zero bias: indistinguishable from zero at its sigma (never a FAIL)",
              _indistinguishable, "nothing to fix if the IMU's bias is near zero: the recording cannot tell it from "
              "zero; for a bias to learn from, record longer or with more motion so its sigma shrinks"))
register(Rule("MANY_FLAGGED", Verdict.WARN, "more than warn_flagged_fraction of the candidate's windows flagged "
              "as outliers (error > flag_k x its median)", _flagged,
              "many flagged windows: look at them in the quality report (pose outliers, IMU glitches); recover with "
              "a robust loss ('--robust cauchy') if the poses have outliers"))
register(Rule("MANY_DROPPED", Verdict.WARN, "more than warn_dropped_fraction of the windows dropped", _dropped,
              "many dropped windows: close the IMU gaps or cover the whole IMU span with poses "
              "(windows_dropped.by_reason in validation.json says which)"))
register(Rule("NO_BASELINE", Verdict.WARN, "no constant or dataset bias to compare with", _no_baseline))
del _check, _what, _step, _code, _label
