"""The Snakemake workflow spine: config schema and checks, get_* paths, biasgt run, reruns."""

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
from pipeline.layout import (
    WINDOWS_DATASET,
    Stage,
    interpolated_bias_path,
    log_file,
    report_path,
    stage_dir,
    windows_dataset_dir,
)
from pipeline.types import Split
from pipeline.workflow.config import (
    DEFAULT_CONFIG,
    SCHEMA_FILE,
    check_config,
    load_config,
    load_schema,
    validate_schema,
)
from pipeline.workflow.params import (
    STAGE_CONFIGS,
    FinalOutput,
    final_outputs,
    ingest_extra_inputs,
    ingest_input,
    ingest_settings,
    interpolation_outputs,
    interpolation_settings,
    make_check_options,
    names_regex,
    recovery_settings,
    simulate_inputs,
    simulate_settings,
    stage_config,
    validation_settings,
    window_outputs,
    windowed_sequences,
    windows_inputs,
    windows_settings,
)
from pipeline.workflow.run import (
    WorkflowRunError,
    describe_failure,
    parse_dry_run_jobs,
    resolve_profile,
    run_workflow,
    snakemake_command,
)
from pipeline.workflow.steps import interpolate_step, recover_step, report_step, run_step, validate_step, windows_step
from pipeline.workflow.table import SourceKind, WorkflowConfig, data_root

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
    cfg = load_config(REPO / "config" / "config.yaml")
    assert cfg.names == ["sim_handheld_01", "sim_drone_01", "sim_cart_leica_01", "sim_handheld_val_01",
                         "sim_handheld_test_01"]
    assert all(s.source is SourceKind.SIMULATE for s in cfg.sequences)
    assert all(simulate_settings(cfg, n)["duration_s"] <= 60 for n in cfg.names)  # 'make run' stays quick
    assert [s.name for s in cfg.select(splits=["test"])] == ["sim_handheld_test_01"]
    assert [s.name for s in cfg.select(splits=["val"])] == ["sim_handheld_val_01"]
    assert len(cfg.select(splits=["train"])) == 3
    assert window_outputs(cfg) == ["results/windows/dataset"]
    assert cfg.data["report"] == {}
    from training.config import EvaluationConfig, TrainingPlan

    # schema defaults filled in = the dataclasses' view of the same sections
    assert cfg.data["training"] == TrainingPlan.from_mapping(cfg.data["training"]).to_dict()
    assert cfg.data["evaluation"] == EvaluationConfig.from_mapping(cfg.data["evaluation"]).to_dict()
    assert cfg.data["interpolation"] == {"method": "linear", "clamp": True, "write_csv": True}
    assert cfg.data["windows"] == {"window_s": 1.0, "overlap": 0.5, "resample_hz": None, "gap_factor": 2.0,
                                   "accept_warn": False}
    assert cfg.data["recovery"]["keyframe_rate_hz"] is None and cfg.data["recovery"]["pose_stream"] is None
    assert cfg.data["validation"]["window_s"] == 1.0 and cfg.data["validation"]["poses"] is None
    assert cfg.data["ingest"] == {"repairs": [], "check_options": {}}
    assert cfg.config_file == REPO / "config" / "config.yaml"


def test_defaults_filled_like_snakemake_validate(tmp_path):
    from snakemake.utils import validate

    data = {"sequences": [{"name": "a", "source": "simulate"}, {"name": "b", "source": "tum", "path": "x.txt"}]}
    mine = validate_schema(yaml.safe_load(yaml.safe_dump(data)))
    theirs = yaml.safe_load(yaml.safe_dump(data))
    validate(theirs, str(SCHEMA_FILE))
    assert mine == theirs
    a, b = mine["sequences"]
    assert a == {"name": "a", "source": "simulate", "split": "none", "preset": "handheld", "duration_s": 60,
                 "seed": 0, "pose_format": "mocap", "overrides": {}}
    assert b == {"name": "b", "source": "tum", "path": "x.txt", "split": "none", "poses": [], "reader": {}}
    assert mine["data_root"] == "." and mine["check_input_paths"] is True


