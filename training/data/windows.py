"""Training windows: cut recovered sequences into fixed-length IMU windows with bias and states.

Every sequence is cut exactly as the validation cuts it (:func:`validation.metrics.plan_windows`),
so a model is trained and judged on the same windows: ``T = n + 1`` IMU samples with
``n = round(window_s * rate)`` intervals, starting every ``round(n * (1 - overlap))`` samples.
Each window holds:

* ``imu`` [T, 6]: gyro (rad/s) then accelerometer (m/s^2), as recorded (or resampled);
* ``bias`` / ``bias_std`` [T, 6]: the recovery's keyframe bias interpolated to the IMU stamps
  with its sigma (:func:`interpolation.bias.interpolate_bias`), as ``biasgt interpolate`` writes;
  where the validation's held-out check did not confirm an axis' sigma, that axis' sigma times the
  check's factor (``heldout.sigma_check.factor``, :mod:`validation.crossval.sigma`; the manifest's
  ``info.bias_std_factor``), so a label's sigma covers what the held-out blocks showed;
* ``start_*`` / ``end_*``: the reference orientation (world-from-imu, [3, 3]), velocity and
  position at the first and last stamp (the ground-truth state, else the recovery's pose stream
  on the IMU clock and frame: :func:`validation.reference.build_reference`);
* ``t_ns`` [T], the sequence name and, when every sequence's IMU has one, ``temperature_degc`` [T].

The manifest keeps each sequence's provenance (``info``: rates, reference kind, recovery folder,
``label_pose_stream``, ``bias_random_walk`` [6], ``gravity_mps2``, ``sensor_random_walk`` [6],
``bias_std_factor`` [6]) and, with a ground-truth state, that state's own bias at the window stamps
(``state_bias``).

Dropped windows are counted per reason: ``imu_gap``, ``imu_nonfinite``, ``outside_recovery`` (the
bias is never extrapolated) and ``no_reference``.

Rates: all sequences must share one uniform IMU rate (same window length in samples, nominal
rate within 1 %, at most 1 % of intervals more than 10 % off); otherwise extraction stops with a
one-line error naming ``--resample-hz``. With ``resample_hz``, a sequence is interpolated
linearly onto ``t_k = t_first + round(k / resample_hz)`` (ns), leaving out grid points inside IMU
gaps so windows across a gap are still dropped. Linear interpolation does not low-pass filter.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.bias_table import BiasTrack
from pipeline.errors import ConfigError, DataError, InputFormatError, ValidationError
from pipeline.ingest import load
from pipeline.store import is_store, read_store, stored_name
from pipeline.types import NS_PER_S, ImuSeries, Sequence, Split
from recovery.outputs import REPORT_JSON, RecoveryOutputs, bias_sha256, read_report
from validation.metrics import plan_windows, windows_with_any
from validation.reference import ReferenceStates, build_reference, gap_free_mask
from validation.sources import recovered_bias_at_imu
from training.data.dataset import ARRAYS, STATE_BIAS, TEMPERATURE, SequenceWindows, WindowManifest, write_dataset
from training.data.windows_config import WindowConfig
from validation.config import ValidationConfig
from validation.outputs import VALIDATION_JSON, ValidationSummary, Verdict, read_summary

log = logging.getLogger(__name__)

__all__ = [
    "DropReason",
    "WindowConfig",
    "WindowSource",
    "build_window_dataset",
    "extract_windows",
    "format_summary",
    "read_splits_file",
    "resample_imu",
    "sources_from_results",
]

#: Largest relative difference between a sequence's nominal IMU rate and the dataset's.
RATE_TOLERANCE = 0.01
#: An interval more than this (relative) off the nominal one is irregular ...
JITTER_TOLERANCE = 0.10
#: ... and more than this fraction of irregular intervals makes the stamps non-uniform.
MAX_IRREGULAR_FRACTION = 0.01


class DropReason(str, enum.Enum):
    """Why a window is left out of the dataset."""

    IMU_GAP = "imu_gap"
    IMU_NONFINITE = "imu_nonfinite"
    OUTSIDE_RECOVERY = "outside_recovery"
    NO_REFERENCE = "no_reference"


@dataclass(frozen=True)
class WindowSource:
    """One sequence to window.

    Attributes:
        name: Sequence name in the dataset (a folder name).
        split: Its split (the whole sequence belongs to it).
        store_dir: Canonical store (``biasgt convert`` / ingest output) or any readable input.
        recovery_dir: Folder written by ``biasgt recover`` (``bias.csv``, ``recovery.json``).
        validation_dir: Folder written by ``biasgt validate`` for that recovery (its verdict gates
            the sequence), or None (not validated).
        reference_stream: The pose stream the windows' start and end states come from, as in the
            validation's ``--poses`` (None: the ground-truth state, else the recovery's stream).
    """

    name: str
    split: Split
    store_dir: Path
    recovery_dir: Path
    validation_dir: Path | None = None
    reference_stream: str | None = None

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "split", Split(self.split))
        except ValueError:
            raise ConfigError(f"unknown split '{self.split}' for sequence '{self.name}'", field=self.name,
                              hint=f"use one of {', '.join(s.value for s in Split)}") from None
        object.__setattr__(self, "store_dir", Path(self.store_dir))
        object.__setattr__(self, "recovery_dir", Path(self.recovery_dir))
        if self.validation_dir is not None:
            object.__setattr__(self, "validation_dir", Path(self.validation_dir))


# ----------------------------------------------------------------------------- rates


def _nominal_rate_hz(imu: ImuSeries) -> float:
    dt = np.diff(imu.t_ns)
    dt = dt[dt > 0]
    if len(dt) == 0:
        raise DataError("the IMU has fewer than two distinct stamps", hint="give a longer recording")
    return float(NS_PER_S / np.median(dt))


def _irregular_fraction(imu: ImuSeries, gap_factor: float) -> float:
    """Fraction of the non-gap intervals more than JITTER_TOLERANCE off the nominal one."""
    dt = np.diff(imu.t_ns).astype(np.float64)
    nominal = float(np.median(dt))
    inside = dt <= gap_factor * nominal
    if not inside.any():
        return 0.0
    return float(np.mean(np.abs(dt[inside] / nominal - 1.0) > JITTER_TOLERANCE))


def _rate_matches(rate_hz: float, target_hz: float, window_s: float) -> bool:
    return (abs(rate_hz / target_hz - 1.0) <= RATE_TOLERANCE
            and round(window_s * rate_hz) == round(window_s * target_hz))


def resample_imu(imu: ImuSeries, rate_hz: float, *, gap_factor: float = 2.0) -> ImuSeries:
    """The IMU linearly interpolated onto a uniform grid ``t_first + round(k / rate_hz)`` (ns).

    Grid points inside a recorded gap (an interval > ``gap_factor`` x the recorded nominal one)
    are left out, so the result keeps the gap. Temperature is interpolated too.

    Args:
        imu: Recorded IMU, strictly increasing stamps.
        rate_hz: Target rate (Hz).
        gap_factor: Gap threshold of the recorded stamps.

    Returns:
        The resampled IMU, [M] rows.
    """
    t = imu.t_ns
    if len(t) < 2 or np.any(np.diff(t) <= 0):
        raise DataError("cannot resample: the IMU stamps are not strictly increasing",
                        hint="run 'biasgt convert --repair all' first")
    period_ns = NS_PER_S / float(rate_hz)
    m = int(np.floor((int(t[-1]) - int(t[0])) / period_ns + 1e-9)) + 1
    grid = int(t[0]) + np.round(np.arange(m) * period_ns).astype(np.int64)
    grid = grid[gap_free_mask(t, grid, gap_factor)]
    x = (t - t[0]).astype(np.float64)
    xq = (grid - t[0]).astype(np.float64)

    def interp(values: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(xq, x, values[:, i]) for i in range(values.shape[1])])

    temp = None
    if imu.temperature_degc is not None:
        temp = np.interp(xq, x, imu.temperature_degc)
    return ImuSeries(grid, interp(imu.gyro_radps), interp(imu.acc_mps2), temp)


def _uniform_imu(sequence: Sequence, config: WindowConfig, rate_hz: float | None) -> tuple[ImuSeries, dict[str, Any]]:
    """The sequence's IMU at the dataset rate (resampled only when ``config.resample_hz`` asks)."""
    imu = sequence.imu
    rate = _nominal_rate_hz(imu)
    irregular = _irregular_fraction(imu, config.gap_factor)
    target = config.resample_hz if config.resample_hz is not None else rate_hz
    uniform = irregular <= MAX_IRREGULAR_FRACTION
    matches = target is None or _rate_matches(rate, target, config.window_s)
    info: dict[str, Any] = {"recorded_rate_hz": rate, "resampled": False}
    if uniform and matches:
        info["rate_hz"] = rate
        return imu, info
    if config.resample_hz is None:
        if not matches:
            raise DataError(
                f"sequence '{sequence.name}' has an IMU rate of {rate:.3f} Hz, not the dataset's {target:.3f} Hz",
                field="resample_hz",
                hint="give --resample-hz HZ (windows: resample_hz) to resample every sequence onto one uniform grid",
            )
        raise DataError(
            f"sequence '{sequence.name}' has non-uniform IMU stamps ({rate:.3f} Hz nominal, {irregular:.1%} of the "
            f"intervals more than {JITTER_TOLERANCE:.0%} off)", field="resample_hz",
            hint="give --resample-hz HZ (windows: resample_hz) to resample onto a uniform grid",
        )
    log.info("resampling the IMU of '%s' from %.3f Hz to %.3f Hz", sequence.name, rate, config.resample_hz)
    out = resample_imu(imu, config.resample_hz, gap_factor=config.gap_factor)
    info.update(resampled=True, rate_hz=float(config.resample_hz))
    return out, info


