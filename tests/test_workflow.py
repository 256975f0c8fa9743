"""The Snakemake workflow spine: config schema and checks, get_* paths, biasgt run, reruns."""

from __future__ import annotations

import contextlib
import io
import logging
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline import workflow as wf
from pipeline.errors import ConfigError, DataError
REPO = Path(__file__).resolve().parents[1]

SPINE_GROUP = pytest.mark.xdist_group("workflow_snakemake")


def write_config(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def sim_entry(name: str, **kw) -> dict:
    return {"name": name, "source": "simulate", "duration_s": 3, "seed": 1, **kw}


# ---------------------------------------------------------------------------------------------
# schema and checks


def test_default_config_is_valid_with_defaults():
    cfg = wf.load_config(REPO / "config" / "config.yaml")
    assert cfg.names == ["sim_handheld_01", "sim_drone_01", "sim_cart_leica_01", "sim_handheld_test_01"]
    assert all(s.source is wf.SourceKind.SIMULATE for s in cfg.sequences)
    assert [s.name for s in cfg.select(splits=["test"])] == ["sim_handheld_test_01"]
    assert len(cfg.select(splits=["train"])) == 3
    for section in ("recovery", "interpolation", "validation", "windows", "training", "evaluation", "report"):
        assert cfg.data[section] == {}
    assert cfg.data["ingest"] == {"repairs": [], "check_options": {}}
    assert cfg.config_file == REPO / "config" / "config.yaml"


def test_defaults_filled_like_snakemake_validate(tmp_path):
    from snakemake.utils import validate

    data = {"sequences": [{"name": "a", "source": "simulate"}, {"name": "b", "source": "tum", "path": "x.txt"}]}
    mine = wf.validate_schema(yaml.safe_load(yaml.safe_dump(data)))
    theirs = yaml.safe_load(yaml.safe_dump(data))
    validate(theirs, str(wf.SCHEMA_FILE))
    assert mine == theirs
    a, b = mine["sequences"]
    assert a == {"name": "a", "source": "simulate", "split": "none", "preset": "handheld", "duration_s": 60,
                 "seed": 0, "pose_format": "mocap", "overrides": {}}
    assert b == {"name": "b", "source": "tum", "path": "x.txt", "split": "none", "poses": [], "reader": {}}
    assert mine["data_root"] == "." and mine["check_input_paths"] is True
    assert mine["training"] == {}


def test_euroc_config_is_valid(shared_data):
    data = yaml.safe_load((REPO / "config" / "euroc.yaml").read_text())
    data["data_root"] = str(shared_data)  # the fixture's folder (may come from BIASGT_SHARED_DATA)
    wf.validate_schema(data)
    cfg = wf.check_config(data, REPO / "config" / "euroc.yaml")
    mh01 = cfg.sequence("MH_01_easy")
    assert mh01.source is wf.SourceKind.ASL and mh01.path == shared_data / "euroc" / "MH_01_easy"
    semi = wf.simulate_settings(cfg, "semi_MH_04_difficult")
    assert semi["duration_s"] is None
    assert Path(semi["motion"]["ground_truth_path"]).is_file()
    assert [s.name for s in cfg.select(splits=["test"])] == [
        "semi_MH_04_difficult", "semi_V1_03_difficult", "semi_V2_02_medium"]


def test_euroc_config_default_data_root_points_at_shared_data():
    data = yaml.safe_load((REPO / "config" / "euroc.yaml").read_text())
    root = wf.data_root(wf.validate_schema(data), REPO / "config" / "euroc.yaml")
    assert root == (REPO.parent / "shared" / "data").resolve()


def test_schema_enums_match_code():
    from pipeline.sim.config import MotionPreset, PoseFormat

    schema = wf.load_schema()
    entry = schema["properties"]["sequences"]["items"]
    assert entry["properties"]["source"]["enum"] == [s.value for s in wf.SourceKind]
    assert entry["properties"]["split"]["enum"] == [s.value for s in wf.Split]
    sim_props = entry["allOf"][0]["then"]["properties"]
    assert sim_props["preset"]["enum"] == [p.value for p in MotionPreset]
    assert sim_props["pose_format"]["enum"] == [p.value for p in PoseFormat]


def _error(tmp_path: Path, data: dict, name: str = "bad.yaml") -> str:
    path = write_config(tmp_path / name, data)
    with pytest.raises(ConfigError) as info:
        wf.load_config(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(str(path)), msg  # every config error names the file
    return msg


def test_rejects_duplicate_names(tmp_path):
    msg = _error(tmp_path, {"sequences": [sim_entry("a"), sim_entry("b"), sim_entry("a", seed=2)]})
    assert "sequences[2] ('a'): duplicate sequence name 'a' (also sequences[0])" in msg
    assert "unique name" in msg


def test_rejects_unknown_source(tmp_path):
    msg = _error(tmp_path, {"sequences": [{"name": "x", "source": "kitti", "path": "."}]})
    assert "sequences[0].source (sequence 'x'): 'kitti' is not one of simulate, asl, tum, csv, bag" in msg


def test_rejects_missing_input_path(tmp_path):
    msg = _error(tmp_path, {"sequences": [{"name": "real", "source": "asl", "path": "nowhere/mav0"}]})
    assert f"sequences[0] ('real'): input path {tmp_path / 'nowhere' / 'mav0'} does not exist" in msg
    assert f"data_root = {tmp_path}" in msg
    # inputs in remote storage: the check can be switched off
    cfg = wf.load_config(write_config(tmp_path / "remote.yaml", {
        "check_input_paths": False, "sequences": [{"name": "real", "source": "asl", "path": "nowhere/mav0"}]}))
    assert cfg.sequence("real").path == tmp_path / "nowhere" / "mav0"


def test_rejects_real_source_without_path(tmp_path):
    msg = _error(tmp_path, {"sequences": [{"name": "real", "source": "bag"}]})
    assert "sequences[0] (sequence 'real'): 'path' is a required property" in msg


def test_rejects_bad_names_and_unknown_keys(tmp_path):
    msg = _error(tmp_path, {"sequences": [sim_entry("a/b")]})
    assert "sequences[0].name (sequence 'a/b'): 'a/b' is not a valid name" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("..")]})
    assert "'..' is not a valid name" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", presett="handheld")]})
    assert "'presett' was unexpected" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a")], "recover": {}})
    assert "'recover' was unexpected" in msg
    msg = _error(tmp_path, {"sequences": []})
    assert "sequences" in msg and "should be non-empty" in msg