def test_euroc_semireal_config_is_valid(shared_data):
    data = yaml.safe_load((REPO / "config" / "euroc_semireal.yaml").read_text())
    data["data_root"] = str(shared_data)  # the fixture's folder (may come from BIASGT_SHARED_DATA)
    validate_schema(data)
    cfg = check_config(data, REPO / "config" / "euroc_semireal.yaml")
    mh01 = cfg.sequence("MH_01_easy")
    assert mh01.source is SourceKind.ASL and mh01.path == shared_data / "euroc" / "MH_01_easy"
    semi = simulate_settings(cfg, "semi_MH_04_difficult")
    assert semi["duration_s"] is None
    assert Path(semi["motion"]["ground_truth_path"]).is_file()
    # AirIMU's EuRoC split (which the paper follows), V1_01 aside: every sequence of it is there
    def euroc_names(split: str) -> set[str]:
        return {re.search(r"(MH|V1|V2)_0\d", s.name).group(0) for s in cfg.select(splits=[split])}

    assert euroc_names("test") == {"MH_02", "MH_04", "V1_03", "V2_02"}
    assert euroc_names("train") == {"MH_01", "MH_03", "MH_05", "V1_02", "V2_01", "V2_03"}
    # the poses-only sequences (MH_02, MH_03) are labelled: their bias is simulated
    poses_only = simulate_settings(cfg, "semi_MH_02_easy_simbias")["motion"]["ground_truth_path"]
    assert poses_only.endswith("MH_02_easy.txt") and Path(poses_only).is_file()
    # MH_01: recovered from the raw Leica positions, validated against independent GT poses
    assert recovery_settings(cfg, "MH_01_easy")["pose_stream"] == "leica0"
    assert validation_settings(cfg, "MH_01_easy")["poses"] == "groundtruth_poses"
    # V1_01: OpenVINS's re-estimated bias integrated next to the recovered one (a file resolved against data_root)
    [[name, path]] = validation_settings(cfg, "V1_01_easy")["bias"]
    assert name == "openvins" and path.endswith("V1_01_easy/ov_data/V1_01_easy.csv") and Path(path).is_file()
    assert validation_settings(cfg, "MH_01_easy")["bias"] == []
    assert ingest_settings(cfg, "MH_01_easy")["reader_kwargs"]["extra_poses"][0]["kind"] == "ground_truth"
    assert recovery_settings(cfg, "V1_02_medium_excerpt")["pose_stream"] == "ground_truth"  # GT state only
    # every entry goes through every per-sequence stage; MH_01's real windows take the validation's
    # reference (its GT poses: Leica positions have no orientation)
    assert mh01.split is Split.TRAIN
    assert [s.name for s in windowed_sequences(cfg)] == ["MH_01_easy", "V1_01_easy_openvins"] + [
        s.name for s in cfg.sequences if s.is_simulated]
    assert windows_settings(cfg)["sequences"][0] == ["MH_01_easy", "train", "groundtruth_poses"]
    # the validation split: the real V1_01 IMU labelled from OpenVINS's poses (EuRoC's ground-truth frame
    # puts V1_01's ba_y far outside the training sequences'), read as its own pose stream
    assert [s.name for s in cfg.select(splits=["val"])] == ["V1_01_easy_openvins"]
    assert recovery_settings(cfg, "V1_01_easy_openvins")["pose_stream"] == "openvins_poses"
    assert cfg.sequence("V1_01_easy").split is Split.NONE
    assert window_outputs(cfg) == ["results/windows/dataset"]