# ----------------------------------------------------------------------------- extraction


def state_bias_at(sequence: Sequence, t_ns: np.ndarray) -> np.ndarray | None:
    """The sequence's ground-truth-state bias (gyro, acc) at the stamps ``t_ns`` [...], [..., 6].

    Linear in time between the state's samples (:func:`numpy.interp`); NaN outside its span.
    None when the sequence has no ground-truth state.
    """
    gt = sequence.ground_truth
    if gt is None or len(gt) < 2:
        return None
    x = (gt.t_ns - gt.t_ns[0]).astype(np.float64)
    xq = (np.asarray(t_ns, dtype=np.int64) - gt.t_ns[0]).astype(np.float64).reshape(-1)
    values = np.column_stack([gt.bias_gyro_radps, gt.bias_acc_mps2])
    out = np.column_stack([np.interp(xq, x, values[:, i]) for i in range(6)])
    out[(xq < x[0]) | (xq > x[-1])] = np.nan
    return out.reshape(*np.shape(t_ns), 6)


def _empty_arrays(samples: int) -> dict[str, np.ndarray]:
    shapes = {"imu": (samples, 6), "bias": (samples, 6), "bias_std": (samples, 6), "t_ns": (samples,),
              "start_R": (3, 3), "start_v": (3,), "start_p": (3,), "end_R": (3, 3), "end_v": (3,), "end_p": (3,)}
    return {k: np.zeros((0, *shapes[k]), dtype=np.int64 if k == "t_ns" else np.float64) for k in ARRAYS}


