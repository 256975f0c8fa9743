"""The learning stage in the workflow: the ``training:`` section, result paths and the job steps.

Layout (relative to the workflow's folder)::

    results/training/{method}/seed{seed}/       a run of 'biasgt train' (best.pt, last.pt, metrics.csv, run.json)
    results/evaluation/{method}/seed{seed}/     its evaluation (summary.json, windows.parquet, predictions.parquet,
                                                examples.parquet)
    results/evaluation/{reference}/             a reference row (training.references)
    results/evaluation/table.csv, table.md      Table I
    results/report/training.html                the training report
    logs/training/{method}_seed{seed}.log, logs/evaluation/..., logs/table/table.log, logs/report/training.log

The steps are called by the thin scripts under ``workflow/scripts/`` (train, evaluate, table,
training_report); each is an ordinary function, importable and tested without Snakemake. The
learning itself (models, dataset, train, evaluate, Table I) is the :mod:`training` package; this
module only wires it to the workflow.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from pipeline.errors import DataError
from training.config import EvaluationConfig, TrainConfig, TrainingPlan
from training.networks import get_network, network_names
from training.references import reference_names
from training.evaluation.table import TABLE_CSV, TABLE_MD, write_table

# torch and the evaluation are imported by the steps that use them: the Snakefile imports this
# module for its paths, and Snakemake parses the Snakefile twice in every cluster job.

log = logging.getLogger(__package__)  # job logs name the workflow glue as one: 'biasgt.workflow'

__all__ = [
    "TrainingPlan",
    "chain_priority",
    "evaluate_step",
    "evaluation_dir",
    "evaluation_summaries",
    "is_sampled",
    "network_names",
    "reference_names",
    "table_step",
    "training_run_dir",
]

RESULTS = "results"
TABLE_DIR = f"{RESULTS}/evaluation"
TRAINING_REPORT = f"{RESULTS}/report/training.html"
TABLE_LOG = "logs/table/table.log"


def training_run_dir(method: str, seed: int | str) -> str:
    """``results/training/{method}/seed{seed}`` (also with Snakemake wildcards as arguments)."""
    return f"{RESULTS}/training/{getattr(method, 'value', method)}/seed{seed}"


def evaluation_dir(name: str, seed: int | str | None = None) -> str:
    """``results/evaluation/{method}/seed{seed}`` for a learned run, ``results/evaluation/{reference}`` else."""
    value = getattr(name, "value", name)
    return f"{RESULTS}/evaluation/{value}" + ("" if seed is None else f"/seed{seed}")


def is_sampled(method: str) -> bool:
    """Whether ``method`` draws samples (a diffusion network): its evaluation reads the sampling options."""
    return get_network(method).is_diffusion


def chain_priority(method: str) -> int:
    """Snakemake priority of ``method``'s train and evaluate jobs: 1 for a sampled model (the longest
    chains, started first so that short jobs fill the cores at the end), else 0."""
    return int(is_sampled(method))


def evaluation_summaries(plan: TrainingPlan, evaluation: EvaluationConfig) -> list[str]:
    """Every evaluation folder of the plan (learned runs, then references)."""
    return ([evaluation_dir(m, s) for m, s in plan.runs()]
            + [evaluation_dir(b) for b in evaluation.references])


def table_outputs() -> list[str]:
    return [f"{TABLE_DIR}/{TABLE_CSV}", f"{TABLE_DIR}/{TABLE_MD}"]


def _set_threads(threads: int | None) -> None:
    import torch

    if threads:
        torch.set_num_threads(int(threads))


def train_step(dataset_dir: str | Path, out_dir: str | Path, config: Mapping[str, Any],
               threads: int | None = None, processes: int = 1) -> Path:
    """Train one run from its resolved :class:`TrainConfig` mapping (:meth:`TrainingPlan.run_settings`),
    as ``processes`` data-parallel processes under torchrun when more than 1."""
    from training.fit.train import train

    _set_threads(threads)
    cfg = TrainConfig.from_mapping(config)
    log.info("training %s (preset %s, seed %d) on %s", cfg.method, cfg.preset.value, cfg.seed, dataset_dir)
    if processes > 1:
        return _train_under_torchrun(cfg, Path(dataset_dir), Path(out_dir), processes)
    return train(cfg, Path(dataset_dir), Path(out_dir))


def evaluation_settings(section: Mapping[str, Any], *, sampled: bool = True) -> dict[str, Any]:
    """Parameters of an evaluate job: the ``evaluation:`` section without ``references`` (which
    only says which reference jobs exist), so that listing another reference re-evaluates nothing;
    without the sampling options (:data:`SAMPLING_OPTIONS`) for a job that draws no
    samples (``sampled`` False: the references), so that changing them reruns only the models'."""
    drop = {"references"} | (set() if sampled else set(SAMPLING_OPTIONS))
    return {k: v for k, v in section.items() if k not in drop}


