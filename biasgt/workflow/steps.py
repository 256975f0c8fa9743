"""Steps: what the thin scripts under ``workflow/scripts/`` call.

:func:`run_step` runs one job with its log file; :func:`simulate_step` / :func:`ingest_step` /
:func:`recover_step` / :func:`interpolate_step` / :func:`validate_step` / :func:`windows_step` /
:func:`report_step` / :func:`dataset_report_step` each run one stage (the stage's heavy libraries load inside the step, in the
job that runs it).
"""

from __future__ import annotations

import logging
import os
import socket
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from pipeline.errors import BiasgtError, ConfigError
from pipeline.ingest import ingest
from pipeline.sim.config import SimConfig
from pipeline.store import read_store
from biasgt.workflow.params import make_check_options, stage_config

log = logging.getLogger(__package__)  # job logs name the workflow glue as one: 'biasgt.workflow'


def run_step(log_path: str | Path, func: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """Run one workflow job with the ``pipeline`` loggers writing to ``log_path``.

    A known error (:class:`BiasgtError`) is logged on one line and ends the process with the
    error's exit code (no traceback), Ctrl-C with 130; any other exception is logged with its traceback and
    re-raised.
    """
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(log_path, mode="w", encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    old_level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    slurm_job = os.environ.get("SLURM_JOB_ID")  # set inside a SLURM job (docs/cluster.md)
    log.info("job on host %s%s", socket.gethostname(), f", SLURM job {slurm_job}" if slurm_job else "")
    try:
        return func(*args, **kwargs)
    except BiasgtError as exc:
        log.error("%s", exc)
        print(f"biasgt: error: {exc}", file=sys.stderr)
        raise SystemExit(exc.exit_code) from None
    except KeyboardInterrupt:  # 'biasgt run' forwards Ctrl-C to Snakemake's process group, jobs included
        log.error("interrupted (SIGINT); nothing half-written was left")
        raise SystemExit(130) from None
    except Exception:
        log.exception("unexpected error (a bug in biasgt; please report it with this log)")
        raise
    finally:
        root.removeHandler(handler)
        root.setLevel(old_level)
        handler.close()


def simulate_step(settings: dict[str, Any], out_dir: str | Path) -> Path:
    """Simulate one sequence from a :class:`SimConfig` dict and write it as an ASL folder."""
    from pipeline.sim.simulator import simulate  # scipy.signal: only in the job that runs the step
    from pipeline.sim.writer import write_simulation  # rosbags: only in the job that runs the step

    config = SimConfig.from_dict(dict(settings))
    log.info("simulating '%s': %.1f s, preset %s, poses %s, seed %d", config.name, config.duration_s or -1,
             config.motion.preset.value, config.poses.format.value, config.seed)
    simulation = simulate(config)
    out = Path(out_dir)
    write_simulation(simulation, out)
    log.info("wrote %s", out)
    return out


def ingest_step(input_path: str | Path, out_dir: str | Path, settings: dict[str, Any]) -> Path:
    """Read, check (and, where allowed, repair) one input and write the canonical store."""
    reader_kwargs = dict(settings.get("reader_kwargs") or {})
    log.info("ingesting %s (format %s) -> %s", input_path, reader_kwargs.get("fmt", "auto"), out_dir)
    ingest(
        input_path, out_dir,
        repairs=list(settings.get("repairs") or []),
        reader_kwargs=reader_kwargs,
        check_options=make_check_options(dict(settings.get("check_options") or {})),
    )
    log.info("wrote %s", out_dir)
    return Path(out_dir)


def recover_step(store_dir: str | Path, out_dir: str | Path, settings: dict[str, Any]) -> Path:
    """Recover the bias of one canonical store and write ``bias.csv``, ``recovery.json``,
    ``trajectory_tum.txt`` (settings: :func:`recovery_settings`)."""
    from recovery.recover import recover, write_recovery  # gtsam: only in the job that runs the step

    config = stage_config("recovery", settings.get("config") or {})
    sequence = read_store(store_dir)
    log.info("recovering the bias of '%s' from pose stream %s", sequence.name,
             settings.get("pose_stream") or "(default)")
    result = recover(sequence, pose_stream=settings.get("pose_stream"), config=config)
    write_recovery(result, out_dir)
    report = result.report
    log.info("wrote %s: %s keyframes over %.1f s from '%s'", out_dir, report.get("keyframes"),
             float(report.get("duration_s") or 0.0), report.get("pose_stream"))
    for warning in result.warnings:
        log.warning("%s", warning)
    return Path(out_dir)


def interpolate_step(recovery_dir: str | Path, store_dir: str | Path, out_path: str | Path,
                     settings: dict[str, Any]) -> list[Path]:
    """Interpolate a recovery's keyframe bias to the store's IMU stamps (settings:
    :func:`interpolation_settings`)."""
    from interpolation.interpolate import interpolate_recovery  # pandas: only in the job that runs the step

    config = stage_config("interpolation", settings)
    written = interpolate_recovery(recovery_dir, store_dir, out_path, config)
    log.info("wrote %s", ", ".join(map(str, written)))
    return written


def validate_step(store_dir: str | Path, recovery_dir: str | Path, out_dir: str | Path,
                  settings: dict[str, Any]) -> Any:
    """Validate one sequence's recovered bias by 1-s integration error and write
    ``validation.json`` + ``windows.parquet`` (settings: :func:`validation_settings`).

    A FAIL verdict is a result (written, logged as a warning, returned); only bad inputs raise.

    Returns:
        The :class:`validation.validate.ValidationResult`.
    """
    from validation.validate import Verdict, validate_inputs, write_validation  # torch: only in this step's job

    config = stage_config("validation", settings.get("config") or {})
    sequence = read_store(store_dir)
    result = validate_inputs(sequence, recovery_dir=recovery_dir, pose_stream=settings.get("poses"),
                             bias_files=[(name, path) for name, path in settings.get("bias") or []],
                             gravity_mps2=settings.get("gravity_mps2"), config=config)
    write_validation(result, out_dir)
    level = logging.WARNING if result.verdict is Verdict.FAIL else logging.INFO
    log.log(level, "verdict %s for '%s'%s", result.verdict.value, result.sequence,
            "".join(f"; {r}" for r in result.reasons))
    log.info("wrote %s", out_dir)
    return result


def windows_step(stores: Sequence[str | Path], recoveries: Sequence[str | Path], validations: Sequence[str | Path],
                 out_dir: str | Path, settings: dict[str, Any]) -> Path:
    """Cut the window dataset of the train / val / test sequences whose validation verdict allows it,
    with its sequence records (``context/``, :func:`training.data.records.write_context`).

    Args:
        stores / recoveries / validations: Each sequence's canonical store, recovery and validation
            folder, in the order of ``settings["sequences"]`` (:func:`windows_inputs`).
        out_dir: The dataset folder.
        settings: :func:`windows_settings`.
    """
    from training.data.records import write_window_dataset  # torch: only in the job of this step
    from training.data.windows import WindowSource

    named = list(settings.get("sequences") or [])
    if not (len(named) == len(stores) == len(recoveries) == len(validations)):
        raise ConfigError(f"windows: {len(named)} sequences but {len(stores)} stores, {len(recoveries)} recoveries "
                          f"and {len(validations)} validations", field="windows",
                          hint="a bug in the workflow wiring; please report it")
    sources = [WindowSource(name, split, str(store), str(rec), str(val), *reference)
               for (name, split, *reference), store, rec, val in zip(named, stores, recoveries, validations)]
    config = stage_config("windows", settings.get("config") or {})
    log.info("cutting windows of %d sequence(s): %s", len(sources),
             ", ".join(f"{s.name} ({s.split})" for s in sources))
    # with its sequence records (the start_rest / sequence_mean rows, context networks), as one
    write_window_dataset(sources, out_dir, config)
    log.info("wrote %s", out_dir)
    return Path(out_dir)


def report_step(ingest_dir: str | Path, recovery_dir: str | Path | None, validation_dir: str | Path | None,
                out_path: str | Path) -> Path:
    """Write the quality report (one self-contained HTML file) of one sequence."""
    from reports.quality import build_quality_report  # matplotlib: only in the job that runs the step

    return build_quality_report(ingest_dir, recovery_dir=recovery_dir, validation_dir=validation_dir,
                                out_path=out_path)


def dataset_report_step(results_dir: str | Path, out_path: str | Path, settings: dict[str, Any]) -> Path:
    """Write the dataset page (``results/report/index.html``) over the config's sequences
    (settings: :func:`biasgt.workflow.params.dataset_report_settings`)."""
    from reports.dataset import build_dataset_report  # matplotlib: only in the job that runs the step

    named = [(str(name), str(split)) for name, split in settings.get("sequences") or []]
    return build_dataset_report(results_dir, out_path, sequences=[n for n, _ in named], splits=dict(named))
