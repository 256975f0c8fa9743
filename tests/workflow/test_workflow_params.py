"""What the workflow's get_* functions return for a config: stage folders and logs, each rule's inputs,
settings and outputs."""

from __future__ import annotations

import pytest

from pipeline.errors import ConfigError
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
from biasgt.workflow.config import load_config
from biasgt.workflow.params import (
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
    windows_inputs,
    windows_settings,
)
from biasgt.workflow.table import SIMULATE, WorkflowConfig
from workflow_configs import sim_entry, write_config


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
        FinalOutput("simulate", "results/simulate/{sequence}", sources=(SIMULATE,)),
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