#: Evaluation options that only matter where samples are drawn (a diffusion model).
SAMPLING_OPTIONS = ("samples", "samplers", "steps", "backend", "sample_rows")

#: Manifest entries that do not change what a model learns or is tested on (why sequences were left
#: out, with the verdict's wording; the code version): left out of :func:`dataset_checksum`.
_VOLATILE_MANIFEST_KEYS = frozenset({"excluded", "code_version", "reasons"})


def _stable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _stable(v) for k, v in value.items() if k not in _VOLATILE_MANIFEST_KEYS}
    if isinstance(value, list):
        return [_stable(v) for v in value]
    return value


def dataset_checksum(root: str | Path) -> str | None:
    """SHA-256 of a window dataset's content: every array file's bytes and the manifest without
    :data:`_VOLATILE_MANIFEST_KEYS`; None when there is no dataset yet. The learning jobs depend on
    it (not on the folder's time stamp): a dataset rewritten with the same content retrains nothing."""
    import hashlib
    import json

    root = Path(root)
    manifest = root / "manifest.json"
    if not manifest.is_file():
        return None
    h = hashlib.sha256()
    h.update(json.dumps(_stable(json.loads(manifest.read_text(encoding="utf-8"))), sort_keys=True).encode())
    for path in sorted(root.rglob("*.npy")):
        h.update(str(path.relative_to(root)).encode())
        with path.open("rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def torchrun_command(config: TrainConfig, dataset_dir: Path, out_dir: Path, processes: int,
                     config_file: Path) -> list[str]:
    """``torchrun --standalone --nproc-per-node N -m biasgt.cli train ...`` for one run.

    ``config_file`` must hold ``config``'s options (YAML); the command line adds nothing else.
    """
    return [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc-per-node={processes}",
            "-m", "biasgt.cli", "-q", "train", "--dataset", str(dataset_dir), "--out", str(out_dir),
            "--config", str(config_file)]


def _train_under_torchrun(config: TrainConfig, dataset_dir: Path, out_dir: Path, processes: int) -> Path:
    """Run one training job as ``processes`` data-parallel processes (DDP) and wait for them.

    Raises:
        DataError: A process failed (its output is in the job's log).
    """
    import subprocess
    import tempfile

    import yaml

    with tempfile.TemporaryDirectory(prefix="biasgt-train-") as tmp:
        config_file = Path(tmp) / "train.yaml"
        config_file.write_text(yaml.safe_dump(config.to_dict(), sort_keys=False), encoding="utf-8")
        command = torchrun_command(config, dataset_dir, out_dir, processes, config_file)
        log.info("launching %d data-parallel processes: %s", processes, " ".join(command))
        run = subprocess.run(command, capture_output=True, text=True)
    for line in (run.stdout + run.stderr).splitlines():
        log.info("torchrun: %s", line)
    if run.returncode != 0:
        raise DataError(f"data-parallel training of {config.method} failed (torchrun exit {run.returncode})",
                        path=out_dir, hint="see the torchrun lines in this job's log")
    return out_dir


def evaluate_step(dataset_dir: str | Path, out_dir: str | Path, settings: Mapping[str, Any], *,
                  run_dir: str | Path | None = None, method: str | None = None, reference: str | None = None,
                  threads: int | None = None) -> Path:
    """Evaluate a trained run (``run_dir``, ``method``) or a reference row (``reference``)."""
    from training.evaluation.evaluate import evaluate_reference, evaluate_run

    _set_threads(threads)
    config = EvaluationConfig.from_mapping(settings)
    if reference is not None:
        evaluate_reference(reference, dataset_dir, out_dir, config)
    else:
        evaluate_run(run_dir, dataset_dir, out_dir, config, method=method)
    log.info("wrote %s", out_dir)
    return Path(out_dir)


def table_step(evaluation_dirs: Sequence[str | Path], out_dir: str | Path) -> Path:
    """Write Table I from the evaluation folders and log it."""
    from training.evaluation.outputs import SUMMARY_JSON

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