def test_euroc_config_is_the_papers_split_on_the_real_recordings(shared_data):
    from training.config import EvalGravity, EvaluationConfig, OracleWalk

    data = yaml.safe_load((REPO / "config" / "euroc.yaml").read_text())
    assert data_root(validate_schema(dict(data)), REPO / "config" / "euroc.yaml").resolve() == (
        REPO.parent / "shared" / "data").resolve()
    data["data_root"] = str(shared_data)
    validate_schema(data)
    cfg = check_config(data, REPO / "config" / "euroc.yaml")
    assert not any(s.is_simulated for s in cfg.sequences)  # real IMU recordings only
    names = lambda split: {s.name for s in cfg.select(splits=[split])}  # noqa: E731
    assert names("train") == {"MH_01_easy", "MH_03_medium", "MH_05_difficult", "V1_02_medium", "V2_01_easy",
                              "V2_03_difficult"}
    assert names("test") == {"MH_04_difficult", "V1_03_difficult", "V2_02_medium"}  # MH_02: no IMU available
    assert names("val") == {"V1_01_easy"}
    for s in cfg.sequences:
        assert (s.path / "mav0" / "imu0" / "data.csv").is_file()
    stream = {s.name: recovery_settings(cfg, s.name)["pose_stream"] for s in cfg.sequences}
    assert {n for n, v in stream.items() if v == "vicon0"} == {"V1_02_medium", "V2_01_easy", "V2_03_difficult"}
    assert {n for n, v in stream.items() if v == "ground_truth"} == {"MH_04_difficult", "MH_05_difficult",
                                                                     "V1_03_difficult", "V2_02_medium"}
    # no ground-truth state: raw Leica labels, validated against (and windows' states from) EuRoC's poses
    assert stream["MH_01_easy"] == stream["MH_03_medium"] == "leica0"
    assert validation_settings(cfg, "MH_01_easy")["poses"] == "groundtruth_poses"
    assert windows_settings(cfg)["sequences"][0] == ["MH_01_easy", "train", "groundtruth_poses"]
    # the test sequences' windows take EuRoC's ground-truth state (validation poses left at null)
    for name in names("test"):
        assert validation_settings(cfg, name)["poses"] is None
        assert (shared_data / "euroc" / name / "mav0" / "state_groundtruth_estimate0" / "data.csv").is_file()
    ev = EvaluationConfig.from_mapping(data["evaluation"])
    assert ev.gravity is EvalGravity.NOMINAL and ev.oracle_random_walk is OracleWalk.SENSOR
    assert "state_bias" in data["evaluation"]["references"]


def test_euroc_config_pose_streams_exist_in_the_recordings(shared_data):
    """Each sequence's recovery stream is in its recording, and the sensor's random walks are EuRoC's."""
    from pipeline.ingest import load

    data = yaml.safe_load((REPO / "config" / "euroc.yaml").read_text())
    data["data_root"] = str(shared_data)
    cfg = check_config(validate_schema(data), REPO / "config" / "euroc.yaml")
    for s in cfg.sequences:
        seq = load(s.path, ingest_settings(cfg, s.name)["reader_kwargs"])
        stream = recovery_settings(cfg, s.name)["pose_stream"]
        assert stream in seq.poses or (stream == "ground_truth" and seq.ground_truth is not None), s.name
        assert (s.split is Split.TEST) <= (seq.ground_truth is not None)  # the evaluation reference
        assert (seq.calibration.gyro_random_walk, seq.calibration.acc_random_walk) == (1.9393e-05, 3.0e-3)


def test_euroc_semireal_config_default_data_root_points_at_shared_data():
    data = yaml.safe_load((REPO / "config" / "euroc_semireal.yaml").read_text())
    root = data_root(validate_schema(data), REPO / "config" / "euroc_semireal.yaml")
    assert root.resolve() == (REPO.parent / "shared" / "data").resolve()


def test_schema_enums_match_code():
    from pipeline.sim.config import MotionPreset, PoseFormat

    schema = load_schema()
    entry = schema["properties"]["sequences"]["items"]
    assert entry["properties"]["source"]["enum"] == [s.value for s in SourceKind]
    assert entry["properties"]["split"]["enum"] == [s.value for s in Split]
    sim_props = entry["allOf"][0]["then"]["properties"]
    assert sim_props["preset"]["enum"] == [p.value for p in MotionPreset]
    assert sim_props["pose_format"]["enum"] == [p.value for p in PoseFormat]


def _error(tmp_path: Path, data: dict, name: str = "bad.yaml") -> str:
    path = write_config(tmp_path / name, data)
    with pytest.raises(ConfigError) as info:
        load_config(path)
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
    cfg = load_config(write_config(tmp_path / "remote.yaml", {
        "check_input_paths": False, "sequences": [{"name": "real", "source": "asl", "path": "nowhere/mav0"}]}))
    assert cfg.sequence("real").path == tmp_path / "nowhere" / "mav0"