def extract_windows(
    sequence: Sequence,
    recovery_dir: str | Path,
    split: Split | str,
    config: WindowConfig = WindowConfig(),
    *,
    rate_hz: float | None = None,
    reference_stream: str | None = None,
    sigma_factor: tuple[float, ...] | np.ndarray | None = None,
) -> SequenceWindows:
    """Cut one sequence into training windows (see the module docstring).

    Args:
        sequence: The sequence (IMU; ground-truth state or the recovery's pose stream).
        recovery_dir: Its recovery folder (``bias.csv``, ``recovery.json``).
        split: Split of the whole sequence.
        config: Window settings.
        rate_hz: The dataset's IMU rate, which this sequence must match unless resampled (None:
            any uniform rate, or ``config.resample_hz``).
        sigma_factor: Per axis, the factor the bias sigma is widened by (the validation's held-out
            check, ``validation.outputs.ValidationSummary.sigma_factor``), [6] (None: 1).

    Returns:
        The kept windows (arrays [W, T, 6], [W, T], [W, 3, 3], [W, 3]) with drop counts per
        :class:`DropReason`, ``candidates`` and ``info`` (rates, reference kind, folders).

    Raises:
        DataError: No IMU; another or non-uniform rate without ``resample_hz``.
        InputFormatError: Unreadable recovery folder.
        ValidationError: Sequence shorter than one window, no usable reference.
    """
    if sequence.imu is None or len(sequence.imu) < 2:
        raise DataError(f"sequence '{sequence.name}' has no IMU to cut into windows",
                        hint="give the store of a recording with IMU readings")
    split = Split(split)
    recovery_dir = Path(recovery_dir)
    recovery = RecoveryOutputs.read(recovery_dir)
    random_walk = recovery.report.require_random_walk(recovery_dir / REPORT_JSON)
    imu, info = _uniform_imu(sequence, config, rate_hz)
    if info["resampled"]:
        sequence = dataclasses.replace(sequence, imu=imu)
    vcfg = config.validation_config()

    plan = plan_windows(imu, vcfg)
    n, starts = plan.n, plan.starts
    keep = plan.keep.copy()
    dropped = {DropReason.IMU_GAP.value: plan.dropped["imu_gap"],
               DropReason.IMU_NONFINITE.value: plan.dropped["imu_nonfinite"]}

    bias = recovered_bias_at_imu(recovery.bias, imu.t_ns, random_walk)
    factor = np.ones(6) if sigma_factor is None else np.asarray(sigma_factor, dtype=np.float64).reshape(6)
    bias = dataclasses.replace(bias, std=bias.std * factor)
    outside = windows_with_any(np.asarray(bias.clamped, bool), starts, n + 1)
    dropped[DropReason.OUTSIDE_RECOVERY.value] = int(outside.sum())
    keep &= ~outside

    reference = _window_reference(sequence, reference_stream, recovery, vcfg)
    no_ref = ~(reference.valid[starts] & reference.valid[starts + n])
    dropped[DropReason.NO_REFERENCE.value] = int(no_ref.sum())
    keep &= ~no_ref

    s = starts[keep]
    arrays = _window_arrays(sequence, imu, bias, reference, s, n)
    gravity = recovery.report.gravity_world_mps2
    cal = sequence.calibration
    info.update(
        window_samples=n + 1,
        reference=reference.kind.value,
        reference_info=dict(reference.info),
        recovery_dir=str(recovery_dir),
        label_pose_stream=recovery.report.pose_stream,
        bias_random_walk=random_walk.tolist(),
        sensor_random_walk=[cal.gyro_random_walk] * 3 + [cal.acc_random_walk] * 3,
        gravity_mps2=None if gravity is None else gravity.tolist(),
        bias_std_factor=factor.tolist(),
    )
    if not len(s):
        log.warning("sequence '%s': all %d windows dropped (%s)", sequence.name, len(starts),
                    ", ".join(f"{k} {v}" for k, v in dropped.items() if v))
    elif len(s) < len(starts):
        log.info("sequence '%s': %d of %d windows kept (%s)", sequence.name, len(s), len(starts),
                 ", ".join(f"{k} {v}" for k, v in dropped.items() if v))
    return SequenceWindows(sequence.name, split, arrays, dropped, candidates=len(starts), info=info)