def test_rejects_bad_simulator_and_ingest_settings(tmp_path):
    msg = _error(tmp_path, {"sequences": [sim_entry("a", overrides={"imu": {"rate_hzz": 100}})]})
    assert "sequences[0] ('a'): simulator setting: unknown key(s) imu.rate_hzz" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", overrides={"motion": {"preset": "slow_cart"}})]})
    assert "overrides.motion.preset repeats the entry's 'preset'" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", repairs=["sortt"])]})
    assert "sequences[0] ('a'): unknown repair 'sortt'" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a")], "ingest": {"check_options": {"gap_factr": 3}}})
    assert "sequences[0] ('a'): unknown check option(s) gap_factr" in msg
    (tmp_path / "x.bag").write_bytes(b"")
    msg = _error(tmp_path, {"sequences": [{"name": "r", "source": "bag", "path": "x.bag",
                                           "reader": {"imu_topics": "/imu"}}]})
    assert "sequences[0] ('r'): unknown reader option(s) imu_topics" in msg and "imu_topic" in msg
    msg = _error(tmp_path, {"sequences": [{"name": "r", "source": "bag", "path": "x.bag", "reader": {"fmt": "asl"}}]})
    assert "sequences[0] ('r'): reader option(s) fmt cannot be set here (field 'reader'); 'source' sets the format" in msg


