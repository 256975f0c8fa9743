"""Where the stages write: ``results/<stage folder>/<sequence>/`` and ``logs/<stage folder>/<sequence>.log``.

The one place that names the stage folders; the workflow's rules, ``biasgt report RESULTS_DIR``
and the runner's summary all use it. The files inside a stage folder are named by the package
that owns the stage (:mod:`recovery.outputs`, :mod:`validation.outputs`, ...).
"""

from __future__ import annotations

import enum

RESULTS_DIR = "results"
LOGS_DIR = "logs"
#: The window dataset (one for the whole config) and its job name in ``logs/windows/``.
WINDOWS_DATASET = "dataset"
#: File names inside the interpolation and report folders.
INTERPOLATED_BIAS = "bias_imu.parquet"
REPORT_HTML = "report.html"
#: The dataset page over every sequence, in ``results/report/``.
DATASET_REPORT_HTML = "index.html"


class Stage(str, enum.Enum):
    """Stages with a results folder, in workflow order; the value is the rule's name."""

    SIMULATE = "simulate"
    INGEST = "ingest"
    RECOVER = "recover"
    INTERPOLATE = "interpolate"
    VALIDATE = "validate"
    WINDOWS = "windows"
    TRAIN = "train"
    EVALUATE = "evaluate"
    REPORT = "report"

    @property
    def folder(self) -> str:
        """Folder name under ``results/`` and ``logs/``: the name of the stage's config section
        (``recovery``, ``interpolation``, ``validation``, ...), else the rule's name."""
        return _STAGE_FOLDERS.get(self, self.value)


_STAGE_FOLDERS = {
    Stage.RECOVER: "recovery",
    Stage.INTERPOLATE: "interpolation",
    Stage.VALIDATE: "validation",
    Stage.TRAIN: "training",
    Stage.EVALUATE: "evaluation",
}


def stage_dir(stage: Stage | str, sequence: str) -> str:
    """``results/<folder>/<sequence>`` (folder: :attr:`Stage.folder`), relative to the working directory."""
    return f"{RESULTS_DIR}/{Stage(stage).folder}/{sequence}"


def log_file(stage: Stage | str, sequence: str) -> str:
    """``logs/<folder>/<sequence>.log`` (folder: :attr:`Stage.folder`), relative to the working directory."""
    return f"{LOGS_DIR}/{Stage(stage).folder}/{sequence}.log"


def interpolated_bias_path(sequence: str) -> str:
    """``results/interpolation/<sequence>/bias_imu.parquet`` (its CSV twin lies next to it)."""
    return f"{stage_dir(Stage.INTERPOLATE, sequence)}/{INTERPOLATED_BIAS}"


def report_path(sequence: str) -> str:
    """``results/report/<sequence>/report.html`` (where ``biasgt report results --sequence NAME`` writes)."""
    return f"{stage_dir(Stage.REPORT, sequence)}/{REPORT_HTML}"


def dataset_report_path() -> str:
    """``results/report/index.html``: the dataset page (where ``biasgt report results`` writes)."""
    return f"{RESULTS_DIR}/{Stage.REPORT.folder}/{DATASET_REPORT_HTML}"


def windows_dataset_dir() -> str:
    """``results/windows/dataset``: the window dataset of all train / val / test sequences."""
    return stage_dir(Stage.WINDOWS, WINDOWS_DATASET)