def test_rejects_missing_or_malformed_validation_bias_file(tmp_path):
    msg = _error(tmp_path, {"sequences": [sim_entry("a", validation={"bias": {"other": "nowhere.csv"}})]})
    assert f"sequences[0] ('a'): bias file {tmp_path / 'nowhere.csv'} does not exist" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", validation={"bias": ["nowhere.csv"]})]})
    assert "sequences[0] ('a'): validation.bias must map source names to bias files" in msg


def test_rejects_real_source_without_path(tmp_path):
    msg = _error(tmp_path, {"sequences": [{"name": "real", "source": "bag"}]})
    assert "sequences[0] (sequence 'real'): 'path' is a required property" in msg


def test_rejects_bad_names_and_unknown_keys(tmp_path):
    msg = _error(tmp_path, {"sequences": [sim_entry("a/b")]})
    assert "sequences[0].name (sequence 'a/b'): 'a/b' is not a valid name" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("..")]})
    assert "'..' is not a valid name" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", presett="handheld")]})
    assert "unknown key 'presett' (did you mean 'preset'?)" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a")], "recover": {}})
    assert "(top level): unknown key 'recover' (did you mean 'recovery'?)" in msg
    msg = _error(tmp_path, {"sequences": []})
    assert "sequences" in msg and "should be non-empty" in msg


def test_rejects_bad_simulator_and_ingest_settings(tmp_path):
    msg = _error(tmp_path, {"sequences": [sim_entry("a", overrides={"imu": {"rate_hzz": 100}})]})
    assert "sequences[0] ('a'): simulator setting: unknown key 'imu.rate_hzz' (did you mean 'imu.rate_hz'?)" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", overrides={"motion": {"preset": "slow_cart"}})]})
    assert "overrides.motion.preset repeats the entry's 'preset'" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", repairs=["sortt"])]})
    assert "sequences[0] ('a'): unknown repair 'sortt'" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a")], "ingest": {"check_options": {"gap_factr": 3}}})
    assert "sequences[0] ('a'): unknown key 'gap_factr' (did you mean 'gap_factor'?)" in msg
    (tmp_path / "x.bag").write_bytes(b"")
    msg = _error(tmp_path, {"sequences": [{"name": "r", "source": "bag", "path": "x.bag",
                                           "reader": {"imu_topics": "/imu"}}]})
    assert "sequences[0] ('r'): reader option: unknown key 'imu_topics' (did you mean 'imu_topic'?)" in msg
    msg = _error(tmp_path, {"sequences": [{"name": "r", "source": "bag", "path": "x.bag", "reader": {"fmt": "asl"}}]})
    assert "sequences[0] ('r'): reader option(s) fmt cannot be set here (field 'reader'); 'source' sets the format" in msg


def test_stage_sections_take_options_and_defaults_from_the_dataclasses():
    """The schema leaves the stage sections open; their options and defaults are the dataclasses'."""
    from interpolation.config import InterpolationConfig
    from recovery.config import RecoveryConfig
    from training.windows_config import WindowConfig
    from validation.config import ValidationConfig

    props = load_schema()["properties"]
    assert set(STAGE_CONFIGS) <= set(props)
    for section in STAGE_CONFIGS:
        assert "properties" not in props[section] and "additionalProperties" not in props[section], section
    cfg = check_config(validate_schema({"sequences": [sim_entry("a")]}))
    assert stage_config("recovery", recovery_settings(cfg, "a")["config"]) == RecoveryConfig()
    assert stage_config("validation", validation_settings(cfg, "a")["config"]) == ValidationConfig()
    assert stage_config("windows", windows_settings(cfg)["config"]) == WindowConfig()
    assert stage_config("interpolation", interpolation_settings(cfg, "a")) == InterpolationConfig()
    # a changed option reaches the stage; the others keep their defaults
    cfg = check_config(validate_schema({"sequences": [sim_entry("a", recovery={"keyframe_rate_hz": 20})],
                                              "windows": {"window_s": 2}}))
    assert stage_config("recovery", recovery_settings(cfg, "a")["config"]) == RecoveryConfig(keyframe_rate_hz=20)
    assert stage_config("windows", windows_settings(cfg)["config"]) == WindowConfig(window_s=2)


