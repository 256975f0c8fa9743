"""The verdict's rule registry (validation.rules): one place for every rule, its code, level, wording and next step."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from pipeline.bias_table import BiasTrack
from pipeline.sim import SimConfig, simulate
from pipeline.store import write_store
from pipeline.types import Verdict
from validation import rules
from validation.rules import RULES, Evidence, Rule, register, unregister
from validation.validate import validate_sequence, write_validation

ROOT = Path(__file__).resolve().parents[1]


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
    with pytest.raises(ValueError, match="taken"):
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
