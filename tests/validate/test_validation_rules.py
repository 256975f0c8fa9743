"""The verdict's rule registry (validation.rules): one place for every rule, its code, level, wording and next step."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from pipeline.bias_table import BiasTrack
from pipeline.errors import RegistryError
from pipeline.sim import SimConfig, simulate
from pipeline.store import write_store
from pipeline.types import Verdict
from validation import rules
from validation.rules import RULES, Evidence, Rule, register, unregister
from validation.validate import validate_sequence, write_validation

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def short_sim():
    """8 s, noise-free IMU and poses: the true bias integrates to the truth (a clean PASS)."""
    return simulate(SimConfig(duration_s=8.0, seed=4).noise_free())


def _true_track(sim) -> BiasTrack:
    b = np.hstack([sim.truth.bias_gyro_radps, sim.truth.bias_acc_mps2])
    return BiasTrack(sim.truth.t_ns, b, np.zeros_like(b))


@pytest.fixture
def dummy_rule():
    """A WARN rule that fires on every candidate, registered for one test and removed after it."""
    def dummy_check(ev: Evidence) -> list[str]:
        return [f"dummy rule: '{ev.candidate}' was looked at by the dummy"]

    rule = register(Rule("DUMMY_RULE", Verdict.WARN, "the dummy rule of a test: fires on every candidate",
                         dummy_check, "do nothing: the dummy rule is a test's"))
    yield rule
    unregister(rule.code)
    assert "DUMMY_RULE" not in RULES


def test_every_rule_has_a_code_a_level_wording_and_is_listed_in_the_docs():
    docs = (ROOT / "docs" / "validation.md").read_text(encoding="utf-8")
    caption = (ROOT / "workflow" / "report" / "validate.rst").read_text(encoding="utf-8")
    for code, rule in RULES.items():
        assert code == rule.code and re.fullmatch(r"[A-Z][A-Z_]+", code)
        assert rule.level in (Verdict.WARN, Verdict.FAIL) and rule.wording
        assert f"`{code}`" in docs, f"{code} is not in docs/validation.md"
        assert f"``{code}``" in caption, f"{code} is not in workflow/report/validate.rst"
    with pytest.raises(RegistryError, match="NO_BASELINE already taken"):
        register(RULES["NO_BASELINE"])


def test_a_registered_rule_is_in_the_help_fires_in_validation_json_and_the_report(dummy_rule, short_sim, tmp_path,
                                                                                   capsys):
    from biasgt.cli.app import main
    from reports.quality import build_quality_report

    with pytest.raises(SystemExit):
        main(["validate", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "DUMMY_RULE (WARN): the dummy rule of a test: fires on every candidate" in help_text

    res = validate_sequence(short_sim.sequence, {"recovered": _true_track(short_sim)},
                            gravity_mps2=short_sim.truth.gravity_mps2)
    assert res.verdict is Verdict.WARN and res.reason_codes == ["DUMMY_RULE"], res.reasons
    write_validation(res, tmp_path / "val")
    data = json.loads((tmp_path / "val" / "validation.json").read_text())
    assert data["reasons"] == ["dummy rule: 'recovered' was looked at by the dummy"]
    assert data["reason_codes"] == ["DUMMY_RULE"]
    assert rules.next_steps_for(data["reason_codes"]) == ["do nothing: the dummy rule is a test's"]

    store = write_store(short_sim.sequence, tmp_path / "store")
    html = build_quality_report(store, validation_dir=tmp_path / "val", out_path=tmp_path / "q.html").read_text()
    assert "dummy rule: &#x27;recovered&#x27; was looked at by the dummy" in html
    assert '<code class="rule">DUMMY_RULE</code>' in html


def test_without_the_dummy_the_true_bias_passes(short_sim):
    res = validate_sequence(short_sim.sequence, {"recovered": _true_track(short_sim)},
                            gravity_mps2=short_sim.truth.gravity_mps2)
    assert res.verdict is Verdict.PASS and res.reasons == [] and res.reason_codes == []


def test_the_report_and_the_next_steps_key_on_codes_not_on_wording():
    from reports.quality_verdict import checked_and_not

    said = "not an independent test: the reference poses are those the recovery fitted"
    base = {"reference": {"kind": "poses", "stream": "mocap0"}, "config": {}, "windows_dropped": {}, "sources": {}}
    worded = checked_and_not({**base, "reasons": [said], "reason_codes": ["GIVEN_LIMITATION"]})
    coded = checked_and_not({**base, "reasons": ["(any wording)"], "reason_codes": ["NOT_INDEPENDENT"]})
    assert "Independent reference: yes." in worded and "Independent reference: no," in coded[1]
    assert rules.next_steps_for(["GIVEN_LIMITATION"]) == []
    assert rules.next_steps_for(["NOT_INDEPENDENT"]) == [RULES["NOT_INDEPENDENT"].next_step]
    # one step per cause, in the registry's order whatever the reasons' order
    steps = rules.next_steps_for(["ROE_WORSE_THAN_BASELINE", "PRMSE_WITHIN_MARGIN", "ROE_NOT_SIGNIFICANT"])
    assert steps == [RULES["PRMSE_WITHIN_MARGIN"].next_step, RULES["ROE_WORSE_THAN_BASELINE"].next_step]


# ----------------------------------------------------------------------------- worse than a baseline: one test


def _source(name: str, kind, value: float, n: int = 60, spread: float = 0.3, seed: int = 0, label: str = "ROE",
            mean_bias=None, mean_std=None):
    """A source whose per-window errors have exactly ``value`` as their ROE and PRMSE (the same pattern for
    every source with this ``seed``), with its mean bias and sigma."""
    from validation.metrics import SourceMetrics

    pattern = 1.0 + spread * np.random.default_rng(seed).standard_normal(n)
    pos = pattern * value / np.sqrt(np.mean(pattern ** 2))
    rot = pattern * value / np.mean(pattern)
    return SourceMetrics(name, kind, np.arange(n, dtype=np.int64), pos, rot, float(np.sqrt(np.mean(pos ** 2))),
                         float(np.mean(rot)), np.zeros(n, bool), 1.0, 1.0, np.zeros(n), np.zeros(n),
                         None if mean_bias is None else np.asarray(mean_bias, float),
                         mean_std=None if mean_std is None else np.asarray(mean_std, float))


SIGMA = np.array([2e-4, 2e-4, 2e-4, 5e-3, 5e-3, 5e-3])  # the candidate's own bias sigma (rad/s, m/s^2)


@pytest.mark.parametrize(("cand", "spread", "seed"), [
    (0.3424, 0.3, 0),   # the observed ROE tie: +0.4 % in every window (significant, but within the margin)
    (0.3700, 0.3, 0),   # +8.5 %: within the margin
    (0.4500, 0.8, 7),   # +32 %, but on windows too spread to say so: not significant
])
def test_a_tie_with_zero_within_its_own_sigma_is_never_a_fail(cand, spread, seed):
    from validation.sources import BiasSourceKind as K

    zero = _source("zero", K.ZERO, 0.3411, spread=spread)
    near_zero = 0.5 * SIGMA * np.array([1, -1, 1, -1, 1, -1])  # within one sigma of zero on every axis
    rec = _source("recovered", K.RECOVERED, cand, spread=spread, seed=seed, mean_bias=near_zero, mean_std=SIGMA)
    const = _source("constant", K.CONSTANT_FIRST_WINDOW, cand, spread=spread, seed=seed)  # what it is held constant
    metrics = {"zero": zero, "constant": const, "recovered": rec}
    verdict, reasons = rules.judge(Evidence(metrics, "recovered"))
    codes = [r.code for r in reasons]
    assert verdict is Verdict.WARN and "INDISTINGUISHABLE_FROM_ZERO" in codes, reasons
    assert "indistinguishable from zero at its sigma" in " ".join(r.text for r in reasons)
    # the same errors from a bias 3 sigmas off zero: no better than zero, still only a WARN
    far = dataclasses.replace(rec, mean_bias=3 * SIGMA)
    verdict, reasons = rules.judge(Evidence({**metrics, "recovered": far}, "recovered"))
    assert verdict is Verdict.WARN and "NO_BETTER_THAN_ZERO" in [r.code for r in reasons], reasons
    # held out: the same tie against zero is a WARN too
    held = rules.HeldOut(dataclasses.replace(rec, name="recovered_heldout"),
                         {"zero": (K.ZERO, zero.pos_err_m, zero.rot_err_deg)})
    good = _source("recovered", K.RECOVERED, 0.2, mean_bias=near_zero, mean_std=SIGMA)
    metrics = {**metrics, "recovered": good, "constant": _source("constant", K.CONSTANT_FIRST_WINDOW, 0.2)}
    verdict, reasons = rules.judge(Evidence(metrics, "recovered", heldout=held))
    assert verdict is Verdict.WARN and {r.code for r in reasons} == {"INDISTINGUISHABLE_FROM_ZERO"}, reasons
    assert all(r.text.startswith("held out: 'recovered_heldout' is indistinguishable from zero") for r in reasons)


def test_worse_than_zero_beyond_the_margin_and_significantly_fails_in_sample_and_held_out():
    from validation.sources import BiasSourceKind as K

    zero = _source("zero", K.ZERO, 0.30)
    bad = _source("recovered", K.RECOVERED, 0.40, mean_bias=10 * SIGMA, mean_std=SIGMA)  # +33 % in every window
    metrics = {"zero": zero, "constant": _source("constant", K.CONSTANT_FIRST_WINDOW, 0.5), "recovered": bad}
    verdict, reasons = rules.judge(Evidence(metrics, "recovered"))
    assert verdict is Verdict.FAIL and {"WORSE_THAN_ZERO"} <= {r.code for r in reasons}, reasons
    good = _source("recovered", K.RECOVERED, 0.2)
    held = rules.HeldOut(dataclasses.replace(bad, name="recovered_heldout"),
                         {"zero": (K.ZERO, zero.pos_err_m, zero.rot_err_deg)})
    verdict, reasons = rules.judge(Evidence({**metrics, "recovered": good}, "recovered", heldout=held))
    assert verdict is Verdict.FAIL and [r.code for r in reasons] == ["HELDOUT_WORSE", "HELDOUT_WORSE"], reasons


def test_the_in_sample_and_held_out_rules_share_one_comparison(monkeypatch):
    """Both rules decide by :func:`validation.rule_checks.compare.compare`, called on the in-sample candidate's and the
    held-out candidate's errors: forced to say "worse" both FAIL, forced to say "equal" neither fires."""
    from validation.sources import BiasSourceKind as K

    zero = _source("zero", K.ZERO, 0.30)
    rec = _source("recovered", K.RECOVERED, 0.30, seed=1)
    held = rules.HeldOut(_source("recovered_heldout", K.FILE, 0.30, seed=2),
                         {"zero": (K.ZERO, zero.pos_err_m, zero.rot_err_deg)})
    ev = Evidence({"zero": zero, "recovered": rec}, "recovered", heldout=held)
    calls = []
    from validation.rule_checks import compare as comparisons

    real = comparisons.compare

    def forced(outcome):
        def fake(label, cand_err, base_err, config, stride, sigma=0.0):
            calls.append(cand_err)
            got = real(label, cand_err, base_err, config, stride, sigma)
            return dataclasses.replace(got, outcome=outcome, p_value=0.0)
        return fake

    monkeypatch.setattr(comparisons, "compare", forced("worse"))
    verdict, reasons = rules.judge(ev)
    codes = [r.code for r in reasons]
    assert verdict is Verdict.FAIL and codes.count("WORSE_THAN_ZERO") == 2 and codes.count("HELDOUT_WORSE") == 2
    assert any(c is rec.pos_err_m for c in calls) and any(c is held.metrics.pos_err_m for c in calls)
    monkeypatch.setattr(comparisons, "compare", forced(None))
    assert rules.judge(ev)[0] is Verdict.WARN  # only "no baseline" left: nothing worse than zero


