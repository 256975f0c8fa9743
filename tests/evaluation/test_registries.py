"""The network and reference-row registries: a new network or row is one function and one registration,
and it reaches the CLI, the workflow's start-up checks, training, evaluation and Table I; every method
and row name lives in at most two package files; checkpoints of the flat options still load."""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from torch import nn

from biasgt.cli.app import build_parser
from biasgt.workflow.config import load_config
from pipeline.errors import ConfigError
from training.fit.checkpoint import load_checkpoint, load_run, save_checkpoint
from training.config import EvaluationConfig, ModelConfig, TrainConfig, TrainingPlan
from training.evaluation.evaluate import evaluate_reference, evaluate_run
from training import networks, references
from training.networks import Network, Objective, get_network, network_names
from training.references import ReferenceRow, get_reference, reference_names
from training.evaluation.table import TABLE_CSV, TABLE_MD, write_table
from training.fit.train import train
from window_data import make_window_dataset, train_tiny
from workflow_configs import sim_entry, write_config

ROOT = Path(__file__).resolve().parents[2]
DUMMY_NET, DUMMY_ROW = "dummy_linear", "dummy_half_truth"
#: Ground-truth bias halved: its PRMSE lies between the zero row's and the ground-truth row's.
HALF = 0.5


@dataclasses.dataclass(frozen=True)
class DummyOptions:
    width: int = 8