def test_rejects_unknown_and_invalid_stage_options(tmp_path):
    seqs = [sim_entry("a")]
    msg = _error(tmp_path, {"sequences": seqs, "recovery": {"keyframe_rat_hz": 5}})
    assert ("recovery: unknown key 'keyframe_rat_hz' (did you mean 'keyframe_rate_hz'?) (field 'recovery'); "
            "allowed: ") in msg
    assert "pose_stream" in msg and "time_offset_mode" in msg
    msg = _error(tmp_path, {"sequences": seqs, "validation": {"window": 2, "margn": 0.2}})
    assert "validation: unknown keys 'window' (did you mean 'window_s'?), 'margn' (did you mean 'margin'?)" in msg
    msg = _error(tmp_path, {"sequences": seqs, "interpolation": {"method": "spline"}})
    assert "interpolation: method 'spline' is not one of linear, cubic" in msg
    msg = _error(tmp_path, {"sequences": seqs, "windows": {"window_len": 2}})
    assert "windows: unknown key 'window_len' (did you mean 'window_s'?)" in msg
    msg = _error(tmp_path, {"sequences": seqs, "report": {"theme": "dark"}})
    assert "report: unknown key 'theme': this section has no options" in msg
    msg = _error(tmp_path, {"sequences": seqs, "recovery": {"keyframe_rate_hz": -1}})
    assert "recovery: must be > 0 or null, got -1 (field 'recovery.keyframe_rate_hz')" in msg
    msg = _error(tmp_path, {"sequences": seqs, "recovery": {"robust_loss": "tukey"}})
    assert "recovery: robust_loss 'tukey' is not one of huber, cauchy, none" in msg
    # per-sequence overrides: same keys, checked at start-up, naming the entry
    msg = _error(tmp_path, {"sequences": [sim_entry("a", recovery={"pose_strem": "mocap0"})]})
    assert "sequences[0] ('a'): unknown key 'pose_strem' (did you mean 'pose_stream'?) (field 'recovery')" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", recovery={"segment_s": 60, "segment_overlap_s": 40})]})
    assert ("sequences[0] ('a'): must be >= 0 and less than half of segment_s "
            "(field 'recovery.segment_overlap_s')") in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", validation={"refernce": "x"})]})
    assert "sequences[0] ('a'): unknown key 'refernce' (field 'validation')" in msg
    msg = _error(tmp_path, {"sequences": [sim_entry("a", split="training")]})
    assert "'training' is not one of train, val, test, none" in msg


def test_rejects_unreadable_config(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("sequences:\n  - name: a\n    source: [simulate\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:4: not valid YAML"):
        load_config(bad)
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="the config must be a mapping, got list"):
        load_config(bad)


# ---------------------------------------------------------------------------------------------
# paths and parameters (what the get_* functions return)


@pytest.fixture()
def mixed_cfg(tmp_path) -> WorkflowConfig:
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
    return load_config(write_config(tmp_path / "cfg.yaml", data))


def test_stage_paths():
    assert stage_dir("ingest", "s1") == "results/ingest/s1"
    assert stage_dir(Stage.SIMULATE, "s1") == "results/simulate/s1"
    assert log_file("ingest", "s1") == "logs/ingest/s1.log"
    with pytest.raises(ValueError):
        stage_dir("nonsense", "s1")


def test_ingest_input_paths(mixed_cfg, tmp_path):
    assert ingest_input(mixed_cfg, "sim1", tmp_path) == "results/simulate/sim1"
    # inside the working directory: relative (portable); outside: absolute
    assert ingest_input(mixed_cfg, "seqA", tmp_path) == "data/seqA"
    assert ingest_input(mixed_cfg, "tum1", tmp_path / "elsewhere") == str(tmp_path / "data" / "poses.txt")
    assert simulate_inputs(mixed_cfg, "sim1", tmp_path) == []
    assert simulate_inputs(mixed_cfg, "semi", tmp_path) == ["gt.csv"]
    with pytest.raises(ConfigError, match=r"no sequence named 'nope' \(field 'sequences'\); "
                                          r"configured sequences: sim1, seqA, tum1, semi"):
        ingest_input(mixed_cfg, "nope", tmp_path)


