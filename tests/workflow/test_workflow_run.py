"""Running the workflow: the step functions, the Snakemake driver (command, profiles, failures, dry runs)
and real Snakemake runs of every stage, with reruns after a config change."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline.errors import ConfigError, DataError
from biasgt.workflow.config import DEFAULT_CONFIG, load_config
from biasgt.workflow.params import stage_config, validation_settings
from biasgt.workflow.run import (
    WorkflowRunError,
    describe_failure,
    parse_dry_run_jobs,
    resolve_profile,
    run_workflow,
    snakemake_command,
)
from biasgt.workflow.steps import interpolate_step, recover_step, report_step, run_step, validate_step, windows_step
from test_report_chromium import chromium  # noqa: F401  (the fixture: finds or installs Chromium)
from workflow_configs import sim_entry, write_config

REPO = Path(__file__).resolve().parents[2]

SPINE_GROUP = pytest.mark.xdist_group("workflow_snakemake")


# ---------------------------------------------------------------------------------------------
# step helpers and the snakemake driver (no snakemake run)


def test_run_step_logs_and_maps_errors(tmp_path):
    log_path = tmp_path / "logs" / "x.log"

    def ok(a, b):
        logging.getLogger("pipeline.test").info("adding %s", a)
        return a + b

    assert run_step(log_path, ok, 1, 2) == 3
    assert "adding 1" in log_path.read_text()

    def bad():
        raise DataError("the data is wrong", path="in.csv", hint="fix it")

    with pytest.raises(SystemExit) as info:
        run_step(log_path, bad)
    assert info.value.code == 2
    assert "ERROR biasgt.workflow: in.csv: the data is wrong; fix it" in log_path.read_text()

    def bug():
        raise KeyError("k")

    with pytest.raises(KeyError):
        run_step(log_path, bug)
    text = log_path.read_text()
    assert "unexpected error" in text and "Traceback" in text


def test_run_step_names_the_slurm_job(tmp_path, monkeypatch):
    log_path = tmp_path / "x.log"
    monkeypatch.delenv("SLURM_JOB_ID", raising=False)
    run_step(log_path, lambda: None)
    assert "job on host" in log_path.read_text() and "SLURM job" not in log_path.read_text()
    monkeypatch.setenv("SLURM_JOB_ID", "4711")
    run_step(log_path, lambda: None)
    assert ", SLURM job 4711" in log_path.read_text()


def test_snakefile_imports_no_torch():
    """The Snakefile's imports (biasgt.workflow and its learning module) leave PyTorch out: Snakemake
    parses the Snakefile twice in every cluster job, and importing torch cost 1.3 s each time."""
    code = ("import sys; import biasgt.workflow.config, biasgt.workflow.params, biasgt.workflow.learning; "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(REPO)})
    assert out.stdout.strip() == "False"


def test_resolve_profile(tmp_path):
    assert resolve_profile("slurm") == REPO / "workflow" / "profiles" / "slurm"
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "config.yaml").write_text("jobs: 2\n")
    assert resolve_profile(tmp_path / "mine") == tmp_path / "mine"
    with pytest.raises(ConfigError, match="no Snakemake profile 'nope'.*use one of slurm"):
        resolve_profile("nope")


@SPINE_GROUP
def test_slurm_profile_sets_each_rules_resources(tmp_path, capsys):
    """A dry run with --profile slurm gives every job the profile's memory and time (attempt 1)."""
    from biasgt.cli.app import main

    profile = yaml.safe_load((REPO / "workflow" / "profiles" / "slurm" / "config.yaml").read_text())
    assert profile["executor"] == "slurm" and profile["set-resources"]["train"]["gpu"] == 1
    cfg = write_config(tmp_path / "c.yaml", {"sequences": [sim_entry("a", split="train")]})
    assert main(["-v", "run", "--config", str(cfg), "--directory", str(tmp_path), "--profile", "slurm",
                 "--dry-run"]) == 0  # -v: the whole plan
    resources = {}  # rule -> its jobs' "resources:" line
    rule = None
    for line in capsys.readouterr().err.splitlines():
        if m := re.match(r"^\s*(?:local)?(?:rule|checkpoint) (\w+):", line):  # indented: a job of a group job
            rule = m.group(1)
        elif (m := re.match(r"^\s+resources: (.*)$", line)) and rule:
            resources[rule] = m.group(1)
    for rule, res in resources.items():
        want = profile["set-resources"].get(rule, profile["default-resources"])
        assert f"mem_mb={eval(str(want['mem_mb']), {'attempt': 1})}," in res, (rule, res)
        assert f"runtime={eval(str(want['runtime']), {'attempt': 1})}" in res, (rule, res)
    seen = set(resources) - {"all"}
    assert seen == set(STAGE_RULES)