# ----------------------------------------------------------------------------- simulated recordings without bias


def _no_bias_simulation(seed: int, duration_s: float):
    """Handheld motion with no IMU bias at all, 120-Hz mocap with a 4-mrad 1-s correlated attitude error and 3
    dropouts (the pose stream only: the reference is the stream the bias is fitted to)."""
    from pipeline.sim.config import ImuNoiseConfig, PoseStreamConfig, TemperatureConfig

    sim = simulate(SimConfig(duration_s=duration_s, seed=seed,
                             imu=ImuNoiseConfig(bias_random_walk=False, turn_on_bias=False,
                                                temperature=TemperatureConfig(enabled=False)),
                             poses=PoseStreamConfig(rate_hz=120.0, correlated_rotation_noise_rad=0.004,
                                                    correlated_noise_tau_s=1.0, dropouts=3)))
    return dataclasses.replace(sim.sequence, ground_truth=None)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(5))
def test_no_simulated_recording_without_bias_fails(seed, tmp_path):
    """A recording without bias gives a recovered bias near zero that ties the zero bias, in sample and held
    out (6-s blocks, judged: the reference is the fitted stream): a WARN at most, never a FAIL; and the
    held-out bias integrates within 5 % of the in-sample one on the same windows (a recovery that absorbed no
    pose error loses nothing held out, edge blocks included). The recovery's defaults (noise by evidence), as
    a user runs it."""
    from recovery.recover import recover, write_recovery
    from validation.validate import ValidationConfig, validate_inputs

    seq = _no_bias_simulation(seed, 60.0)
    write_recovery(recover(seq), tmp_path / "rec")
    res = validate_inputs(seq, recovery_dir=tmp_path / "rec", config=ValidationConfig(crossval_block_s=6.0))
    assert res.heldout is not None and res.heldout["judged"] and res.heldout["windows"] > 40
    assert res.verdict is not Verdict.FAIL, list(zip(res.reason_codes, res.reasons))
    held, in_sample = res.sources["recovered_heldout"].prmse_m, res.heldout["others_on_these_windows"]["recovered"]
    assert held <= 1.05 * in_sample["prmse_m"], (held, in_sample)