def test_simulate_settings(mixed_cfg, tmp_path):
    from pipeline.sim.config import MotionPreset, PoseFormat, SimConfig

    settings = simulate_settings(mixed_cfg, "sim1")
    assert settings == {
        "name": "sim1", "duration_s": 3, "seed": 1,
        "motion": {"preset": "slow_cart"},
        "poses": {"format": "position", "rate_hz": 20.0},
        "imu": {"temperature": {"enabled": False}},
    }
    sim = SimConfig.from_dict(settings)
    assert sim.motion.preset is MotionPreset.SLOW_CART and sim.poses.format is PoseFormat.POSITION
    assert sim.poses.rate_hz == 20.0 and sim.imu.temperature.enabled is False
    semi = simulate_settings(mixed_cfg, "semi")
    assert semi["duration_s"] is None and semi["motion"]["ground_truth_path"] == str(tmp_path / "gt.csv")
    with pytest.raises(ConfigError, match=r"sequences\[1\] \('seqA'\) is not simulated"):
        simulate_settings(mixed_cfg, "seqA")


def test_ingest_settings(mixed_cfg):
    assert ingest_settings(mixed_cfg, "sim1") == {
        "reader_kwargs": {"fmt": "asl", "name": "sim1"},
        "repairs": ["drop-duplicates"],
        "check_options": {"gap_factor": 3.0},
    }
    assert ingest_settings(mixed_cfg, "seqA")["repairs"] == ["sort"]  # the entry's list replaces the default
    tum = ingest_settings(mixed_cfg, "tum1")
    assert tum["reader_kwargs"] == {"fmt": "tum", "name": "tum1"}
    assert tum["check_options"] == {"gap_factor": 3.0, "allow_pose_only": True}
    opts = make_check_options(tum["check_options"] | {"ignore": ["gyro_degps"]})
    assert opts.gap_factor == 3.0 and opts.allow_pose_only is True and opts.ignore == frozenset({"GYRO_DEGPS"})


def test_stage_folders_and_files():
    assert stage_dir("recover", "s") == "results/recovery/s"
    assert stage_dir(Stage.INTERPOLATE, "s") == "results/interpolation/s"
    assert stage_dir("validate", "s") == "results/validation/s"
    assert log_file("recover", "s") == "logs/recovery/s.log"
    assert log_file("windows", WINDOWS_DATASET) == "logs/windows/dataset.log"
    assert windows_dataset_dir() == "results/windows/dataset"
    assert interpolated_bias_path("s") == "results/interpolation/s/bias_imu.parquet"
    assert report_path("s") == "results/report/s/report.html"
    # the report's reader finds the workflow's stage folders
    from reports.quality import STAGE_FOLDERS

    assert STAGE_FOLDERS["recovery"][0] == Stage.RECOVER.folder
    assert STAGE_FOLDERS["validation"][0] == Stage.VALIDATE.folder