def test_snakemake_command(tmp_path):
    cmd = snakemake_command(config_file=tmp_path / "c.yaml", cores=3, workdir=tmp_path, dry_run=True,
                               until=["ingest"], targets=["results/ingest/a"], extra=["--forceall"])
    assert cmd[:3] == [sys.executable, "-m", "snakemake"]
    assert cmd[cmd.index("--snakefile") + 1] == str(REPO / "Snakefile")
    assert cmd[cmd.index("--directory") + 1] == str(tmp_path)
    assert cmd[cmd.index("--configfile") + 1] == str(tmp_path / "c.yaml")
    assert cmd[cmd.index("--cores") + 1] == "3"
    assert "--replace-workflow-config" in cmd and "--dry-run" in cmd
    assert cmd[-4:] == ["--until", "ingest", "--forceall", "results/ingest/a"]


def test_describe_failure(tmp_path):
    (tmp_path / "logs" / "ingest").mkdir(parents=True)
    (tmp_path / "logs" / "ingest" / "a.log").write_text(
        "2026-01-01 INFO biasgt.workflow: ingesting\n"
        "2026-01-01 00:00:00,000 ERROR biasgt.workflow: in.csv: refusing to convert; rerun with --repair sort\n")
    lines = [  # what Snakemake 9 prints (trimmed)
        "localrule ingest:",
        "    input: results/simulate/b",
        "    jobid: 2",
        "    wildcards: sequence=b",
        "localrule ingest:",
        "    input: results/simulate/a",
        "    jobid: 1",
        "    wildcards: sequence=a",
        "biasgt: error: in.csv: refusing to convert; rerun with --repair sort",
        "[Sat Nov 21 23:35:04 2026]",
        "Error in rule ingest:",
        "    message: None",
        "    jobid: 1",
        "    output: results/ingest/a",
        "    log: logs/ingest/a.log (check log file(s) for error details)",
        "Shutting down, this might take some time.",
        "Exiting because a job execution failed. Look below for error messages",
    ]
    msg = describe_failure(lines, tmp_path)
    assert msg == (f"rule 'ingest' (sequence=a) failed: in.csv: refusing to convert; rerun with --repair sort "
                   f"(log: {tmp_path / 'logs' / 'ingest' / 'a.log'})")
    slurm = [ln.replace("log: logs/ingest/a.log (", "log: logs/ingest/a.log, /x/.snakemake/slurm_logs/rule_ingest/a/7.log (")
             for ln in lines]  # the SLURM executor adds its own log
    assert describe_failure(slurm, tmp_path) == msg
    assert describe_failure(["WorkflowError:", "Target rules may not contain wildcards.", ""], tmp_path) == (
        "Target rules may not contain wildcards.")