def test_rejects_unreadable_config(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        wf.load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("sequences:\n  - name: a\n    source: [simulate\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:4: not valid YAML"):
        wf.load_config(bad)
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="the config must be a mapping, got list"):
        wf.load_config(bad)


# ---------------------------------------------------------------------------------------------
# paths and parameters (what the get_* functions return)


@pytest.fixture()
def mixed_cfg(tmp_path) -> wf.WorkflowConfig:
    (tmp_path / "data" / "seqA" / "mav0").mkdir(parents=True)
    (tmp_path / "data" / "poses.txt").write_text("")
    (tmp_path / "gt.csv").write_text("")
    data = {
        "data_root": "data",
        "sequences": [
            sim_entry("sim1", split="train", preset="slow_cart", pose_format="position",
                      overrides={"poses": {"rate_hz": 20.0}, "imu": {"temperature": {"enabled": False}}}),
            {"name": "seqA", "source": "asl", "path": "seqA", "split": "test", "repairs": ["sort"]},
            {"name": "tum1", "source": "tum", "path": "poses.txt", "check_options": {"allow_pose_only": True}},
            sim_entry("semi", duration_s=None, overrides={"motion": {"ground_truth_path": "../gt.csv"}}),
        ],
        "ingest": {"repairs": ["drop-duplicates"], "check_options": {"gap_factor": 3.0}},
    }
    return wf.load_config(write_config(tmp_path / "cfg.yaml", data))


def test_stage_paths():
    assert wf.stage_dir("ingest", "s1") == "results/ingest/s1"
    assert wf.stage_dir(wf.Stage.SIMULATE, "s1") == "results/simulate/s1"
    assert wf.log_file("ingest", "s1") == "logs/ingest/s1.log"
    with pytest.raises(ValueError):
        wf.stage_dir("nonsense", "s1")


def test_ingest_input_paths(mixed_cfg, tmp_path):
    assert wf.ingest_input(mixed_cfg, "sim1", tmp_path) == "results/simulate/sim1"
    # inside the working directory: relative (portable); outside: absolute
    assert wf.ingest_input(mixed_cfg, "seqA", tmp_path) == "data/seqA"
    assert wf.ingest_input(mixed_cfg, "tum1", tmp_path / "elsewhere") == str(tmp_path / "data" / "poses.txt")
    assert wf.simulate_inputs(mixed_cfg, "sim1", tmp_path) == []
    assert wf.simulate_inputs(mixed_cfg, "semi", tmp_path) == ["gt.csv"]
    with pytest.raises(ConfigError, match=r"no sequence named 'nope' \(field 'sequences'\); configured sequences: sim1, seqA, tum1, semi"):
        wf.ingest_input(mixed_cfg, "nope", tmp_path)


def test_simulate_settings(mixed_cfg, tmp_path):
    from pipeline.sim.config import MotionPreset, PoseFormat, SimConfig

    settings = wf.simulate_settings(mixed_cfg, "sim1")
    assert settings == {
        "name": "sim1", "duration_s": 3, "seed": 1,
        "motion": {"preset": "slow_cart"},
        "poses": {"format": "position", "rate_hz": 20.0},
        "imu": {"temperature": {"enabled": False}},
    }
    sim = SimConfig.from_dict(settings)
    assert sim.motion.preset is MotionPreset.SLOW_CART and sim.poses.format is PoseFormat.POSITION
    assert sim.poses.rate_hz == 20.0 and sim.imu.temperature.enabled is False
    semi = wf.simulate_settings(mixed_cfg, "semi")
    assert semi["duration_s"] is None and semi["motion"]["ground_truth_path"] == str(tmp_path / "gt.csv")
    with pytest.raises(ConfigError, match=r"sequences\[1\] \('seqA'\) is not simulated"):
        wf.simulate_settings(mixed_cfg, "seqA")


