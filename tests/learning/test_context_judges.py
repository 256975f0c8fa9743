"""The configs the label-comparison benchmark derives from config/euroc.yaml (benchmarks/learning/context_judges.py):
each passes the workflow's own config check, and differs from the base only where it says."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import yaml

from biasgt.workflow.config import load_config

REPO = Path(__file__).resolve().parents[2]


def _benchmark():
    spec = importlib.util.spec_from_file_location("context_judges", REPO / "benchmarks" / "learning" / "context_judges.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_derived_configs_check_and_change_only_the_label_or_judge_stream(shared_data, tmp_path):
    bench = _benchmark()
    base = yaml.safe_load(bench.EUROC_CONFIG.read_text())
    bench.write_configs(tmp_path)
    derived = {name: yaml.safe_load((tmp_path / f"{name}.yaml").read_text()) for name in ("labels_gt", "test_vicon0")}
    for name in derived:
        cfg = load_config(tmp_path / f"{name}.yaml")  # the workflow's schema and path checks
        assert len(cfg.sequences) == len(base["sequences"])
    entries = {name: {e["name"]: e for e in cfg["sequences"]} for name, cfg in derived.items()}
    for entry in base["sequences"]:
        gt, vic = entries["labels_gt"][entry["name"]], entries["test_vicon0"][entry["name"]]
        if entry["split"] == "train":
            own = [p["stream"] for p in entry.get("poses", []) if p.get("kind") == "ground_truth"]
            assert gt["recovery"]["pose_stream"] == (own[0] if own else "ground_truth")
        else:
            assert gt == entry
        has_vicon = (shared_data / entry["path"] / "mav0" / "vicon0").is_dir()
        if entry["split"] == "test" and has_vicon:
            assert vic["recovery"]["pose_stream"] == vic["validation"]["poses"] == "vicon0"
        else:
            assert vic == entry
    tests_with_vicon = [n for n, e in entries["test_vicon0"].items() if e.get("validation", {}).get("poses") == "vicon0"]
    assert sorted(tests_with_vicon) == ["V1_03_difficult", "V2_02_medium"]