def test_describe_failure_of_a_group_job(tmp_path):
    """A failed group job (the SLURM profile's 'sequence' group) lists all its rules as failed: the
    one named is the rule whose log holds the error, not the first in Snakemake's (alphabetical) list."""
    for stage, text in (("ingest", "INFO biasgt.workflow: wrote results/ingest/b\n"),
                        ("recovery", "INFO biasgt.workflow: recovering\n"
                                     "2026-01-01 00:00:00,000 ERROR biasgt.workflow: no pose stream in b\n")):
        (tmp_path / "logs" / stage).mkdir(parents=True)
        (tmp_path / "logs" / stage / "b.log").write_text(text)

    def error_block(rule, jobid, log):
        return [f"    Error in rule {rule}:", f"        jobid: {jobid}", f"        output: results/{rule}/b",
                f"        log: {log} (check log file(s) for error details)"]

    lines = [  # what Snakemake 9 with the SLURM executor prints for a failed group job (trimmed)
        "[Tue Dec  1 19:30:00 2026] Group job sequence (jobs in lexicogr. order):",
        "    rule ingest:", "        jobid: 3", "        wildcards: sequence=b",
        "    rule interpolate:", "        jobid: 5", "        wildcards: sequence=b",
        "    rule recover:", "        jobid: 4", "        wildcards: sequence=b",
        "[Tue Dec  1 19:31:00 2026]",
        "    message: Error in group sequence",
        "    log: /x/.snakemake/slurm_logs/group_sequence_ingest_interpolate_recover/9.log (check log file(s) ...)",
        "    jobs:",
        "        rule recover:", "            jobid: 4", "            log: logs/recovery/b.log (check log file(s) ...)",
        "        rule interpolate:", "            jobid: 5", "            log: logs/interpolation/b.log (check ...)",
        "        rule ingest:", "            jobid: 3", "            log: logs/ingest/b.log (check log file(s) ...)",
        *error_block("ingest", 3, "logs/ingest/b.log"),
        *error_block("interpolate", 5, "logs/interpolation/b.log"),  # never ran: no log
        *error_block("recover", 4, "logs/recovery/b.log"),
    ]
    assert describe_failure(lines, tmp_path) == (
        f"rule 'recover' (sequence=b) failed: no pose stream in b (log: {tmp_path / 'logs' / 'recovery' / 'b.log'})")


def test_parse_dry_run_jobs():
    text = (
        "rule simulate:\n    output: results/simulate/a\n    jobid: 2\n    wildcards: sequence=a\n"
        "localrule ingest:\n    input: results/simulate/a\n    wildcards: sequence=a\n"
        "localrule all:\n    input: results/ingest/a\n    jobid: 0\n"
    )
    assert parse_dry_run_jobs(text) == [("simulate", {"sequence": "a"}), ("ingest", {"sequence": "a"}),
                                           ("all", {})]