def test_ingest_settings(mixed_cfg):
    assert wf.ingest_settings(mixed_cfg, "sim1") == {
        "reader_kwargs": {"fmt": "asl", "name": "sim1"},
        "repairs": ["drop-duplicates"],
        "check_options": {"gap_factor": 3.0},
    }
    assert wf.ingest_settings(mixed_cfg, "seqA")["repairs"] == ["sort"]  # the entry's list replaces the default
    tum = wf.ingest_settings(mixed_cfg, "tum1")
    assert tum["reader_kwargs"] == {"fmt": "tum", "name": "tum1"}
    assert tum["check_options"] == {"gap_factor": 3.0, "allow_pose_only": True}
    opts = wf.make_check_options(tum["check_options"] | {"ignore": ["gyro_degps"]})
    assert opts.gap_factor == 3.0 and opts.allow_pose_only is True and opts.ignore == frozenset({"GYRO_DEGPS"})


def test_final_outputs_registry(mixed_cfg):
    registry = [
        wf.FinalOutput("ingest", "results/ingest/{sequence}"),
        wf.FinalOutput("evaluate", "results/evaluate/{sequence}/metrics.json", splits=(wf.Split.TEST,)),
        wf.FinalOutput("train", "results/train/model.pt"),
        wf.FinalOutput("report", lambda cfg: [f"results/report/{len(cfg.names)}.html"]),
        wf.FinalOutput("simulate", "results/simulate/{sequence}", sources=(wf.SourceKind.SIMULATE,)),
    ]
    assert wf.final_outputs(registry, mixed_cfg) == [
        "results/ingest/sim1", "results/ingest/seqA", "results/ingest/tum1", "results/ingest/semi",
        "results/evaluate/seqA/metrics.json", "results/train/model.pt", "results/report/4.html",
        "results/simulate/sim1", "results/simulate/semi",
    ]
    assert wf.final_outputs(registry[:1] * 2, mixed_cfg) == wf.final_outputs(registry[:1], mixed_cfg)


def test_names_regex():
    import re

    rx = wf.names_regex(["a.b", "c"])
    assert re.fullmatch(rx, "a.b") and re.fullmatch(rx, "c") and not re.fullmatch(rx, "axb")
    assert not re.fullmatch(wf.names_regex([]), "")


# ---------------------------------------------------------------------------------------------
# step helpers and the snakemake driver (no snakemake run)


def test_run_step_logs_and_maps_errors(tmp_path):
    log_path = tmp_path / "logs" / "x.log"

    def ok(a, b):
        logging.getLogger("pipeline.test").info("adding %s", a)
        return a + b

    assert wf.run_step(log_path, ok, 1, 2) == 3
    assert "adding 1" in log_path.read_text()

    def bad():
        raise DataError("the data is wrong", path="in.csv", hint="fix it")

    with pytest.raises(SystemExit) as info:
        wf.run_step(log_path, bad)
    assert info.value.code == 2
    assert "ERROR pipeline.workflow: in.csv: the data is wrong; fix it" in log_path.read_text()

    def bug():
        raise KeyError("k")

    with pytest.raises(KeyError):
        wf.run_step(log_path, bug)
    text = log_path.read_text()
    assert "unexpected error" in text and "Traceback" in text


def test_snakemake_command(tmp_path):
    cmd = wf.snakemake_command(config_file=tmp_path / "c.yaml", cores=3, workdir=tmp_path, dry_run=True,
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
        "2026-01-01 INFO pipeline.workflow: ingesting\n"
        "2026-01-01 00:00:00,000 ERROR pipeline.workflow: in.csv: refusing to convert; rerun with --repair sort\n")
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
    msg = wf.describe_failure(lines, tmp_path)
    assert msg == (f"rule 'ingest' (sequence=a) failed: in.csv: refusing to convert; rerun with --repair sort "
                   f"(log: {tmp_path / 'logs' / 'ingest' / 'a.log'})")
    assert wf.describe_failure(["WorkflowError:", "Target rules may not contain wildcards.", ""], tmp_path) == (
        "Target rules may not contain wildcards.")