def test_stage_settings_merge_entry_overrides(tmp_path):
    cfg = load_config(write_config(tmp_path / "c.yaml", {
        "sequences": [
            sim_entry("a", split="train", recovery={"pose_stream": "ground_truth", "keyframe_rate_hz": 20},
                      validation={"poses": "mocap0", "margin": 0.5}),
            sim_entry("b", split="val"),
            sim_entry("c", split="none"),
            sim_entry("d", split="test"),
        ],
        "recovery": {"keyframe_rate_hz": 50, "robust_loss": "cauchy"},
        "interpolation": {"method": "cubic", "write_csv": False},
        "validation": {"window_s": 2.0, "gravity_mps2": [0, 0, -9.8]},
        "windows": {"window_s": 2.0},
    }))
    a, b = recovery_settings(cfg, "a"), recovery_settings(cfg, "b")
    assert a["pose_stream"] == "ground_truth" and b["pose_stream"] is None
    assert a["config"]["keyframe_rate_hz"] == 20 and b["config"]["keyframe_rate_hz"] == 50
    assert a["config"]["robust_loss"] == b["config"]["robust_loss"] == "cauchy"
    assert "pose_stream" not in a["config"]
    rc = stage_config("recovery", a["config"])
    assert rc.keyframe_rate_hz == 20 and rc.robust_loss.value == "cauchy"
    va, vb = validation_settings(cfg, "a"), validation_settings(cfg, "b")
    assert va["poses"] == "mocap0" and vb["poses"] is None
    assert va["bias"] == vb["bias"] == [] and "bias" not in va["config"]
    assert va["gravity_mps2"] == vb["gravity_mps2"] == [0, 0, -9.8]
    assert va["config"]["margin"] == 0.5 and vb["config"]["margin"] == 0.1 and va["config"]["window_s"] == 2.0
    assert interpolation_settings(cfg, "a") == {"method": "cubic", "clamp": True, "write_csv": False}
    assert interpolation_outputs(cfg) == ["results/interpolation/{sequence}/bias_imu.parquet"]
    assert windows_settings(cfg) == {
        "sequences": [["a", "train", "mocap0"], ["b", "val", None], ["d", "test", None]],  # the validation's poses
        "config": {"window_s": 2.0, "overlap": 0.5, "resample_hz": None, "gap_factor": 2.0, "accept_warn": False},
    }
    assert windows_inputs(cfg) == {
        "stores": ["results/ingest/a", "results/ingest/b", "results/ingest/d"],
        "recoveries": ["results/recovery/a", "results/recovery/b", "results/recovery/d"],
        "validations": ["results/validation/a", "results/validation/b", "results/validation/d"],
    }
    assert window_outputs(cfg) == ["results/windows/dataset"]
    no_train = load_config(write_config(tmp_path / "t.yaml", {"sequences": [sim_entry("x", split="test")]}))
    assert window_outputs(no_train) == []  # no train split: no dataset (normalisation needs train)
    assert interpolation_outputs(no_train) == ["results/interpolation/{sequence}/bias_imu.parquet",
                                                  "results/interpolation/{sequence}/bias_imu.csv"]
    with pytest.raises(ConfigError, match="unknown key 'windw_s' .did you mean 'window_s'"):
        stage_config("validation", {"windw_s": 1})
    with pytest.raises(ConfigError, match="invalid overlap"):
        stage_config("validation", {"overlap": 1.5})


def test_final_outputs_registry(mixed_cfg):
    registry = [
        FinalOutput("ingest", "results/ingest/{sequence}"),
        FinalOutput("evaluate", "results/evaluate/{sequence}/metrics.json", splits=(Split.TEST,)),
        FinalOutput("train", "results/train/model.pt"),
        FinalOutput("report", lambda cfg: [f"results/report/{len(cfg.names)}.html"]),
        FinalOutput("simulate", "results/simulate/{sequence}", sources=(SourceKind.SIMULATE,)),
    ]
    assert final_outputs(registry, mixed_cfg) == [
        "results/ingest/sim1", "results/ingest/seqA", "results/ingest/tum1", "results/ingest/semi",
        "results/evaluate/seqA/metrics.json", "results/train/model.pt", "results/report/4.html",
        "results/simulate/sim1", "results/simulate/semi",
    ]
    assert final_outputs(registry[:1] * 2, mixed_cfg) == final_outputs(registry[:1], mixed_cfg)


