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

The registry's form is :mod:`pipeline.registry`'s: the :data:`BUILTIN` tuple, :func:`register` and
:func:`unregister`, plugins found through the ``biasgt.rules`` entry points. The checks live in
:mod:`validation.rule_checks`, named as ``"module:function"`` and imported when the verdict is judged,
so that listing the rules (``biasgt validate --help``) imports no numerics. Adding a rule: its check in
a module of :mod:`validation.rule_checks` and one :class:`Rule` line in :data:`BUILTIN`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.errors import RegistryError
from pipeline.registry import Registry, resolve
from pipeline.types import Finding, Verdict
from validation.config import BiasSourceKind, ValidationConfig

if TYPE_CHECKING:  # validation.metrics imports torch, validation.plausibility scipy: off the CLI's start-up path
    from validation.metrics import SourceMetrics
    from validation.plausibility import Implausible

__all__ = ["BUILTIN", "RULES", "Evidence", "HeldOut", "Reason", "Rule", "VerdictInputs", "judge", "next_steps_for",
           "register", "rules_text", "said_once", "unregister"]


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
        sigma_check: The held-out test of the recovery's sigma (:mod:`validation.crossval.sigma`,
            ``SigmaCheck.to_dict``), or None.
    """

    findings: tuple[Finding, ...] = ()
    recovery: Any = None
    implausible: tuple[Implausible, ...] = ()
    not_independent: bool = False
    crossval_ran: bool = False
    sigma_check: Mapping[str, Any] | None = None


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
        recording_s: The recording's IMU span (s), None when not known.
    """

    metrics: Mapping[str, SourceMetrics]
    candidate: str
    config: ValidationConfig = ValidationConfig()
    dropped_fraction: float = 0.0
    heldout: HeldOut | None = None
    inputs: VerdictInputs = VerdictInputs()
    given_fails: tuple[str, ...] = ()
    given_limitations: tuple[str, ...] = ()
    recording_s: float | None = None

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
        check: ``(evidence, *args) -> [text]``, or ``(evidence, baseline, *args) -> [text]`` with
            ``per_baseline``; a callable or its ``"module:function"`` (imported when first judged).
        next_step: What the user can do when it fires (None: no step of its own).
        per_baseline: Checked against each baseline.
        args: Further arguments of ``check`` (one check function serving a family of rules).
    """

    code: str
    level: Verdict
    wording: str
    check: Callable[..., list[str]] | str = field(repr=False)
    next_step: str | None = None
    per_baseline: bool = False
    args: tuple[Any, ...] = ()

    def fired(self, evidence: Evidence, *baseline: SourceMetrics) -> list[str]:
        """The texts of the times the rule fires on ``evidence`` (against ``baseline`` when per baseline)."""
        return list(resolve(self.check)(evidence, *baseline, *self.args))


# ----------------------------------------------------------------------------- the engine


def judge(evidence: Evidence) -> tuple[Verdict, list[Reason]]:
    """The verdict and its reasons: every rule of :data:`RULES` checked on ``evidence``."""
    fired: list[Reason] = []
    rules = list(RULES.values())
    i = 0
    while i < len(rules):
        if not rules[i].per_baseline:
            fired += [Reason(rules[i].code, rules[i].level, t) for t in rules[i].fired(evidence)]
            i += 1
            continue
        j = i
        while j < len(rules) and rules[j].per_baseline:
            j += 1
        for base in evidence.baselines:  # a run of per-baseline rules: baseline by baseline
            where = f"'{evidence.candidate}' against '{base.name}' ({base.kind.value})"
            for rule in rules[i:j]:
                fired += [Reason(rule.code, rule.level, f"{where}: {t}") for t in rule.fired(evidence, base)]
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
_SIGMA_STEP = ("use the bias sigma widened by validation.json's heldout.sigma_check.factor (per axis) where a "
               "sigma matters (the window dataset's labels carry it); the recovery did not model an error of this "
               "rig (a correlated pose error, a pose frame not level, IMU scale or misalignment): check the pose "
               "stream (biasgt report's residual plot) and the IMU's calibration, and recover again")
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


_C, _L = "validation.rule_checks.compare", "validation.rule_checks.limitations"
_ERRORS = (("PRMSE", _POSITION_STEP), ("ROE", _ROTATION_STEP))
#: The rules biasgt ships, in the order the reasons are listed.
BUILTIN = (
    Rule("GIVEN_FAIL", Verdict.FAIL, "a reason for a FAIL found by the caller", f"{_L}:given_fails"),
    *(Rule(f"IMPLAUSIBLE_{check.upper()}", Verdict.FAIL, f"physically impossible: {what}, whatever the integration "
           "errors", f"{_L}:implausible", step, args=(check,)) for check, (what, step) in _IMPLAUSIBLE_WORDS.items()),
    Rule("HELDOUT_WORSE", Verdict.FAIL, "held out (the reference is the stream the bias was fitted to): worse than the "
         "zero or the constant bias on the held-out windows by more than the margin and significantly (paired t-test)",
         f"{_C}:worse_than", _HELDOUT_STEP, args=(True,)),
    Rule("HELDOUT_NO_BETTER", Verdict.WARN, "held out: worse than the zero or the constant bias on the held-out "
         "windows, but within the margin or not significantly: no better than that bias", f"{_C}:no_better",
         _HELDOUT_STEP, args=(True,)),
    *(Rule(f"INPUT_{code}", Verdict.WARN, f"limitation: {what} (input finding {code})", f"{_L}:input_finding", step,
           args=(code,)) for code, (what, step) in _LIMITING_FINDINGS.items()),
    Rule("RANDOM_WALK_AT_EDGE", Verdict.WARN, "limitation: a bias random walk chosen at the upper edge of its evidence "
         "search", f"{_L}:random_walk_at_edge",
         _NOISE_STEP + "; widen recovery.random_walk_scales only if the calibration is known to be wrong"),
    Rule("RANDOM_WALK_FAR", Verdict.WARN, "limitation: a bias random walk more than max_random_walk_scale times off the "
         "calibration's", f"{_L}:random_walk_far", _NOISE_STEP),
    Rule("EXTRINSIC_DIFFERS", Verdict.WARN, "limitation: the extrinsic estimated from the data differs from the "
         "calibration's beyond its sigmas", f"{_L}:extrinsic_differs",
         "if the tracked body was not moved, put the estimate (recovery.json T_imu_pose) into the calibration file; "
         "else check the mount and recover again"),
    Rule("EXTRINSIC_UNOBSERVABLE", Verdict.WARN, "limitation: the pose-to-IMU rotation was not observable",
         f"{_L}:extrinsic_unobservable",
         "record a stretch rotating about every axis, or give T_imu_pose in the calibration and recover with "
         "--extrinsic known"),
    Rule("NOT_INDEPENDENT", Verdict.WARN, "limitation: the reference is the pose stream the bias was fitted to and no "
         "held-out blocks judge", f"{_L}:not_independent",
         "validate against another pose stream or a ground truth (--poses STREAM, --add-poses FILE:KIND), or "
         "cross-validate (--crossval on)"),
    Rule("SIGMA_NOT_CONFIRMED", Verdict.WARN, "limitation: held out, the bias differs from the in-sample bias "
         "block by block beyond what both sigmas allow (chi-square bound): the sigma is not confirmed held out",
         f"{_L}:sigma_not_confirmed", _SIGMA_STEP),
    Rule("GIVEN_LIMITATION", Verdict.WARN, "a limitation found by the caller", f"{_L}:given_limitations"),
    *(Rule(f"{label}_TOO_UNCERTAIN", Verdict.WARN, f"{label}: its own sigma exceeds a baseline's error and it is "
           "materially worse: too uncertain to tell from the baseline", f"{_C}:too_uncertain", step,
           per_baseline=True, args=(label,)) for label, step in _ERRORS),
    *(Rule(f"{label}_WORSE_THAN_BASELINE", Verdict.FAIL, f"{label} worse than a baseline (constant or dataset bias) "
           "by more than its own sigma and the margin, significantly (paired t-test over non-overlapping windows)",
           f"{_C}:against_baseline", step, per_baseline=True, args=(label, "worse")) for label, step in _ERRORS),
    *(rule for label, step in _ERRORS for rule in (
        Rule(f"{label}_WITHIN_MARGIN", Verdict.WARN, f"{label} worse than a baseline beyond its own sigma, within the "
             "margin", f"{_C}:against_baseline", step, per_baseline=True, args=(label, "within")),
        Rule(f"{label}_NOT_SIGNIFICANT", Verdict.WARN, f"{label} worse than a baseline by more than the margin, not "
             "significantly", f"{_C}:against_baseline", step, per_baseline=True, args=(label, "not_significant")))),
    Rule("WORSE_THAN_ZERO", Verdict.FAIL, "PRMSE or ROE worse than the zero bias by more than the margin and "
         "significantly (paired t-test), whatever its sigma", f"{_C}:worse_than", _ZERO_STEP, args=(False,)),
    Rule("NO_BETTER_THAN_ZERO", Verdict.WARN, "PRMSE or ROE worse than the zero bias, but within the margin or not "
         "significantly: no better than no bias estimate", f"{_C}:no_better", _ZERO_STEP, args=(False,)),
    Rule("INDISTINGUISHABLE_FROM_ZERO", Verdict.WARN, "the candidate (or its held-out version) is within its own sigma "
         "of zero and ties the zero bias: indistinguishable from zero at its sigma (never a FAIL)",
         f"{_C}:indistinguishable", "nothing to fix if the IMU's bias is near zero: the recording cannot tell it "
         "from zero; for a bias to learn from, record longer or with more motion so its sigma shrinks"),
    Rule("MANY_FLAGGED", Verdict.WARN, "more than warn_flagged_fraction of the candidate's windows flagged as outliers "
         "(error > flag_k x its median)", f"{_L}:flagged",
         "many flagged windows: look at them in the quality report (pose outliers, IMU glitches); recover with a "
         "robust loss ('--robust cauchy') if the poses have outliers"),
    Rule("MANY_DROPPED", Verdict.WARN, "more than warn_dropped_fraction of the windows dropped", f"{_L}:dropped",
         "many dropped windows: close the IMU gaps or cover the whole IMU span with poses "
         "(windows_dropped.by_reason in validation.json says which)"),
    Rule("NO_BASELINE", Verdict.WARN, "no constant or dataset bias to compare with", f"{_L}:no_baseline"),
)


def _check_level(rule: Rule, entries: Mapping[str, Rule]) -> None:
    if Verdict(rule.level) is Verdict.PASS:
        raise RegistryError(f"cannot register rule {rule.code!r}: a rule's level is WARN or FAIL, not PASS",
                            field="level", hint="give Verdict.WARN or Verdict.FAIL")


#: Every rule, by code, in the order the reasons are listed.
RULES: Registry[Rule] = Registry("rule", BUILTIN, entry_type=Rule, key=lambda r: r.code, check=_check_level)


def register(rule: Rule, *, before: str | None = None) -> Rule:
    """Add ``rule`` to :data:`RULES` (at the end, or before the rule ``before``); returns it.

    Raises:
        RegistryError: Its code is taken, its level is PASS, or ``before`` is not a rule.
    """
    return RULES.register(rule, before=before)


def unregister(code: str) -> None:
    """Remove the rule ``code`` (nothing when it is not registered)."""
    RULES.unregister(code)