def test_parse_dry_run_jobs():
    text = (
        "rule simulate:\n    output: results/simulate/a\n    jobid: 2\n    wildcards: sequence=a\n"
        "localrule ingest:\n    input: results/simulate/a\n    wildcards: sequence=a\n"
        "localrule all:\n    input: results/ingest/a\n    jobid: 0\n"
    )
    assert wf.parse_dry_run_jobs(text) == [("simulate", {"sequence": "a"}), ("ingest", {"sequence": "a"}),
                                           ("all", {})]


def test_cli_reports_bad_config_on_one_line(tmp_path, capsys):
    from pipeline.cli import main

    cfg = write_config(tmp_path / "bad.yaml", {"sequences": [sim_entry("a"), sim_entry("a")]})
    assert main(["run", "--config", str(cfg), "--directory", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"biasgt run: error: {cfg}: sequences[1] ('a'): duplicate sequence name 'a'")
    assert not (tmp_path / ".snakemake").exists()  # snakemake never started


# ---------------------------------------------------------------------------------------------
# real snakemake runs (grouped on one xdist worker; ~40 s together)


def _dry_run_jobs(cfg: Path, workdir: Path) -> list[tuple[str, dict[str, str]]]:
    echo = io.StringIO()
    wf.run_workflow(config_file=cfg, workdir=workdir, dry_run=True, echo=echo)
    return [(rule, w) for rule, w in wf.parse_dry_run_jobs(echo.getvalue()) if rule != "all"]


@SPINE_GROUP
def test_dry_run_of_default_workflow(tmp_path):
    echo = io.StringIO()
    result = wf.run_workflow(workdir=tmp_path, dry_run=True, echo=echo)
    jobs = wf.parse_dry_run_jobs(echo.getvalue())
    names = wf.load_config(wf.DEFAULT_CONFIG).names
    assert sorted(w["sequence"] for r, w in jobs if r == "simulate") == sorted(names)
    assert sorted(w["sequence"] for r, w in jobs if r == "ingest") == sorted(names)
    assert [r for r, _ in jobs].count("all") == 1
    assert result.outputs == [] and not (tmp_path / "results").exists()


def _have_spine() -> str | None:
    try:
        from pipeline.ingest import ingest  # noqa: F401
        from pipeline.io import load_sequence  # noqa: F401
        from pipeline.sim import simulate, write_simulation  # noqa: F401
    except ImportError as exc:
        return f"the simulator or ingest stage is not importable yet ({exc})"
    return None


@pytest.fixture(scope="module")
def spine_run(tmp_path_factory):
    """A real run of simulate + ingest on two 3-second simulated sequences."""
    reason = _have_spine()
    if reason:
        pytest.skip(reason)
    workdir = tmp_path_factory.mktemp("spine")
    cfg = write_config(workdir / "config.yaml", {
        "sequences": [sim_entry("tiny_a", seed=1, split="train"), sim_entry("tiny_b", seed=2, split="test")],
    })
    import argparse

    from pipeline.commands import run

    parser = argparse.ArgumentParser()
    run.register(parser.add_subparsers())
    args = parser.parse_args(["run", "--config", str(cfg), "--directory", str(workdir), "--cores", "2"])
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):  # the 'biasgt run' command, as 'make run' calls it
        code = args.func(args)
    assert code == 0
    return workdir, cfg, stdout.getvalue()