def test_names_regex():
    import re

    rx = names_regex(["a.b", "c"])
    assert re.fullmatch(rx, "a.b") and re.fullmatch(rx, "c") and not re.fullmatch(rx, "axb")
    assert not re.fullmatch(names_regex([]), "")


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
    assert "ERROR pipeline.workflow: in.csv: the data is wrong; fix it" in log_path.read_text()

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
    """The Snakefile's imports (pipeline.workflow and its learning module) leave PyTorch out: Snakemake
    parses the Snakefile twice in every cluster job, and importing torch cost 1.3 s each time."""
    code = ("import sys; import pipeline.workflow.config, pipeline.workflow.params, pipeline.workflow.learning; "
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
    from pipeline.cli.app import main

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
    for stage, text in (("ingest", "INFO pipeline.workflow: wrote results/ingest/b\n"),
                        ("recovery", "INFO pipeline.workflow: recovering\n"
                                     "2026-01-01 00:00:00,000 ERROR pipeline.workflow: no pose stream in b\n")):
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
    from pipeline.cli.app import main

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
    assert "WARNING pipeline.workflow: verdict FAIL for 'tiny_b'" in log_path.read_text()
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


STAGE_RULES = ("simulate", "ingest", "recover", "interpolate", "validate", "windows", "report")


@SPINE_GROUP
def test_dry_run_of_default_workflow(tmp_path):
    echo = io.StringIO()
    result = run_workflow(workdir=tmp_path, dry_run=True, echo=echo)
    jobs = parse_dry_run_jobs(echo.getvalue())
    names = load_config(DEFAULT_CONFIG).names
    for rule in STAGE_RULES:
        if rule != "windows":
            assert sorted(w["sequence"] for r, w in jobs if r == rule) == sorted(names), rule
    assert [r for r, _ in jobs].count("windows") == 1
    assert [r for r, _ in jobs].count("all") == 1
    assert result.outputs == [] and not (tmp_path / "results").exists()


def _have_stages() -> str | None:
    try:
        from pipeline.ingest import ingest  # noqa: F401
        from pipeline.io import load_sequence  # noqa: F401
        from pipeline.sim import simulate, write_simulation  # noqa: F401
        from recovery.recover import recover  # noqa: F401
        from reports.quality import build_quality_report  # noqa: F401
        from training.windows import build_window_dataset  # noqa: F401
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

    from pipeline.cli.commands import run

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
        f"reports ({2}):",
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
    assert jobs_after(lambda d: None) == []
    # a recovery option: recover and everything after it, for every sequence; not simulate / ingest
    assert jobs_after(lambda d: d.update(recovery={"keyframe_rate_hz": 50})) == sorted(
        [(r, s) for r in ("recover", "interpolate", "validate", "report") for s in both] + [("windows", "")])
    # one sequence's own recovery override: that sequence's chain (and the dataset) only
    assert jobs_after(lambda d: d["sequences"][1].update(recovery={"keyframe_rate_hz": 50})) == sorted(
        [(r, "tiny_b") for r in ("recover", "interpolate", "validate", "report")] + [("windows", "")])
    # a validation option: validate, report and windows (the verdicts decide which sequences are windowed)
    assert jobs_after(lambda d: d.update(validation={"window_s": 2.0})) == sorted(
        [(r, s) for r in ("validate", "report") for s in both] + [("windows", "")])
    # interpolation and windows options: their own jobs only
    assert jobs_after(lambda d: d.update(interpolation={"method": "cubic"})) == [
        ("interpolate", "tiny_a"), ("interpolate", "tiny_b")]
    assert jobs_after(lambda d: d.update(windows={"overlap": 0.0})) == [("windows", "")]
    # a simulator parameter of one sequence: its whole chain; an ingest option: from ingest on
    def sim_and_ingest(d):
        d["sequences"][0]["seed"] = 7
        d["sequences"][1]["check_options"] = {"gap_factor": 4.0}

    assert jobs_after(sim_and_ingest) == sorted(
        [("simulate", "tiny_a")] + [(r, s) for r in ("ingest", "recover", "interpolate", "validate", "report")
                                    for s in both] + [("windows", "")])


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


def test_extra_pose_inputs_in_config(tmp_path):
    """A real entry may merge poses from other files; they become ingest inputs and reader options."""
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "imu").mkdir()
    (tmp_path / "data" / "gt.txt").write_text("1.0 0 0 0 0 0 0 1\n")
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text(
        "data_root: data\nsequences:\n  - name: s\n    source: asl\n    path: imu\n"
        "    poses: [{path: gt.txt, kind: ground_truth, stream: gt}]\n"
    )
    cfg = load_config(cfg_file)
    settings = ingest_settings(cfg, "s")
    assert settings["reader_kwargs"]["extra_poses"] == [
        {"path": str((tmp_path / "data" / "gt.txt").resolve()), "kind": "ground_truth", "stream": "gt"}
    ]
    assert ingest_extra_inputs(cfg, "s", tmp_path) == ["data/gt.txt"]
    cfg_file.write_text(cfg_file.read_text().replace("gt.txt", "nope.txt"))
    with pytest.raises(ConfigError, match=r"poses\[0\].path"):
        load_config(cfg_file)