def _window_reference(sequence: Sequence, reference_stream: str | None, recovery: RecoveryOutputs,
                      vcfg: ValidationConfig) -> ReferenceStates:
    """The validation's reference: the ground-truth state, else ``reference_stream`` (e.g. ground-truth
    poses when the bias was recovered from position-only Leica data), else the recovery's stream."""
    try:
        reference: ReferenceStates = build_reference(sequence, pose_stream=reference_stream, recovery=recovery,
                                                     config=vcfg)
    except ValidationError as exc:
        if exc.field != "--poses":
            raise
        raise ValidationError(f"sequence '{sequence.name}': no reference for its windows: {exc.problem}",
                              field="reference",
                              hint=(exc.hint or "").replace("validate against", "take the states from")
                              .replace("--poses ", f"--reference {sequence.name}=")
                              + " (workflow: the entry's validation: {poses: STREAM})") from None
    return reference


def _window_arrays(sequence: Sequence, imu: ImuSeries, bias: BiasTrack, reference: ReferenceStates,
                   s: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """The arrays of the windows starting at ``s`` (``n`` steps each): IMU, bias and its std, stamps, the
    reference's start and end states, and (where available and finite) the temperature and the
    ground-truth state's bias."""
    idx = s[:, None] + np.arange(n + 1)[None, :]
    e = s + n
    if len(s):
        imu6 = imu.imu_6
        arrays = {
            "imu": imu6[idx], "bias": bias.bias[idx], "bias_std": bias.std[idx], "t_ns": imu.t_ns[idx],
            "start_R": reference.R[s], "start_v": reference.v[s], "start_p": reference.p[s],
            "end_R": reference.R[e], "end_v": reference.v[e], "end_p": reference.p[e],
        }
    else:
        arrays = _empty_arrays(n + 1)
    if imu.temperature_degc is not None:
        temperature = imu.temperature_degc[idx] if len(s) else np.zeros((0, n + 1))
        if np.isfinite(temperature).all():
            arrays[TEMPERATURE] = temperature
        else:
            log.warning("sequence '%s': non-finite IMU temperatures in the windows; temperature left out",
                        sequence.name)
    state_bias = state_bias_at(sequence, imu.t_ns[idx]) if len(s) else None
    if state_bias is not None:
        arrays[STATE_BIAS] = state_bias
    return arrays


# ----------------------------------------------------------------------------- dataset


def _load_source(source: WindowSource) -> Sequence:
    if is_store(source.store_dir):
        return read_store(source.store_dir)
    if not source.store_dir.exists():
        raise InputFormatError(f"input of sequence '{source.name}' does not exist", path=source.store_dir,
                               hint="give the store folder written by 'biasgt convert' (or the workflow's ingest)")
    return load(source.store_dir)


def _check_sources(sources: list[WindowSource]) -> None:
    if not sources:
        raise ConfigError("no sequence to window", hint="give at least one sequence (--seq or --splits)")
    seen: dict[str, WindowSource] = {}
    for src in sources:
        if src.name in seen:
            a, b = seen[src.name].split.value, src.split.value
            where = f"in splits {a} and {b}" if a != b else f"twice in split {a}"
            raise ConfigError(f"sequence '{src.name}' is listed {where}", field=src.name,
                              hint="name every sequence once, in exactly one split (windows of one recording "
                                   "must never be in two splits)")
        seen[src.name] = src
    if not any(s.split is Split.TRAIN for s in sources):
        raise ConfigError("no sequence in split 'train': normalisation statistics come from the train split",
                          hint="assign at least one sequence to 'train'")


def build_window_dataset(sources: list[WindowSource], out_dir: str | Path,
                         config: WindowConfig = WindowConfig()) -> WindowManifest:
    """Window every source and write the dataset atomically (:func:`training.data.dataset.write_dataset`).

    ``biasgt windows`` and the workflow's windows stage then write the sequence records
    (``context/``, :func:`training.data.records.write_context`: each whole IMU record once, 56 bytes per
    IMU sample, 64 with temperature, whatever the overlap).

    Sequences are loaded, cut and written one at a time. The dataset rate is ``config.resample_hz``
    when set, else the first source's IMU rate; every other sequence must match it (see the module
    docstring). A failure anywhere leaves ``out_dir`` as it was.

    Args:
        sources: The sequences, each in one split; at least one in ``train``.
        out_dir: Dataset folder.
        config: Window settings.

    Returns:
        The manifest (see :func:`training.data.dataset.write_dataset`).

    Raises:
        ConfigError: A sequence listed twice (in one or two splits), no train sequence.
        DataError / InputFormatError / ValidationError: From loading and cutting a sequence.
    """
    sources = list(sources)
    _check_sources(sources)
    for src in sources:
        check_recovery_of_store(src)
    for src in sources:
        if not src.split.windowed:
            log.info("%s: split %s, not windowed", src.name, src.split.value)
    sources = [s for s in sources if s.split.windowed]
    summaries = {src.name: read_summary(src.validation_dir) for src in sources if src.validation_dir is not None}
    excluded = {src.name: left for src in sources
                if (left := verdict_exclusion(src, config, summaries.get(src.name))) is not None}
    for name, left in excluded.items():
        log.warning("sequence '%s' left out of the window dataset: %s", name, left.text)
    usable = [s for s in sources if s.name not in excluded]
    if not any(s.split is Split.TRAIN for s in usable):
        raise unusable_error(sources, excluded)
    sources = usable
    not_validated = [s.name for s in sources if s.validation_dir is None]

    def windows() -> Iterator[SequenceWindows]:
        rate = config.resample_hz
        for src in sources:
            seq = _load_source(src)
            seq = dataclasses.replace(seq, name=src.name)
            factor = summaries[src.name].sigma_factor if src.name in summaries else None
            if factor is not None and max(factor) > 1.0:
                log.warning("sequence '%s': its labels' bias sigma is widened by the validation's held-out check "
                            "(x%s on gyro xyz, acc xyz: %s)", src.name, ", ".join(f"{f:.2f}" for f in factor),
                            Path(src.validation_dir) / VALIDATION_JSON)
            sw = extract_windows(seq, src.recovery_dir, src.split, config, rate_hz=rate,
                                 reference_stream=src.reference_stream, sigma_factor=factor)
            sw.info["store_dir"] = str(src.store_dir)
            if rate is None:
                rate = float(sw.info["rate_hz"])
            yield sw

    return write_dataset(windows(), out_dir, config=config.to_dict(),
                         extra={"excluded": {n: left.text for n, left in excluded.items()},
                                "not_validated": not_validated})


#: Sequences whose reasons the "none is usable" error lists (the worst first); the rest are counted and named
#: (the first :data:`_NAMES_SHOWN`).
_REASONS_SHOWN = 3
_NAMES_SHOWN = 10


@dataclasses.dataclass(frozen=True)
class Exclusion:
    """Why a sequence stays out of the dataset: its validation ``verdict`` and the leading reason."""

    verdict: Verdict
    reason: str

    @property
    def text(self) -> str:
        """``"validation <VERDICT>: <reason>"`` (the manifest's ``excluded`` entry)."""
        return f"validation {self.verdict.value}: {self.reason}"


def unusable_error(sources: list[WindowSource], excluded: Mapping[str, Exclusion]) -> ConfigError:
    """One line for a dataset left without a train sequence by the verdicts: how many sequences are usable,
    the worst few (FAIL before WARN) each with its whole first reason, "and K more" naming the others, and
    where the validation reports are."""
    everyone = len(excluded) == len(sources)
    train = [s.name for s in sources if s.split is Split.TRAIN]
    head = (f"none of the {len(sources)} sequences is usable" if everyone
            else f"none of the {len(train)} train sequence(s) is usable")
    order = sorted((n for n in excluded if everyone or n in train), key=lambda n: excluded[n].verdict is not Verdict.FAIL)
    shown = [f"{n}: {excluded[n].text}" for n in order[:_REASONS_SHOWN]]
    rest = order[_REASONS_SHOWN:]
    names = ", ".join(rest[:_NAMES_SHOWN]) + (", ..." if len(rest) > _NAMES_SHOWN else "")
    more = f"; and {len(rest)} more ({names})" if rest else ""
    folders = [s.validation_dir for s in sources if s.name in excluded and s.validation_dir is not None]
    where = folders[0] if len(folders) == 1 else Path(os.path.commonpath([str(f) for f in folders]))
    warn = any(excluded[n].verdict is Verdict.WARN for n in order)
    reports = (f"{where / VALIDATION_JSON}" if len(folders) == 1 else f"{where}{os.sep}<sequence>{os.sep}{VALIDATION_JSON}")
    return ConfigError(f"{head} (left out by their validation verdict): {'; '.join(shown)}{more}",
                       path=where, hint=(f"the reports say why ({reports}; the workflow's quality report "
                                         "results/report/<sequence>/report.html); fix those recordings"
                                         + (", or set windows.accept_warn (--accept-warn) to take WARN sequences"
                                            if warn else "")))


def verdict_exclusion(source: WindowSource, config: WindowConfig, summary: ValidationSummary | None
                      ) -> Exclusion | None:
    """Why ``source`` stays out of the dataset (its validation verdict, ``summary``: read from its
    ``validation_dir``, None without one), or None to take it.

    Raises:
        ConfigError: The validation judged another sequence or another recovery (:func:`check_validation_judged`).
    """
    if summary is None:
        return None
    check_validation_judged(source, summary)
    if summary.verdict is Verdict.PASS or (summary.verdict is Verdict.WARN and config.accept_warn):
        return None
    return Exclusion(summary.verdict, summary.reasons[0] if summary.reasons else "no reason given")


def check_recovery_of_store(source: WindowSource) -> None:
    """Refuse a recovery folder whose ``recovery.json`` names another sequence than ``source``'s store holds
    (its bias is another recording's). Without a name on either side (a store-less input, a recovery
    written without it) there is nothing to compare.

    Raises:
        ConfigError: Naming the recovery.json, both names and the fix.
    """
    if not source.split.windowed or not (Path(source.recovery_dir) / REPORT_JSON).is_file():
        return
    held, recovered = stored_name(source.store_dir), read_report(source.recovery_dir).data.get("sequence")
    if held is not None and recovered and str(recovered) != held:
        raise ConfigError(f"this recovery is of sequence '{recovered}', but sequence '{source.name}' is cut from "
                          f"store {source.store_dir}, which holds '{held}'", path=Path(source.recovery_dir) / REPORT_JSON,
                          hint=f"give the recovery of '{held}' ('biasgt recover' of that store; the workflow's "
                               f"recovery/{held})")


def check_validation_judged(source: WindowSource, summary: ValidationSummary) -> None:
    """Refuse a validation that judged another sequence than ``source``'s store holds, or another
    recovery than ``source.recovery_dir`` (its ``bias.csv`` by SHA-256): its verdict says nothing of it.

    A validation.json from before the recovery's hash was recorded is checked by the name alone.

    Raises:
        ConfigError: Naming the validation.json, what it judged and the fix.
    """
    where = Path(source.validation_dir) / VALIDATION_JSON
    hint = (f"give the validation of '{source.name}' itself ('biasgt validate' of its store with --recovery "
            f"{source.recovery_dir}; the workflow's validation/{source.name}), or run it again")
    held = stored_name(source.store_dir)
    if held is not None and summary.sequence and summary.sequence != held:
        raise ConfigError(f"this validation judged sequence '{summary.sequence}', but sequence '{source.name}' "
                          f"is cut from store {source.store_dir}, which holds '{held}'", path=where, hint=hint)
    judged = summary.recovery_bias_sha256
    if judged is not None and judged != bias_sha256(source.recovery_dir):
        raise ConfigError(f"this validation judged another recovery than the one sequence '{source.name}' is cut "
                          f"with ({source.recovery_dir}/bias.csv differs from the bias it judged)", path=where,
                          hint=hint)


# ----------------------------------------------------------------------------- splits and results layout


def read_splits_file(path: str | Path) -> dict[Split, list[str]]:
    """Read a splits YAML: ``{train: [NAME, ...], val: [...], test: [...], none: [...]}``.

    Raises:
        ConfigError: Unreadable file, unknown split, a non-list value, or a name in two splits.
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError("splits file not found", path=path) from None
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read the splits file ({exc})", path=path) from None
    if not isinstance(data, dict) or not data:
        raise ConfigError("a splits file is a mapping split -> list of sequence names", path=path,
                          hint="write e.g. 'train: [MH_01, MH_03]' and 'test: [MH_02]'")
    out: dict[Split, list[str]] = {}
    where: dict[str, Split] = {}
    for key, names in data.items():
        try:
            split = Split(str(key))
        except ValueError:
            raise ConfigError(f"unknown split '{key}'", path=path, field=str(key),
                              hint=f"use {', '.join(s.value for s in Split)}") from None
        if names is None:
            names = []
        if not isinstance(names, list) or not all(isinstance(n, (str, int)) for n in names):
            raise ConfigError(f"split '{key}' must be a list of sequence names", path=path, field=str(key))
        for name in map(str, names):
            if name in where:
                a = where[name].value
                detail = f"in splits {a} and {split.value}" if a != split.value else f"twice in split {a}"
                raise ConfigError(f"sequence '{name}' is listed {detail}", path=path, field=name,
                                  hint="name every sequence once, in exactly one split")
            where[name] = split
            out.setdefault(split, []).append(name)
    return out


def sources_from_results(splits: Mapping[Split | str, Iterable[str]], results_dir: str | Path) -> list[WindowSource]:
    """Sources from a workflow results folder: ``DIR/ingest/NAME``, ``DIR/recovery/NAME`` and, when
    it exists, ``DIR/validation/NAME`` (whose verdict then gates the sequence).

    Raises:
        InputFormatError: A store or recovery folder is missing.
    """
    results_dir = Path(results_dir)
    out = []
    for split, names in splits.items():
        for name in names:
            store, rec = results_dir / "ingest" / name, results_dir / "recovery" / name
            for folder, stage in ((store, "ingest"), (rec, "recovery")):
                if not folder.is_dir():
                    raise InputFormatError(f"no {stage} output for sequence '{name}'", path=folder,
                                           hint=f"run the workflow up to the {stage} stage for '{name}' "
                                                "(biasgt run), or give --results the right folder")
            val = results_dir / "validation" / name
            out.append(WindowSource(name, Split(split), store, rec, val if val.is_dir() else None))
    return out


def format_summary(manifest: WindowManifest) -> str:
    """Per-split table: sequences, windows kept, windows dropped (and the reasons)."""
    rows = [("split", "sequences", "windows", "dropped", "reasons")]
    for split in Split:
        names = manifest.names(split)
        if not names:
            continue
        entries = [manifest["sequences"][n] for n in names]
        reasons: dict[str, int] = {}
        for e in entries:
            for k, v in e["dropped"].items():
                reasons[k] = reasons.get(k, 0) + int(v)
        kept = sum(e["windows"] for e in entries)
        dropped = sum(e["candidates"] - e["windows"] for e in entries)
        why = ", ".join(f"{k} {v}" for k, v in reasons.items() if v) or "-"
        rows.append((split.value, str(len(names)), str(kept), str(dropped), why))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    lines = ["  ".join([r[0].ljust(widths[0])] + [c.rjust(w) for c, w in zip(r[1:4], widths[1:])] + [r[4]])
             for r in rows]
    lines += [f"left out: {name}: {reason}" for name, reason in (manifest.get("excluded") or {}).items()]
    if manifest.get("not_validated"):
        lines.append(f"not validated (taken as they are): {', '.join(manifest['not_validated'])}")
    return "\n".join(lines)