@SPINE_GROUP
def test_real_run_writes_readable_stores(spine_run):
    from pipeline.store import read_store

    workdir, _, printed = spine_run
    assert printed.splitlines() == [
        f"results: {workdir / 'results'}",
        f"  stage: {workdir / 'results' / 'ingest'}",
        f"  stage: {workdir / 'results' / 'simulate'}",
    ]
    for name, seed in (("tiny_a", 1), ("tiny_b", 2)):
        assert (workdir / "results" / "simulate" / name / "mav0" / "imu0" / "data.csv").is_file()
        seq = read_store(workdir / "results" / "ingest" / name)
        assert seq.name == name
        assert seq.imu is not None and 3.0 * 200 - 2 <= len(seq.imu) <= 3.0 * 200 + 2
        assert seq.poses, "the simulated mocap stream must be ingested"
        for stage in ("simulate", "ingest"):
            log_text = (workdir / "logs" / stage / f"{name}.log").read_text()
            assert "INFO" in log_text and "ERROR" not in log_text


@SPINE_GROUP
def test_rerun_only_what_a_config_change_affects(spine_run):
    """--rerun-triggers params: a dry run after editing the config lists only the affected jobs.

    One dry run covers three edits at once (each Snakemake start costs seconds): a simulator
    parameter of tiny_a (-> simulate and ingest of tiny_a), an ingest option of tiny_b (-> ingest of
    tiny_b only, not its simulation) and a later stage's section (-> nothing of the spine).
    """
    workdir, cfg, _ = spine_run
    data = yaml.safe_load(cfg.read_text())
    data["sequences"][0]["seed"] = 7
    data["sequences"][1]["check_options"] = {"gap_factor": 4.0}
    data["recovery"] = {"some_option": 1}
    jobs = _dry_run_jobs(write_config(workdir / "edited.yaml", data), workdir)
    assert sorted(jobs, key=str) == [
        ("ingest", {"sequence": "tiny_a"}), ("ingest", {"sequence": "tiny_b"}), ("simulate", {"sequence": "tiny_a"}),
    ]


@SPINE_GROUP
def test_failed_job_is_one_line_error(tmp_path):
    if _have_spine():
        pytest.skip(_have_spine())
    (tmp_path / "empty_mav0").mkdir()
    cfg = write_config(tmp_path / "cfg.yaml", {"sequences": [{"name": "broken", "source": "asl",
                                                             "path": "empty_mav0"}]})
    with pytest.raises(wf.WorkflowRunError) as info:
        wf.run_workflow(config_file=cfg, workdir=tmp_path, echo=io.StringIO())
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith("workflow failed (snakemake exit 1): rule 'ingest' (sequence=broken) failed: ")
    assert "not an ASL dataset folder" in msg
    assert f"(log: {tmp_path / 'logs' / 'ingest' / 'broken.log'})" in msg
    assert not (tmp_path / "results" / "ingest" / "broken").exists()


def test_extra_pose_inputs_in_config(tmp_path):
    """A real entry may merge poses from other files; they become ingest inputs and reader options."""
    from pipeline import workflow as wf

    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "imu").mkdir()
    (tmp_path / "data" / "gt.txt").write_text("1.0 0 0 0 0 0 0 1\n")
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text(
        "data_root: data\nsequences:\n  - name: s\n    source: asl\n    path: imu\n"
        "    poses: [{path: gt.txt, kind: ground_truth, stream: gt}]\n"
    )
    cfg = wf.load_config(cfg_file)
    settings = wf.ingest_settings(cfg, "s")
    assert settings["reader_kwargs"]["extra_poses"] == [
        {"path": str((tmp_path / "data" / "gt.txt").resolve()), "kind": "ground_truth", "stream": "gt"}
    ]
    assert wf.ingest_extra_inputs(cfg, "s", tmp_path) == ["data/gt.txt"]
    cfg_file.write_text(cfg_file.read_text().replace("gt.txt", "nope.txt"))
    with pytest.raises(ConfigError, match=r"poses\[0\].path"):
        wf.load_config(cfg_file)