class DummyNet(nn.Module):
    """Regression: the normalised condition [B, T, C] through Linear(C, width) and Linear(width, 6)."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.a = nn.Linear(config.condition_channels, config.network.width)
        self.b = nn.Linear(config.width, 6)

    def forward(self, condition: torch.Tensor) -> torch.Tensor:
        return self.b(self.a(condition))


def half_truth(items: dict, *, bias_mean: np.ndarray, extra_scale: np.ndarray | None) -> np.ndarray:
    assert bias_mean.shape == (6,) and extra_scale is None  # both given as declared
    return HALF * np.asarray(items["bias"], dtype=np.float64)[:, None]


@pytest.fixture()
def dummies():
    """A dummy network and a dummy row, registered through the public API and removed afterwards."""
    networks.register(Network(DUMMY_NET, "Dummy linear", Objective.REGRESSION, "a linear test network", "#000000",
                             DummyOptions, DummyNet, {"tiny": {"width": 4}}))
    references.register(ReferenceRow(DUMMY_ROW, "Half the GT bias", "half the recovered bias (test)", half_truth,
                                    oracle=False, needs=("bias_mean", "info.extra_scale"), default=False))
    try:
        yield
    finally:
        networks.unregister(DUMMY_NET)
        references.unregister(DUMMY_ROW)
    assert DUMMY_NET not in network_names() and DUMMY_ROW not in reference_names()


def _choices(command: str, option: str) -> list[str]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return list(next(a for a in sub.choices[command]._actions if option in a.option_strings).choices)


def test_dummies_reach_cli_config_checks_training_evaluation_and_table(dummies, tmp_path):
    # the CLI's choices
    assert _choices("train", "--method")[-1] == DUMMY_NET
    assert _choices("evaluate", "--method")[-1] == DUMMY_NET
    assert _choices("evaluate", "--reference")[-1] == DUMMY_ROW
    # the workflow config's start-up checks accept them and name them when refusing another
    cfg = load_config(write_config(tmp_path / "ok.yaml", {
        "sequences": [sim_entry("a")], "training": {"methods": [DUMMY_NET]},
        "evaluation": {"references": ["zero", DUMMY_ROW]}}))
    assert cfg.data["training"]["methods"] == [DUMMY_NET]
    assert cfg.data["evaluation"]["references"] == ["zero", DUMMY_ROW]
    with pytest.raises(ConfigError, match=DUMMY_NET):
        TrainingPlan(methods=("no_such_net",))
    with pytest.raises(ConfigError, match=DUMMY_ROW):
        EvaluationConfig(references=("no_such_row",))
    assert DUMMY_ROW not in EvaluationConfig().references  # registered as on request only
    # trained, checkpointed with its own options, evaluated; Table I in registry order
    data = make_window_dataset(tmp_path, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    run = train(TrainConfig(method=DUMMY_NET, preset="tiny", max_steps=3, batch_size=8, val_every=3,
                            checkpoint_every=3, warmup_steps=1, device="cpu", threads=1), data, tmp_path / "run")
    state = load_checkpoint(run / "best.pt")
    assert state["model_config"]["network"] == {"width": 4} and "normalizer" in state and "config" in state
    ev = tmp_path / "evaluation"
    evaluate_run(run, data, ev / DUMMY_NET, EvaluationConfig(samples=2), method=DUMMY_NET)
    zero, gt, half = (evaluate_reference(r, data, ev / r).summary for r in ("zero", "ground_truth", DUMMY_ROW))
    assert half.kind == "reference" and half.label == "Half the GT bias"
    assert gt.row().average.prmse_m < half.row().average.prmse_m < zero.row().average.prmse_m
    write_table([ev / n / "summary.json" for n in (DUMMY_ROW, "zero", DUMMY_NET, "ground_truth")], ev)
    csv = pd.read_csv(ev / TABLE_CSV, index_col=0)
    assert [c.removesuffix(" PRMSE_m") for c in csv.columns if c.endswith("PRMSE_m")] == \
        ["Dummy linear", get_reference("zero").label, get_reference("ground_truth").label, "Half the GT bias"]
    assert csv.loc["Average", "Half the GT bias PRMSE_m"] == pytest.approx(half.row().average.prmse_m, rel=1e-6)
    assert "| Half the GT bias |" in (ev / TABLE_MD).read_text()


def test_checkpoint_with_the_flat_options_of_earlier_versions_still_loads(tmp_path):
    data = make_window_dataset(tmp_path, splits={"train": 1, "val": 1, "test": 1}, duration_s=5.0)
    run = train_tiny(data, tmp_path / "run", "regression_rnn")
    state = load_checkpoint(run / "best.pt")
    new = state["model_config"]
    assert ModelConfig.from_dict(new).network == get_network("regression_rnn").make_options("tiny")
    assert set(new["network"]) == {f.name for f in dataclasses.fields(get_network("regression_rnn").options)}
    # the earlier flat form: every architecture's sizes side by side (the U-Net's at their defaults)
    flat = {k: v for k, v in new.items() if k != "network"} | new["network"] | {
        "unet_dims": [256, 512, 1024], "unet_kernel": 3, "unet_groups": 8}
    old = tmp_path / "old.pt"
    save_checkpoint({**state, "model_config": flat}, old)
    a, b = load_run(run / "best.pt"), load_run(old)
    assert b.model.config == a.model.config
    x = torch.randn(2, 50, 6, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(b.model.net(x), a.model.net(x), rtol=0, atol=0)


class _Stop(Exception):
    pass


def test_evaluate_cli_defaults_are_the_evaluation_configs(monkeypatch, tmp_path):
    seen = {}

    def evaluate_reference(name, dataset, out, config):
        seen["config"] = config
        raise _Stop

    monkeypatch.setattr("training.evaluation.evaluate.evaluate_reference", evaluate_reference)
    args = build_parser().parse_args(["evaluate", "--reference", "zero", "--dataset", str(tmp_path), "--out",
                                      str(tmp_path / "o")])
    with pytest.raises(_Stop):
        args.func(args)
    assert seen["config"] == EvaluationConfig()  # every sampler of the dataclass, not ddim alone


def test_unknown_network_option_names_the_allowed_ones():
    with pytest.raises(ConfigError, match="unknown diffusion_rnn option.*unet_dims") as info:
        ModelConfig.for_preset("diffusion_rnn", "tiny", unet_dims=(8, 16))
    assert "hidden" in info.value.hint
    # a plan's options apply to every method: another network's option is accepted and left to it
    assert TrainConfig(method="diffusion_rnn", model_overrides={"unet_dims": (8, 16)}).model_config().hidden == 64


# ----------------------------------------------------------------------------- one place per name

PACKAGES = ("biasgt", "pipeline", "recovery", "interpolation", "validation", "training", "reports", "workflow")
#: Files where a row's name is another concept's word (not the row): validation's zero-bias source and
#: a variable of the recovery, the ground-truth pose stream / state, the dataset's ground-truth-state bias array.
HOMONYMS = {
    "zero": {"validation/sources.py", "validation/validate.py", "validation/verdict.py", "reports/quality_inputs.py",
             "recovery/solver/calibration_uncertainty.py", "validation/config.py", "reports/dataset.py",
             "reports/dataset_inputs.py"},
    "ground_truth": {"pipeline/checks/options.py", "pipeline/checks/streams.py", "pipeline/checks/__init__.py",
                     "pipeline/checks/run.py", "pipeline/io/__init__.py", "pipeline/io/asl.py", "pipeline/io/_text.py",
                     "pipeline/sim/writer.py", "pipeline/sim/simulator.py", "pipeline/types.py", "pipeline/store.py", "validation/reference.py",
                     "validation/plausibility.py", "reports/quality_residuals.py", "reports/quality_verdict.py",
                     "biasgt/cli/commands/_args.py", "biasgt/workflow/params.py"},
    "state_bias": {"training/data/dataset.py", "training/data/windows.py"},
}


def _package_files() -> list[Path]:
    return [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*")
            if p.suffix in (".py", ".smk") or p.name == "Snakefile"
            if "schemas" not in p.parts]


@pytest.mark.parametrize("name", [*network_names(), *reference_names()])
def test_each_method_and_row_name_lives_in_at_most_two_package_files(name):
    """The registry entry and the implementation: quoted ('name', "name") or marked up (``name``)."""
    pattern = re.compile(rf"""["'`]{re.escape(name)}["'`]""")
    files = sorted(str(p.relative_to(ROOT)) for p in _package_files()
                   if pattern.search(p.read_text(encoding="utf-8", errors="replace")))
    files = [f for f in files if f not in HOMONYMS.get(name, set())]
    assert len(files) <= 2, f"'{name}' is named in {files}"
