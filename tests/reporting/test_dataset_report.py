"""The dataset page (reports/dataset.py) against hand-written stage outputs: counts, rows, values, links."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.bias_table import CSV_HEADER
from pipeline.errors import ConfigError
from reports.dataset import build_dataset_report
from reports.dataset_inputs import gather_dataset

T0 = 1_400_000_000_000_000_000


def _validation(verdict: str, reasons: list[str], *, reference: dict, heldout: bool = False) -> dict:
    sources = {"zero": {"kind": "zero", "prmse_m": 0.2, "roe_deg": 2.0},
               "constant": {"kind": "constant_first_window", "prmse_m": 0.05, "roe_deg": 0.4},
               "recovered": {"kind": "recovered", "prmse_m": 0.00321, "roe_deg": 0.0456},
               "dataset": {"kind": "dataset", "prmse_m": 0.004, "roe_deg": 0.05}}
    if heldout:
        sources["recovered_heldout"] = {"kind": "file", "prmse_m": 0.00789, "roe_deg": 0.0678}
    return {"schema_version": 1, "sequence": "x", "verdict": verdict, "reasons": reasons, "candidate": "recovered",
            "reference": reference, "sources": sources, "notes": [], "next_steps": []}


def _recovery(stream: str, offset_s: float, offset_std_s: float, gyro_scale: float, *, diff: dict | None = None,
              outliers: int = 0, keyframes: int = 100) -> dict:
    return {"pose_stream": stream, "pose_source_kind": "mocap", "pose_time_offset_s": offset_s,
            "pose_time_offset_std_s": offset_std_s,
            "T_imu_pose": {"p_m": [0, 0, 0], "quat_wxyz": [1, 0, 0, 0]},
            "extrinsic": {"difference_from_calibration": diff} if diff else {"mode": "estimate"},
            "noise": {"method": "evidence", "gyro_random_walk_scale": gyro_scale, "acc_random_walk_scale": 1.0,
                      "gyro_random_walk": 1e-4, "acc_random_walk": 1e-3},
            "config": {"random_walk_scales": [0.1, 1.0, 10.0, 100.0]},
            "outliers_rejected": outliers, "keyframes": keyframes, "pose_fusion": {"samples_rejected": 0}}


def _write(results: Path, name: str, validation: dict | None, recovery: dict, bias_level: float) -> None:
    rec = results / "recovery" / name
    rec.mkdir(parents=True)
    (rec / "recovery.json").write_text(json.dumps(recovery))
    t = T0 + np.arange(50, dtype=np.int64) * 100_000_000
    frame = pd.DataFrame({c: np.zeros(50) for c in CSV_HEADER[1:]})
    frame.insert(0, "t_ns", t)
    frame[CSV_HEADER[1]] = bias_level
    frame.to_csv(rec / "bias.csv", index=False)
    if validation is not None:
        (results / "validation" / name).mkdir(parents=True)
        (results / "validation" / name / "validation.json").write_text(json.dumps({**validation, "sequence": name}))
    (results / "report" / name).mkdir(parents=True)
    (results / "report" / name / "report.html").write_text("<!DOCTYPE html><title>x</title>")


@pytest.fixture
def results(tmp_path) -> Path:
    res = tmp_path / "results"
    state = {"kind": "state", "source": "ground_truth_state"}
    fitted = {"kind": "poses", "stream": "vicon0"}
    _write(res, "a_pass", _validation("PASS", [], reference=state),
           _recovery("vicon0", 0.0021, 0.0003, 1.0, diff={"rotation_sigmas": 1.5, "translation_sigmas": 4.25}), 0.01)
    _write(res, "b_warn", _validation("WARN", ["the gyro walk sits at a bound", "second"], reference=fitted,
                                      heldout=True),
           _recovery("vicon0", -0.0104, 0.0012, 100.0, outliers=5), 0.02)
    _write(res, "c_fail", _validation("FAIL", ["worse than a constant bias"], reference=state),
           _recovery("leica0", 0.0, 0.0, 3.0), 0.03)
    _write(res, "d_none", None, _recovery("vicon0", 0.0, 0.0, 1.0), 0.04)
    manifest = {"format_version": 1, "sequences": {
        "a_pass": {"split": "train", "windows": 40, "candidates": 43, "dropped": {"imu_gap": 1, "outside_recovery": 2}},
        "b_warn": {"split": "test", "windows": 30, "candidates": 30, "dropped": {"imu_gap": 0}}},
        "totals": {"train": {"sequences": 1, "windows": 40, "candidates": 43, "dropped": 3},
                   "test": {"sequences": 1, "windows": 30, "candidates": 30, "dropped": 0}},
        "excluded": {"c_fail": "validation FAIL: worse than a constant bias"}, "not_validated": []}
    (res / "windows" / "dataset").mkdir(parents=True)
    (res / "windows" / "dataset" / "manifest.json").write_text(json.dumps(manifest))
    (res / "evaluation").mkdir()
    pd.DataFrame({"zero PRMSE_m": [0.5, 0.25], "zero ROE_deg": [1.0, 2.0], "regression_rnn PRMSE_m": [0.1, 0.125],
                  "regression_rnn ROE_deg": [0.2, 0.3]}, index=pd.Index(["b_warn", "Average"], name="sequence")
                 ).to_csv(res / "evaluation" / "table.csv")
    (res / "report" / "training.html").write_text("<!DOCTYPE html>")
    return res


def _row_html(html: str, name: str) -> str:
    return re.search(rf'<tr data-sequence="{name}">(.*?)</tr>', html, re.S).group(1)


def test_rows_read_the_stage_outputs(results):
    inp = gather_dataset(results.parent, splits={"c_fail": "train", "d_none": "none"})
    rows = {r.name: r for r in inp.rows}
    assert list(rows) == ["a_pass", "b_warn", "c_fail", "d_none"]
    assert [rows[n].verdict for n in rows] == ["PASS", "WARN", "FAIL", None]
    assert rows["b_warn"].reason == "the gyro walk sits at a bound"  # the leading reason only
    assert rows["a_pass"].independent is True and rows["b_warn"].independent is False  # fitted stream
    assert rows["b_warn"].metrics["held-out"] == (0.00789, 0.0678) and "held-out" not in rows["a_pass"].metrics
    assert rows["a_pass"].metrics["constant"] == (0.05, 0.4) and rows["a_pass"].metrics["dataset's"] == (0.004, 0.05)
    assert rows["a_pass"].extrinsic_sigmas == 4.25 and rows["b_warn"].extrinsic_sigmas is None
    assert rows["b_warn"].at_bound == ("gyro",) and rows["c_fail"].at_bound == ()
    assert rows["b_warn"].outlier_share == pytest.approx(0.05)
    assert rows["a_pass"].dropped == {"imu_gap": 1, "outside_recovery": 2} and rows["a_pass"].windows == 40
    assert rows["c_fail"].split == "train" and rows["c_fail"].left_out.startswith("validation FAIL")
    assert rows["d_none"].left_out == "no split (not windowed)"
    assert any("d_none: no validation" in x for x in inp.problems)


def test_page_headline_rows_links_table_and_figure(results):
    out = build_dataset_report(results)
    assert out == results / "report" / "index.html"
    html = out.read_text()
    assert html.startswith("<!DOCTYPE html>") and "<script>" in html
    for verdict, n in (("PASS", 1), ("WARN", 1), ("FAIL", 1)):
        assert f'class="count-{verdict}" data-count="{n}"' in html
    assert "1 not validated" in html
    assert html.count("<tr data-sequence=") == 4
    a = _row_html(html, "a_pass")
    assert '<a href="a_pass/report.html">' in a and 'class="PASS"' in a and "train" in a
    assert "2.100 ± 0.3" in a and "4.25" in a  # the clock offset in ms, the extrinsic in sigmas
    assert "0.00321 / 0.0456" in a and "0.2 / 2" in a and "0.05 / 0.4" in a
    b = _row_html(html, "b_warn")
    assert "vicon0 (fitted)" in b and "0.00789 / 0.0678" in b and 'class="flag">gyro 100x (bound)' in b
    assert "5.00%" in b and "the gyro walk sits at a bound" in b and "second" not in b
    assert "c_fail</strong>: validation FAIL: worse than a constant bias" in html
    assert '<a href="training.html">' in html
    assert "regression_rnn</td>\n<td class=\"num\">0.125" in html  # the Average row, not the sequence's
    assert html.count("data:image/png;base64,") == 1
    # every link resolves to a file next to the page
    for href in re.findall(r'href="([^"#][^"]*)"', html):
        assert (out.parent / href).is_file(), href


def test_out_path_elsewhere_keeps_links_and_errors(results, tmp_path):
    out = build_dataset_report(results, tmp_path / "pages" / "all.html")
    html = out.read_text()
    for href in re.findall(r'href="([^"#][^"]*)"', html):
        assert (out.parent / href).resolve().is_file(), href
    with pytest.raises(ConfigError, match="no sequence"):
        build_dataset_report(tmp_path / "pages")
    with pytest.raises(ConfigError, match="is a folder"):
        build_dataset_report(results, tmp_path)


def test_cli_report_without_sequence_writes_the_dataset_page(results, capsys):
    from biasgt.cli.app import main

    assert main(["report", str(results.parent)]) == 0
    assert Path(capsys.readouterr().out.strip()) == results / "report" / "index.html"
    assert main(["report", str(results), "--ingest", str(results)]) == 2
    assert "needs --sequence" in capsys.readouterr().err
