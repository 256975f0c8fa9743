"""The learning stage in the workflow: the ``training:`` section, result paths and the job steps.

Layout (relative to the workflow's folder)::

    results/training/{method}/seed{seed}/       a run of 'biasgt train' (best.pt, last.pt, metrics.csv, run.json)
    results/evaluation/{method}/seed{seed}/     its evaluation (summary.json, windows.parquet, examples.parquet)
    results/evaluation/{reference}/             a reference row (training.baselines.Baseline)
    results/evaluation/table.csv, table.md      Table I
    results/report/training.html                the training report
    logs/training/{method}_seed{seed}.log, logs/evaluation/..., logs/table/table.log, logs/report/training.log

The steps are called by the thin scripts under ``workflow/scripts/`` (train, evaluate, table,
training_report); each is an ordinary function, importable and tested without Snakemake.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from pipeline.configs import dataclass_from_mapping
from pipeline.errors import ConfigError
from training.baselines import Baseline
from training.config import Method, Preset, TrainConfig
from training.evaluate import SUMMARY_JSON, EvaluationConfig, evaluate_reference, evaluate_run
from training.table import TABLE_CSV, TABLE_MD, write_table

log = logging.getLogger(__name__)

__all__ = [
    "TrainingPlan",
    "evaluate_step",
    "evaluation_dir",
    "evaluation_summaries",
    "table_step",
    "training_run_dir",
]

RESULTS = "results"
TABLE_DIR = f"{RESULTS}/evaluation"
TRAINING_REPORT = f"{RESULTS}/report/training.html"
TABLE_LOG = "logs/table/table.log"


@dataclass(frozen=True)
class TrainingPlan:
    """The workflow's ``training:`` section: which runs to train.

    Attributes:
        methods: Learned methods, one job per method and seed.
        seeds: Training seeds (Table I shows mean and spread over seeds).
        preset: Network size preset of every run.
        options: Further :class:`training.config.TrainConfig` options (``max_steps``,
            ``batch_size``, ``lr``, ...; not ``method``, ``seed``, ``preset``).
    """

    methods: tuple[Method, ...] = tuple(Method)
    seeds: tuple[int, ...] = (0,)
    preset: Preset = Preset.SMALL
    options: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "methods", tuple(Method(m) for m in self.methods))
        except ValueError as exc:
            raise ConfigError(f"unknown training method ({exc})", field="training.methods",
                              hint=f"choose from {', '.join(m.value for m in Method)}") from None
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))
        object.__setattr__(self, "preset", Preset(self.preset))
        object.__setattr__(self, "options", dict(self.options))
        reserved = sorted({"method", "seed", "preset"} & set(self.options))
        if reserved:
            raise ConfigError(f"training.options sets {', '.join(reserved)}", field="training.options",
                              hint="give methods, seeds and preset at the top of the training section")
        if len(set(self.seeds)) != len(self.seeds):
            raise ConfigError(f"training seeds repeat: {list(self.seeds)}", field="training.seeds",
                              hint="list each seed once")
        for m in self.methods:
            self.train_config(m, self.seeds[0] if self.seeds else 0)  # bad options fail at load time

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None) -> TrainingPlan:
        """From the (partial) ``training:`` section; one-line :class:`ConfigError` on bad keys or values."""
        return dataclass_from_mapping(cls, d, what="training option", field="training")

    def train_config(self, method: Method | str, seed: int) -> TrainConfig:
        """The :class:`TrainConfig` of one run."""
        return TrainConfig.from_mapping({**self.options, "method": Method(method), "seed": int(seed),
                                         "preset": self.preset})

    def run_settings(self, method: Method | str, seed: int | str) -> dict[str, Any]:
        """Parameters of one train job: its resolved :class:`TrainConfig` as a plain mapping (so that
        adding a method or a seed retrains nothing else)."""
        return self.train_config(method, int(seed)).to_dict()

    def runs(self) -> list[tuple[Method, int]]:
        return [(m, s) for m in self.methods for s in self.seeds]

    def to_dict(self) -> dict[str, Any]:
        return {"methods": [m.value for m in self.methods], "seeds": list(self.seeds), "preset": self.preset.value,
                "options": dict(self.options)}


def training_run_dir(method: Method | str, seed: int | str) -> str:
    """``results/training/{method}/seed{seed}`` (also with Snakemake wildcards as arguments)."""
    return f"{RESULTS}/training/{getattr(method, 'value', method)}/seed{seed}"


def evaluation_dir(name: Method | Baseline | str, seed: int | str | None = None) -> str:
    """``results/evaluation/{method}/seed{seed}`` for a learned run, ``results/evaluation/{reference}`` else."""
    value = getattr(name, "value", name)
    return f"{RESULTS}/evaluation/{value}" + ("" if seed is None else f"/seed{seed}")


def evaluation_summaries(plan: TrainingPlan, evaluation: EvaluationConfig) -> list[str]:
    """Every evaluation folder of the plan (learned runs, then references)."""
    return ([evaluation_dir(m, s) for m, s in plan.runs()]
            + [evaluation_dir(b) for b in evaluation.references])


def table_outputs() -> list[str]:
    return [f"{TABLE_DIR}/{TABLE_CSV}", f"{TABLE_DIR}/{TABLE_MD}"]


def _set_threads(threads: int | None) -> None:
    if threads:
        torch.set_num_threads(int(threads))


def train_step(dataset_dir: str | Path, out_dir: str | Path, config: Mapping[str, Any],
               threads: int | None = None) -> Path:
    """Train one run from its resolved :class:`TrainConfig` mapping (:meth:`TrainingPlan.run_settings`)."""
    from training.train import train

    _set_threads(threads)
    cfg = TrainConfig.from_mapping(config)
    log.info("training %s (preset %s, seed %d) on %s", cfg.method.value, cfg.preset.value, cfg.seed, dataset_dir)
    return train(cfg, Path(dataset_dir), Path(out_dir))


def evaluation_settings(section: Mapping[str, Any]) -> dict[str, Any]:
    """Parameters of an evaluate job: the ``evaluation:`` section without ``references`` (which
    only says which reference jobs exist), so that listing another reference re-evaluates nothing."""
    return {k: v for k, v in section.items() if k != "references"}


def evaluate_step(dataset_dir: str | Path, out_dir: str | Path, settings: Mapping[str, Any], *,
                  run_dir: str | Path | None = None, method: str | None = None, reference: str | None = None,
                  threads: int | None = None) -> Path:
    """Evaluate a trained run (``run_dir``, ``method``) or a reference row (``reference``)."""
    _set_threads(threads)
    config = EvaluationConfig.from_mapping(settings)
    if reference is not None:
        evaluate_reference(Baseline(reference), dataset_dir, out_dir, config)
    else:
        evaluate_run(run_dir, dataset_dir, out_dir, config, method=Method(method))
    log.info("wrote %s", out_dir)
    return Path(out_dir)


def table_step(evaluation_dirs: Sequence[str | Path], out_dir: str | Path) -> Path:
    """Write Table I from the evaluation folders and log it."""
    write_table([Path(d) / SUMMARY_JSON for d in evaluation_dirs], out_dir)
    log.info("Table I:\n%s", (Path(out_dir) / TABLE_MD).read_text(encoding="utf-8"))
    return Path(out_dir)


def learning_outputs(cfg: Any, wf: Any) -> list[str]:
    """Targets of rule ``all`` for the learning stage: Table I and the training report, when the
    window dataset has train, val (the best checkpoint is chosen on it) and test sequences; else
    nothing (the rest of the workflow still runs)."""
    if not all(cfg.select(splits=[split]) for split in ("train", "val", "test")):
        return []
    return table_outputs() + [TRAINING_REPORT]
