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
from html_tables import parse_page, style_rules, table_by_id
from reports.dataset import GLANCE_HEADERS, build_dataset_report
from reports.dataset_figure import bias_overview_figure, channel_outliers, trace_label
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
            "reason_codes": [f"CODE_{i}" for i in range(len(reasons))], "reference": reference, "sources": sources,
            "notes": [], "next_steps": [f"fix {verdict.lower()} with sensor.yaml"] if reasons else []}


def _recovery(stream: str, offset_s: float, offset_std_s: float, gyro_scale: float, *, diff: dict | None = None,
              outliers: int = 0, keyframes: int = 100, kind: str = "mocap") -> dict:
    return {"pose_stream": stream, "pose_source_kind": kind, "pose_time_offset_s": offset_s,
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
           _recovery("leica0", 0.0, 0.0, 3.0, kind="position_tracker"), 1.0)  # an outlier bias: must not set the figure's scale
    _write(res, "d_none", None, _recovery("vicon0", 0.0, 0.0, 1.0), 0.04)
    manifest = {"format_version": 1, "sequences": {
        "a_pass": {"split": "train", "windows": 40, "candidates": 43, "dropped": {"imu_gap": 1, "outside_recovery": 2}},
        "b_warn": {"split": "test", "windows": 30, "candidates": 30, "dropped": {"imu_gap": 0},
                   "info": {"bias_std_factor": [2.5, 1.0, 1.0, 1.0, 1.0, 1.25]}}},
        "totals": {"train": {"sequences": 1, "windows": 40, "candidates": 43, "dropped": 3},
                   "test": {"sequences": 1, "windows": 30, "candidates": 30, "dropped": 0}},
        "excluded": {"c_fail": "validation FAIL: worse than a constant bias"}, "not_validated": []}
    (res / "windows" / "dataset").mkdir(parents=True)
    (res / "windows" / "dataset" / "manifest.json").write_text(json.dumps(manifest))
    (res / "evaluation").mkdir()
    pd.DataFrame({"zero PRMSE_m": [0.5, 0.25], "zero ROE_deg": [1.0, 2.0], "regression_rnn PRMSE_m": [0.1, 0.125],
                  "regression_rnn ROE_deg": [0.2, 0.3], "Recovered GT bias PRMSE_m": [0.05, 0.0625],
                  "Recovered GT bias ROE_deg": [0.1, 0.15]}, index=pd.Index(["b_warn", "Average"], name="sequence")
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
    widened = re.search(r'<p class="widened">(.*?)</p>', html, re.S).group(1)
    assert re.sub(r"<[^>]+>", "", widened).endswith("widened sigma): b_warn: gyro x x2.50, acc z x1.25")
    glance = table_by_id(html, "sequences-table")
    assert [h for h in glance.headers] == list(GLANCE_HEADERS)
    assert [r[0].text for r in glance.rows] == ["c_fail", "b_warn", "a_pass", "d_none"]  # most severe first
    assert glance.column("verdict") == ["FAIL", "WARN", "PASS", "not validated"]
    keys = [float(r[2].attrs["data-v"]) for r in glance.rows]
    assert keys == sorted(keys)  # the verdict column sorts by severity, not alphabetically
    assert glance.cell("a_pass", "label:").text == "3.21 mm / 0.0456°"
    assert glance.cell("a_pass", "constant").text == "50 mm / 0.4°"
    assert glance.cell("b_warn", "held out").text == "7.89 mm / 0.0678°"
    assert glance.cell("a_pass", "held out").text == "not run"  # an empty cell says why
    assert glance.cell("d_none", "held out").text == "not validated"
    assert glance.cell("c_fail", "windows").text == "left out: validation FAIL"
    assert glance.cell("a_pass", "windows").text == "40 of 43"
    assert glance.cell("b_warn", "leading").text == "the gyro walk sits at a bound CODE_0"  # words, code kept
    assert glance.cell("a_pass", "leading").text == "no reason for concern"
    details = table_by_id(html, "details-table")
    assert details.cell("a_pass", "clock").text == "2.10 ± 0.30 ms"
    assert details.cell("a_pass", "extrinsic").text == "4.2 σ"
    assert details.cell("b_warn", "validation").text == "vicon0 (fitted)"
    assert details.cell("b_warn", "bias random").text.startswith("gyro 100× (larger than calibrated, at a bound)")
    assert details.cell("b_warn", "pose outliers").text == "5.0%"
    assert details.cell("a_pass", "windows dropped").text == "imu gap imu_gap: 1, outside recovery outside_recovery: 2"
    assert details.cell("c_fail", "windows dropped").text == "left out"  # not the reason a second time
    assert glance.in_scroll and details.in_scroll
    assert "c_fail</strong>: validation FAIL: worse than a constant bias" in html
    steps = re.search(r'<section id="next">(.*?)</section>', html, re.S).group(1)
    assert "fix warn with sensor.yaml" in steps and "fix fail with sensor.yaml" in steps and "a_pass" not in steps
    assert steps.index("c_fail") < steps.index("b_warn")
    assert '<a href="training.html">' in html
    table_i = table_by_id(html, "table-i")
    assert table_i.column("method") == ["zero", "regression_rnn", "Recovered GT bias (oracle)"]
    assert table_i.cell("regression_rnn", "average PRMSE").text == "0.1250"  # the Average row, not the sequence's
    assert [a.get("data-oracle") for a in table_i.row_attrs] == [None, None, "1"]
    assert "(oracle): reads the ground truth at test time" in html
    assert html.count("<img ") == 1 and html.count("<source ") == 1 and html.count("data:image/png;base64,") == 2
    assert "Clipped, so that they do not set the scale: gyro x: c_fail (peak 1 rad/s)" in html
    # every link resolves to a file next to the page
    for href in re.findall(r'href="([^"#][^"]*)"', html):
        assert (out.parent / href).is_file(), href


def test_every_table_scrolls_in_its_own_box_and_the_page_has_phone_rules(results):
    html = build_dataset_report(results).read_text()
    tables, _ = parse_page(html)
    assert len(tables) >= 4 and all(t.in_scroll for t in tables)
    css = style_rules(html)
    assert ".scroll{overflow-x:auto" in css and "@media (max-width:640px)" in css
    assert "table.glance{width:100%" in css
    assert "figure img{max-width:100%" in css


def test_figure_names_every_sequence_and_clips_the_outlier(results):
    inp = gather_dataset(results.parent)
    assert channel_outliers(inp.rows) == {0: [("c_fail", 1.0)]}
    for layout in ("wide", "narrow"):
        fig = bias_overview_figure(inp.rows, layout)
        labels = [t.get_text() for t in fig.legends[0].get_texts()]
        assert labels == [trace_label(r) for r in inp.rows]
        assert "c_fail · train (left out) · FAIL" not in labels  # c_fail's split comes from the workflow
        assert len(set(labels)) == len(inp.rows) == 4
        gyro_x = fig.axes[0]
        colors = {tuple(line.get_color()) for line in gyro_x.get_lines()}
        assert len(gyro_x.get_lines()) == 4 and len(colors) == 4  # one identifiable trace per sequence
        assert gyro_x.get_ylim()[1] < 0.5  # the 1 rad/s outlier does not set the scale
        assert any("clipped: c_fail" in t.get_text() for t in gyro_x.texts)
        assert not fig.axes[1].texts  # nothing clipped on the other channels
    narrow = bias_overview_figure(inp.rows, "narrow")
    assert narrow.get_size_inches()[0] < 5  # a phone-width layout


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