def test_cli_reports_bad_config_on_one_line(tmp_path, capsys):
    from biasgt.cli.app import main

    cfg = write_config(tmp_path / "bad.yaml", {"sequences": [sim_entry("a"), sim_entry("a")]})
    assert main(["run", "--config", str(cfg), "--directory", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"biasgt run: error: {cfg}: sequences[1] ('a'): duplicate sequence name 'a'")
    assert not (tmp_path / ".snakemake").exists()  # snakemake never started


# ---------------------------------------------------------------------------------------------
# step functions in-process (validate: a FAIL verdict is data, bad inputs stop the job)


@SPINE_GROUP
@pytest.mark.slow  # uses the end-to-end run (~40-80 s, once per module)
def test_validate_step_fail_is_a_result_and_bad_input_stops(e2e_run, tmp_path):
    import json as _json

    import pandas as pd

    from validation.validate import Verdict

    workdir = e2e_run.workdir
    store = workdir / "results" / "ingest" / "tiny_b"
    recovery = tmp_path / "recovery_off"
    import shutil

    shutil.copytree(workdir / "results" / "recovery" / "tiny_b", recovery)
    shutil.copy(recovery / "bias.csv", tmp_path / "unshifted.csv")
    bias = pd.read_csv(recovery / "bias.csv")
    bias["ba_x"] += 0.5  # 0.5 m/s^2 off: far worse than a constant bias
    bias.to_csv(recovery / "bias.csv", index=False)
    cfg = load_config(e2e_run.config)
    settings = {**validation_settings(cfg, "tiny_b"), "bias": [["unshifted", str(tmp_path / "unshifted.csv")]]}
    log_path = tmp_path / "logs" / "validate.log"
    result = run_step(log_path, validate_step, store, recovery, tmp_path / "val", settings)
    assert result.verdict is Verdict.FAIL
    data = _json.loads((tmp_path / "val" / "validation.json").read_text())
    assert data["verdict"] == "FAIL" and data["reasons"]
    # a validation.bias file is integrated on the same windows, compared, not judged: the unshifted bias wins
    other, judged = data["sources"]["unshifted"], data["sources"]["recovered"]
    assert other["kind"] == "file" and data["candidate"] == "recovered"
    assert other["windows"] == judged["windows"] and other["prmse_m"] < 0.2 * judged["prmse_m"]
    assert "WARNING biasgt.workflow: verdict FAIL for 'tiny_b'" in log_path.read_text()
    # a missing recovery is an input error: exit 2, one logged line, nothing written
    with pytest.raises(SystemExit) as info:
        run_step(log_path, validate_step, store, tmp_path / "nowhere", tmp_path / "val2", settings)
    assert info.value.code == 2 and not (tmp_path / "val2").exists()
    assert "recovery output lacks recovery.json" in log_path.read_text()


@SPINE_GROUP
@pytest.mark.slow  # uses the end-to-end run (~40-80 s, once per module)
def test_other_step_functions_in_process(e2e_run, tmp_path):
    import pyarrow.parquet as pq

    from pipeline.store import read_store

    results = e2e_run.workdir / "results"
    store, recovery = results / "ingest" / "tiny_a", results / "recovery" / "tiny_a"
    log_path = tmp_path / "step.log"
    # interpolate: cubic, Parquet only
    out = tmp_path / "interp" / "bias_imu.parquet"
    written = run_step(log_path, interpolate_step, recovery, store, out,
                          {"method": "cubic", "clamp": True, "write_csv": False})
    assert written == [out] and not out.with_suffix(".csv").exists()
    assert pq.read_table(out).num_rows == len(read_store(store).imu)
    with pytest.raises(SystemExit) as info:
        run_step(log_path, interpolate_step, recovery, store, tmp_path / "x.parquet", {"method": "spline"})
    assert info.value.code == 2 and "method 'spline' is not one of linear, cubic" in log_path.read_text()
    # recover: an unknown pose stream is a one-line input error naming the streams
    with pytest.raises(SystemExit) as info:
        run_step(log_path, recover_step, store, tmp_path / "rec", {"pose_stream": "vicon9", "config": {}})
    assert info.value.code == 2 and "vicon9" in log_path.read_text() and "mocap0" in log_path.read_text()
    assert not (tmp_path / "rec").exists()
    # report: one HTML file from the three stage folders
    html = run_step(log_path, report_step, store, recovery, results / "validation" / "tiny_a",
                       tmp_path / "r" / "report.html")
    assert html.read_text().lower().lstrip().startswith("<!doctype html")
    # windows: inputs and names must line up; options are checked
    with pytest.raises(ConfigError, match="1 sequences but 2 stores"):
        windows_step([store, store], [recovery, recovery], [recovery, recovery], tmp_path / "ds", {"sequences": [["tiny_a", "train"]]})
    with pytest.raises(ConfigError, match="window_len"):
        stage_config("windows", {"window_len": 2})


# ---------------------------------------------------------------------------------------------
# real snakemake runs (grouped on one xdist worker)


def _dry_run_jobs(cfg: Path, workdir: Path) -> list[tuple[str, dict[str, str]]]:
    echo = io.StringIO()
    run_workflow(config_file=cfg, workdir=workdir, dry_run=True, echo=echo)
    return [(rule, w) for rule, w in parse_dry_run_jobs(echo.getvalue()) if rule != "all"]


STAGE_RULES = ("simulate", "ingest", "recover", "interpolate", "validate", "windows", "report", "dataset_report")
#: The rules with one job for the whole config (no {sequence} wildcard).
WHOLE_RUN_RULES = ("windows", "dataset_report")


@SPINE_GROUP
def test_dry_run_of_default_workflow(tmp_path):
    echo = io.StringIO()
    result = run_workflow(workdir=tmp_path, dry_run=True, echo=echo)
    jobs = parse_dry_run_jobs(echo.getvalue())
    names = load_config(DEFAULT_CONFIG).names
    for rule in STAGE_RULES:
        if rule not in WHOLE_RUN_RULES:
            assert sorted(w["sequence"] for r, w in jobs if r == rule) == sorted(names), rule
    for rule in WHOLE_RUN_RULES:
        assert [r for r, _ in jobs].count(rule) == 1, rule
    assert [r for r, _ in jobs].count("all") == 1
    assert result.outputs == [] and not (tmp_path / "results").exists()


def _have_stages() -> str | None:
    try:
        from pipeline.ingest import ingest  # noqa: F401
        from pipeline.io import load_sequence  # noqa: F401
        from pipeline.sim import simulate, write_simulation  # noqa: F401
        from recovery.recover import recover  # noqa: F401
        from reports.quality import build_quality_report  # noqa: F401
        from training.data.windows import build_window_dataset  # noqa: F401
    except ImportError as exc:
        return f"a stage is not importable yet ({exc})"
    return None


@dataclasses.dataclass
class E2E:
    workdir: Path
    config: Path
    printed: str
    wall_s: float


@pytest.fixture(scope="module")
def e2e_run(tmp_path_factory) -> E2E:
    """A real run of every stage on two 8-second simulated sequences (train and test)."""
    import time

    reason = _have_stages()
    if reason:
        pytest.skip(reason)
    workdir = tmp_path_factory.mktemp("e2e")
    cfg = write_config(workdir / "config.yaml", {
        "sequences": [sim_entry("tiny_a", seed=1, split="train", duration_s=8),
                      sim_entry("tiny_b", seed=2, split="test", duration_s=8)],
        # 8 s leave the recovered bias too uncertain to tell from the truth: WARN, windowed all the same
        "windows": {"accept_warn": True},
    })
    import argparse

    from biasgt.cli.commands import run

    parser = argparse.ArgumentParser()
    run.register(parser.add_subparsers())
    args = parser.parse_args(["run", "--config", str(cfg), "--directory", str(workdir), "--cores", "2"])
    stdout = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(stdout):  # the 'biasgt run' command, as 'make run' calls it
        code = args.func(args)
    assert code == 0
    return E2E(workdir, cfg, stdout.getvalue(), time.perf_counter() - t0)


@SPINE_GROUP
@pytest.mark.slow
def test_real_run_writes_every_stage(e2e_run):
    from pipeline.store import read_store
    from pipeline.bias_table import CSV_HEADER

    workdir, printed = e2e_run.workdir, e2e_run.printed
    results = workdir / "results"
    lines = printed.splitlines()
    assert lines[:lines.index("summary:")] == [
        f"results: {results}",
        *(f"  stage: {results / d}" for d in sorted(
            ["simulate", "ingest", "recovery", "interpolation", "validation", "windows", "report"])),
        f"reports ({3}):",
        f"  {results / 'report' / 'index.html'}",
        f"  {results / 'report' / 'tiny_a' / 'report.html'}",
        f"  {results / 'report' / 'tiny_b' / 'report.html'}",
    ]
    summary = lines[lines.index("summary:") + 1:]  # the verdict per sequence, the dataset, the reports
    assert [x.split(":")[0] for x in summary[:2]] == ["  tiny_a", "  tiny_b"]
    assert summary[2].startswith("  windows: 2 sequences in the dataset (test 1, train 1)")
    for name in ("tiny_a", "tiny_b"):
        assert (results / "simulate" / name / "mav0" / "imu0" / "data.csv").is_file()
        seq = read_store(results / "ingest" / name)
        assert seq.name == name and seq.imu is not None and 8 * 200 - 2 <= len(seq.imu) <= 8 * 200 + 2
        header = (results / "recovery" / name / "bias.csv").read_text().splitlines()[0]
        assert header == ",".join(CSV_HEADER)
        assert header == "t_ns,bg_x,bg_y,bg_z,ba_x,ba_y,ba_z,bg_x_std,bg_y_std,bg_z_std,ba_x_std,ba_y_std,ba_z_std"
        rec = json.loads((results / "recovery" / name / "recovery.json").read_text())
        assert rec["pose_stream"] == "mocap0" and rec["keyframes"] >= 70  # 8 s of 10-Hz fused keyframes
        assert rec["pose_fusion"]["enabled"] and rec["pose_fusion"]["samples_per_keyframe_mean"] > 9
        interp = results / "interpolation" / name
        assert (interp / "bias_imu.parquet").is_file() and (interp / "bias_imu.csv").is_file()
        import pyarrow.parquet as pq

        assert pq.read_table(interp / "bias_imu.parquet").num_rows == len(seq.imu)
        val = json.loads((results / "validation" / name / "validation.json").read_text())
        assert val["verdict"] in ("PASS", "WARN", "FAIL") and val["candidate"] == "recovered"
        assert val["reference"]["kind"] == "state"  # the simulator's ground truth
        assert {"zero", "constant", "recovered", "dataset"} <= set(val["sources"])
        # the recovered bias integrates far better than no bias at all
        assert val["sources"]["recovered"]["prmse_m"] < 0.5 * val["sources"]["zero"]["prmse_m"]
        assert (results / "validation" / name / "windows.parquet").is_file()
        html = (results / "report" / name / "report.html").read_text()
        assert html.lstrip().lower().startswith("<!doctype html") and name in html and val["verdict"] in html
        for stage in ("simulate", "ingest", "recovery", "interpolation", "validation", "report"):
            log_text = (workdir / "logs" / stage / f"{name}.log").read_text()
            assert "INFO" in log_text and "ERROR" not in log_text, (stage, name)
    manifest = json.loads((results / "windows" / "dataset" / "manifest.json").read_text())
    assert {n: s["split"] for n, s in manifest["sequences"].items()} == {"tiny_a": "train", "tiny_b": "test"}
    assert all(s["windows"] > 5 for s in manifest["sequences"].values())
    assert "ERROR" not in (workdir / "logs" / "windows" / "dataset.log").read_text()


@SPINE_GROUP
@pytest.mark.slow  # uses the end-to-end run (~40-80 s, once per module)
def test_rerun_only_what_a_config_change_affects(e2e_run):
    """Snakemake's params trigger: a dry run after editing the config lists only the affected jobs."""
    workdir, cfg = e2e_run.workdir, e2e_run.config
    base = yaml.safe_load(cfg.read_text())

    def jobs_after(edit) -> list[tuple[str, str]]:
        data = yaml.safe_load(yaml.safe_dump(base))
        edit(data)
        jobs = _dry_run_jobs(write_config(workdir / "edited.yaml", data), workdir)
        return sorted((rule, w.get("sequence", "")) for rule, w in jobs)

    both = ("tiny_a", "tiny_b")
    whole_run = [("dataset_report", ""), ("windows", "")]  # the dataset page follows every change below
    assert jobs_after(lambda d: None) == []
    # a recovery option: recover and everything after it, for every sequence; not simulate / ingest
    assert jobs_after(lambda d: d.update(recovery={"keyframe_rate_hz": 50})) == sorted(
        [(r, s) for r in ("recover", "interpolate", "validate", "report") for s in both] + whole_run)
    # one sequence's own recovery override: that sequence's chain (and the dataset) only
    assert jobs_after(lambda d: d["sequences"][1].update(recovery={"keyframe_rate_hz": 50})) == sorted(
        [(r, "tiny_b") for r in ("recover", "interpolate", "validate", "report")] + whole_run)
    # a validation option: validate, report and windows (the verdicts decide which sequences are windowed)
    assert jobs_after(lambda d: d.update(validation={"window_s": 2.0})) == sorted(
        [(r, s) for r in ("validate", "report") for s in both] + whole_run)
    # interpolation and windows options: their own jobs only
    assert jobs_after(lambda d: d.update(interpolation={"method": "cubic"})) == [
        ("interpolate", "tiny_a"), ("interpolate", "tiny_b")]
    assert jobs_after(lambda d: d.update(windows={"overlap": 0.0})) == whole_run
    # a simulator parameter of one sequence: its whole chain; an ingest option: from ingest on
    def sim_and_ingest(d):
        d["sequences"][0]["seed"] = 7
        d["sequences"][1]["check_options"] = {"gap_factor": 4.0}

    assert jobs_after(sim_and_ingest) == sorted(
        [("simulate", "tiny_a")] + [(r, s) for r in ("ingest", "recover", "interpolate", "validate", "report")
                                    for s in both] + whole_run)


@SPINE_GROUP
def test_failed_job_is_one_line_error(tmp_path):
    if _have_stages():
        pytest.skip(_have_stages())
    (tmp_path / "empty_mav0").mkdir()
    cfg = write_config(tmp_path / "cfg.yaml", {"sequences": [{"name": "broken", "source": "asl",
                                                             "path": "empty_mav0"}]})
    with pytest.raises(WorkflowRunError) as info:
        run_workflow(config_file=cfg, workdir=tmp_path, echo=io.StringIO())
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith("workflow failed (snakemake exit 1): rule 'ingest' (sequence=broken) failed: ")
    assert "not an ASL dataset folder" in msg
    assert f"(log: {tmp_path / 'logs' / 'ingest' / 'broken.log'})" in msg
    assert not (tmp_path / "results" / "ingest" / "broken").exists()


#: Run after the page has loaded: the row order after sorting by the label's (the recovered bias's) PRMSE,
#: then by name twice.
SORT_PROBE = """<script>
window.addEventListener("load", function () {
  var ths = Array.prototype.slice.call(document.querySelectorAll("#sequences-table th"));
  function order() {
    return Array.prototype.map.call(document.querySelectorAll("#sequences-table tbody tr"),
                                    function (r) { return r.dataset.sequence; }).join(",");
  }
  ths.filter(function (h) { return h.textContent.indexOf("label:") === 0; })[0].click();
  document.body.dataset.byPrmse = order();
  ths[0].click(); ths[0].click();
  document.body.dataset.byNameDesc = order();
});
</script>"""


@SPINE_GROUP
@pytest.mark.slow
@pytest.mark.chromium
def test_dataset_page_in_chromium(e2e_run, chromium, tmp_path):  # noqa: F811  (the imported fixture)
    """results/report/index.html of the run, in headless Chromium: the headline counts against
    validation.json and the manifest, one row per sequence, links that resolve, the figure, sorting."""
    from test_report_chromium import FLAGS

    results = e2e_run.workdir / "results"
    page = results / "report" / "index.html"
    probe = page.with_name("index_sort_probe.html")  # beside the page: its relative links still resolve
    probe.write_text(page.read_text().replace("</body>", SORT_PROBE + "</body>"))
    try:
        dom = subprocess.run([chromium, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                              "--virtual-time-budget=10000", "--dump-dom", probe.as_uri()],
                             capture_output=True, text=True, timeout=120, check=False)
    finally:
        probe.unlink()
    assert dom.returncode == 0, dom.stderr[-2000:]
    html = dom.stdout
    body = re.search(r"<body\b[^>]*>", html).group(0)
    assert 'data-broken-images="0"' in body and 'data-images="1"' in body, body  # the bias figure decoded
    verdicts = {n: json.loads((results / "validation" / n / "validation.json").read_text())["verdict"]
                for n in ("tiny_a", "tiny_b")}
    for verdict in ("PASS", "WARN", "FAIL"):
        n = sum(v == verdict for v in verdicts.values())
        assert f'class="count-{verdict}" data-count="{n}"' in html, verdict
    manifest = json.loads((results / "windows" / "dataset" / "manifest.json").read_text())
    for split, total in manifest["totals"].items():
        cells = re.search(rf"<tr><td>{split}</td>\s*<td[^>]*>(\d+)</td>\s*<td[^>]*>(\d+)</td>", html)
        assert cells and (int(cells.group(1)), int(cells.group(2))) == (total["sequences"], total["windows"]), split
    glance = re.search(r'<table[^>]*id="sequences-table".*?</table>', html, re.S).group(0)
    assert re.findall(r'<tr data-sequence="(\w+)">', glance) == ["tiny_b", "tiny_a"]  # after the last sort
    for href in re.findall(r'href="([^"#][^"]*)"', html):
        assert (page.parent / href).is_file(), href
    assert len(re.findall(r'href="[^"]*/report.html"', glance)) == 2
    prmse = {n: json.loads((results / "validation" / n / "validation.json").read_text())["sources"]["recovered"]
             ["prmse_m"] for n in verdicts}
    assert re.search(r'data-by-prmse="([^"]*)"', body).group(1) == ",".join(sorted(prmse, key=prmse.get))
    assert re.search(r'data-by-name-desc="([^"]*)"', body).group(1) == "tiny_b,tiny_a"
