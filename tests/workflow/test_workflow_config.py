"""The workflow config: schema defaults, the shipped configs, and the one-line errors for bad configs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from pipeline.errors import ConfigError
from pipeline.types import Split
from biasgt.workflow.config import check_config, load_config, load_schema, SCHEMA_FILE, validate_schema
from biasgt.workflow.params import (
    STAGE_CONFIGS,
    ingest_settings,
    interpolation_settings,
    recovery_settings,
    simulate_settings,
    stage_config,
    validation_settings,
    window_outputs,
    windowed_sequences,
    windows_settings,
)
from biasgt.workflow.table import SIMULATE, data_root, source_kinds
from workflow_configs import sim_entry, write_config

REPO = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------------------------
# schema and checks


def test_default_config_is_valid_with_defaults():
    cfg = load_config(REPO / "config" / "config.yaml")
    assert cfg.names == ["sim_handheld_01", "sim_drone_01", "sim_cart_leica_01", "sim_handheld_val_01",
                         "sim_handheld_test_01"]
    assert all(s.source == SIMULATE for s in cfg.sequences)
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
    assert mh01.source == "asl" and mh01.path == shared_data / "euroc" / "MH_01_easy"
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
    assert "enum" not in entry["properties"]["source"]  # the reader registry's names, checked at start-up
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
    assert "sequences[0].source (sequence 'x'): 'kitti' is not one of simulate, asl, bag, tum, csv" in msg
    assert source_kinds() == ["simulate", "asl", "bag", "tum", "csv"]  # the store is not a workflow source
    msg = _error(tmp_path, {"sequences": [{"name": "x", "source": "store", "path": "."}]})
    assert "'store' is not one of simulate, asl, bag, tum, csv" in msg  # as the schema's enum had it
    msg = _error(tmp_path, {"sequences": [{"name": "x", "source": "asl", "path": ".",
                                           "poses": [{"path": ".", "fmt": "rosbag"}]}]})
    assert "sequences[0].poses[0].fmt (sequence 'x'): 'rosbag' is not one of store, asl, bag, tum, csv" in msg


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
    from training.data.windows_config import WindowConfig
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
    assert "method 'spline' is not one of linear, cubic (field 'interpolation.method')" in msg  # the field once
    msg = _error(tmp_path, {"sequences": seqs, "windows": {"window_len": 2}})
    assert "windows: unknown key 'window_len' (did you mean 'window_s'?)" in msg
    msg = _error(tmp_path, {"sequences": seqs, "report": {"theme": "dark"}})
    assert "report: unknown key 'theme': this section has no options" in msg
    msg = _error(tmp_path, {"sequences": seqs, "recovery": {"keyframe_rate_hz": -1}})
    assert ": must be > 0 or null, got -1 (field 'recovery.keyframe_rate_hz')" in msg
    msg = _error(tmp_path, {"sequences": seqs, "recovery": {"robust_loss": "tukey"}})
    assert "robust_loss 'tukey' is not one of huber, cauchy, none (field 'recovery.robust_loss')" in msg
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


def test_every_config_error_is_reported_at_once_each_field_once(tmp_path):
    """Two misspelled split names and an unknown training method: three problems on one line, each
    field named once with its dotted path (never 'training.training.methods')."""
    msg = _error(tmp_path, {"sequences": [sim_entry("a", split="trian"), sim_entry("b", split="tset"),
                                          sim_entry("c", split="val")],
                            "training": {"methods": ["diffusion_rnn", "nope_method"]}})
    assert msg.startswith(f"{tmp_path / 'bad.yaml'}: 3 problems: [1] ")
    assert "sequences[0].split (sequence 'a'): 'trian' is not one of train, val, test, none (did you mean 'train'?)" in msg
    assert "sequences[1].split (sequence 'b'): 'tset'" in msg and "(did you mean 'test'?)" in msg
    assert "'nope_method'" in msg and msg.count("(field 'training.methods')") == 1
    assert "training.training" not in msg
    assert msg.count("config.schema.yaml") == 1  # a shared hint is said once


def test_errors_after_the_schema_are_collected_too(tmp_path):
    """A schema-valid config with a duplicate name and a bad stage section: both said."""
    msg = _error(tmp_path, {"sequences": [sim_entry("a"), sim_entry("a", seed=2)],
                            "training": {"methods": ["nope_method"]}})
    assert "2 problems" in msg and "duplicate sequence name 'a'" in msg and "(field 'training.methods')" in msg
    assert "training.training" not in msg
