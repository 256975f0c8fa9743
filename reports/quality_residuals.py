"""Sections 5 to 7 of the quality report: residuals, integration windows and Allan deviations.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline.errors import BiasgtError
from pipeline.types import NS_PER_S
from reports import plots
from validation.plausibility import pose_residuals
from recovery.noise.allan import ImuAllan
from reports.html import Html, code_and_words, esc, figure_img, fmt, join, p, section, table, tag, ul
from reports.quality_inputs import (TITLE, MAX_FLAGGED_ROWS, ReportInputs, candidate_name, first_of_kind,
                                    missing_box, num, rel_s, validation_sources, other_estimates_sentence, relative_cell)
from reports.quality_verdict import implausible_frame

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- section 5: residuals


def residuals_section(inp: ReportInputs) -> Html:
    rec = inp.recovery.data if inp.recovery is not None else None  # the JSON object: display fields
    if rec is None and inp.residuals is None and inp.trajectory is None:
        return section("residuals", TITLE["residuals"],
                       missing_box("Not available: the recovery output is missing."))
    parts = []
    if rec is not None:
        res = rec.get("residuals") if isinstance(rec.get("residuals"), dict) else {}
        kf = num(rec, "keyframes")
        out = num(rec, "outliers_rejected")
        rows = [[f"{k.replace('_', ' ')}", fmt(num(res, k), 4)] for k in res if num(res, k) is not None]
        samples = int(num(rec.get("pose_fusion") or {}, "samples_rejected") or 0)
        out = None if out is None else out - samples  # outliers_rejected counts both kinds
        rows.append(["keyframe poses rejected as outliers",
                     "n/a" if out is None else (f"{int(out)} of {int(kf)} keyframes ({out / kf:.2%})" if kf else
                                                f"{int(out)}")])
        if samples:
            rows.append(["pose samples rejected before fusion into keyframes", f"{samples}"])
        for key, label in (("segments", "solver segments"), ("imu_pieces", "gap-free IMU pieces"),
                           ("duration_s", "duration [s]"), ("runtime_s", "recovery runtime [s]")):
            if num(rec, key) is not None:
                rows.append([label, fmt(num(rec, key), 5)])
        seams = rec.get("segment_seams")
        if isinstance(seams, list) and seams:
            rows.append(["segment seams", f"{len(seams)}"])
        parts.append(p("Residual statistics of the recovery's final solve. A whitened residual divides the error "
                       "by its assumed standard deviation: an RMS near 1 means the data agree with the noise model; "
                       "well above 1 means the pose stream and the IMU disagree (wrong extrinsic, clock offset or "
                       "noise), well below 1 means the noise was assumed too large."))
        parts.append(table(["statistic", "value"], rows, numeric_from=1))
    if inp.residuals is not None and len(inp.residuals):
        frame = inp.residuals
        # a flag column (the rejected outliers) is drawn as marks on the residuals, not as a 0/1 series
        flags = [c for c in frame.columns if pd.api.types.is_bool_dtype(frame[c])]
        cols = [c for c in frame.columns if c != "t_ns" and c not in flags
                and pd.api.types.is_numeric_dtype(frame[c])][:6]
        if cols:
            t_s = rel_s(frame["t_ns"].to_numpy(), inp.t0_ns)
            outliers = frame[flags[0]].to_numpy(bool) if flags else None
            parts.append(figure_img(plots.residual_series_figure(t_s, {c: frame[c].to_numpy(float) for c in cols},
                                                                 outliers),
                                    "residuals per keyframe", "Residuals per keyframe, as written by the recovery"
                                    + ("; red lines: keyframes rejected as outliers." if flags else ".")))
    else:
        parts.append(missing_box("Per-keyframe residuals are not available: the recovery writes only the "
                                  "statistics above. The figure below compares the recovered trajectory with the "
                                  "pose stream instead."))
    fig = implausible_frame(inp, "rotation_residual", _pose_residual_figure(inp))
    if fig is not None:
        parts.append(fig)
    warnings = [str(w) for w in ((rec or {}).get("warnings") or [])]
    parts.append(tag("h3", "Warnings of the recovery"))
    parts.append(ul(warnings) if warnings else p("None."))
    return section("residuals", TITLE["residuals"], join(parts))


def _pose_residual_figure(inp: ReportInputs) -> Html | None:
    rec, traj, seq = inp.recovery, inp.trajectory, inp.sequence
    if rec is None or traj is None:
        return None
    name = rec.get("pose_stream")
    poses = seq.poses.get(name) if isinstance(name, str) else None
    if poses is None and name == "ground_truth" and seq.ground_truth is not None:
        poses = seq.ground_truth.to_pose_series()
    if poses is None or len(poses) < 2:
        return missing_box(f"The pose stream '{name}' used by the recovery is not in the store: the trajectory "
                            "cannot be compared with it.")
    try:
        t_ns, pos_err, rot_err = pose_residuals(traj, poses, rec.T_imu_pose, rec.time_offset_s)
    except (BiasgtError, ValueError, TypeError) as exc:
        return missing_box(f"The trajectory could not be compared with the pose stream ({exc}).")
    if len(t_ns) == 0:
        return missing_box("The recovered trajectory and the pose stream do not overlap in time.")
    rot_txt = "" if rot_err is None else f", rotation RMS {fmt(np.sqrt(np.mean(rot_err ** 2)), 3)} deg"
    caption = (f"Distance between the recovered IMU trajectory and the pose stream '{name}' moved into the IMU frame "
               f"and clock: position RMS {fmt(1e3 * np.sqrt(np.mean(pos_err ** 2)), 3)} mm, max "
               f"{fmt(1e3 * pos_err.max(), 3)} mm{rot_txt} ({len(t_ns):,} keyframes).")
    outlier_t_s = None
    if len(rec.outlier_t_ns):
        outlier_t_s = rel_s(rec.outlier_t_ns, inp.t0_ns)
        caption += " Red lines: poses rejected as outliers."
    return figure_img(plots.pose_residual_figure(rel_s(t_ns, inp.t0_ns), pos_err, rot_err, outlier_t_s),
                      "pose residuals over time", caption)


# ----------------------------------------------------------------------------- section 6: integration


def integration_section(inp: ReportInputs) -> Html:
    v = inp.validation
    if v is None:
        return section("integration", TITLE["integration"],
                       missing_box("Not available: the validation output (validation.json) is missing."))
    sources = validation_sources(v)
    cand = candidate_name(v)
    const = first_of_kind(v, "constant_first_window", None)
    rows = _source_rows(sources, cand, const)
    cfg = v.get("config") if isinstance(v.get("config"), dict) else {}
    win = num(cfg, "window_s") or 1.0
    parts = [
        p(f"Each source's bias is removed from the IMU readings, which are then integrated over {fmt(win, 3)}-s "
          "windows from the reference state; the end of each window is compared with the reference. PRMSE is the RMS "
          "position error, ROE the mean rotation error. Lower is better; the bias judged by the verdict is marked."),
        table(["bias source", "kind", "windows", "PRMSE [mm]", "ROE [deg]", "PRMSE vs constant", "flagged"], rows,
              numeric_from=2),
    ]
    others = other_estimates_sentence(v)
    if others:
        parts.append(p(others))
    dropped = v.get("windows_dropped") if isinstance(v.get("windows_dropped"), dict) else None
    if dropped:
        text = ", ".join(f"{k} {fmt(x, 4) if not isinstance(x, dict) else ''}".strip() for k, x in dropped.items()
                         if not isinstance(x, dict))
        by = dropped.get("by_reason")
        if isinstance(by, dict) and by:
            shown = {k: x for k, x in by.items() if x}
            if shown:
                text = Html(esc(text + "; by reason: ") + join((Html(code_and_words(k) + esc(f": {x}"))
                                                                 for k, x in shown.items()), sep=", "))
        parts.append(p(Html(esc("Windows: ") + esc(text) + "."), class_="small"))
    elif v.get("windows_dropped") is not None:
        parts.append(p(f"Windows dropped: {v.get('windows_dropped')}.", class_="small"))
    ref = v.get("reference")
    if isinstance(ref, dict) and ref.get("kind"):
        parts.append(p(f"Reference: {reference_words(ref)}.", class_="small"))
    w = inp.windows
    if w is not None and len(w) and {"source", "pos_err_m", "rot_err_deg"} <= set(w.columns):
        names = list(dict.fromkeys(w["source"].astype(str)))
        parts.append(figure_img(plots.error_distribution_figure(
            names, [w.loc[w["source"] == n, "pos_err_m"].to_numpy(float) for n in names],
            [w.loc[w["source"] == n, "rot_err_deg"].to_numpy(float) for n in names]),
            "integration-error distributions per bias source",
            "Per-window errors per bias source (box: quartiles, whiskers: 5th–95th percentile, log scale)."))
        if cand is not None and cand in names and "t0_ns" in w.columns:
            wc = w[w["source"] == cand]
            flagged = wc["flagged"].to_numpy(bool) if "flagged" in wc.columns else None
            parts.append(figure_img(plots.window_errors_over_time_figure(
                rel_s(wc["t0_ns"].to_numpy(), inp.t0_ns), wc["pos_err_m"].to_numpy(float),
                wc["rot_err_deg"].to_numpy(float), flagged, cand),
                "integration error over time", f"Per-window errors of '{cand}' over time; flagged windows circled."))
    elif w is None:
        parts.append(missing_box("The per-window errors (windows.parquet) are missing: no distributions drawn."))
    parts.append(tag("h3", "Flagged windows" + (f" of '{cand}'" if cand else "")))
    flagged_list = (sources.get(cand) or {}).get("flagged") or [] if cand else []
    if flagged_list:
        parts += _flagged_parts(inp, flagged_list, cfg, win)
    else:
        parts.append(p("None."))
    notes = [str(n) for n in v.get("notes") or []]
    if notes:
        parts.append(p("Notes of the validation:"))
        parts.append(ul(notes))
    return section("integration", TITLE["integration"], join(parts))


def reference_words(ref: dict[str, Any]) -> str:
    """The validation reference in words (``state`` -> the dataset's ground-truth state), its kind kept."""
    kind = str(ref.get("kind"))
    if kind == "state":
        return "the dataset's ground-truth state (position, velocity, orientation; kind 'state')"
    if ref.get("stream"):
        return f"the pose stream '{ref['stream']}' (kind '{kind}')"
    return f"kind '{kind}'"


def _source_rows(sources: dict[str, Any], cand: str | None, const: str | None) -> list[list[Any]]:
    """One table row per bias source: windows, PRMSE, ROE, PRMSE relative to the constant bias, flags."""
    rows = []
    for name, s in sources.items():
        prmse, roe = num(s, "prmse_m"), num(s, "roe_deg")
        rel = "—"
        if const is not None and name != const:
            rel = relative_cell(prmse, num(sources[const], "prmse_m"))
        nflag = len(s.get("flagged") or [])
        label = name + (" (judged)" if name == cand else "")
        rows.append([label, s.get("kind", "n/a"), fmt(num(s, "windows"), 6),
                     fmt(None if prmse is None else 1e3 * prmse, 4), fmt(roe, 4), rel, str(nflag)])
    return rows


def _flagged_parts(inp: ReportInputs, flagged_list: list[dict[str, Any]], cfg: dict, win: float) -> list[Any]:
    """The flagged windows of the judged source: merged into stretches, then every one (folded)."""
    out: list[Any] = []
    overlap = num(cfg, "overlap")
    stride_s = win * (1.0 - (0.5 if overlap is None else overlap))
    out.append(p("Windows whose error is far above the source's median (an outlier in the pose stream, a "
               "bias jump, or a stretch the IMU model does not fit), merged into stretches of consecutive "
               "windows. Times in seconds from the first IMU sample."))
    srows = [[f"{(a - inp.t0_ns) / NS_PER_S:.3f}", f"{(b - inp.t0_ns) / NS_PER_S + win:.3f}", str(n),
              fmt(1e3 * pmax, 4), fmt(rmax, 4)]
             for a, b, n, pmax, rmax in flagged_stretches(flagged_list, stride_s)]
    out.append(table(["from [s]", "to [s]", "windows", "max position error [mm]", "max rotation error [deg]"],
                     srows, numeric_from=0))
    frows = []
    for f in flagged_list[:MAX_FLAGGED_ROWS]:
        t0 = int(f.get("t0_ns", 0))
        frows.append([f"{(t0 - inp.t0_ns) / NS_PER_S:.3f}",
                      fmt(1e3 * (num(f, "pos_err_m") or math.nan), 3), fmt(num(f, "rot_err_deg"), 3)])
    more = len(flagged_list) - MAX_FLAGGED_ROWS
    detail = join([
        table(["start [s]", "position error [mm]", "rotation error [deg]"], frows, numeric_from=0),
        p((f"… and {more} more; " if more > 0 else "") + "validation.json holds every one with its exact start "
          "stamp (t0_ns).", class_="small"),
    ])
    out.append(tag("details", Html(tag("summary", f"Every flagged window ({len(flagged_list)})") + detail)))
    return out


def flagged_stretches(flagged: list[dict[str, Any]], stride_s: float) -> list[tuple[int, int, int, float, float]]:
    """Consecutive flagged windows merged: ``[(first_t0_ns, last_t0_ns, count, max_pos_m, max_rot_deg)]``.

    Two flagged windows belong to the same stretch when their starts are at most 1.5 strides apart.
    """
    rows = sorted(((int(f.get("t0_ns", 0)), num(f, "pos_err_m") or 0.0, num(f, "rot_err_deg") or 0.0)
                   for f in flagged), key=lambda r: r[0])
    out: list[list[Any]] = []
    limit = 1.5 * stride_s * NS_PER_S
    for t0, pe, re_ in rows:
        if out and t0 - out[-1][1] <= limit:
            last = out[-1]
            last[1], last[2], last[3], last[4] = t0, last[2] + 1, max(last[3], pe), max(last[4], re_)
        else:
            out.append([t0, t0, 1, pe, re_])
    return [tuple(r) for r in out]  # type: ignore[misc]


# ----------------------------------------------------------------------------- section 7: Allan


def calibration_origin(cal: Any, key: str) -> str:
    """Where a calibration value came from: the file (folder/name), the config, or the default."""
    origin = cal.value_sources()[key]
    path = Path(origin)
    return f"{path.parent.name}/{path.name}" if path.suffix in (".yaml", ".yml") else origin


def allan_cell(x: float, static: bool, is_rw: bool) -> str:
    """One fitted value as shown: a value, an upper bound (motion), or why there is none."""
    if not static:
        return "— (motion)" if is_rw else (f"≤ {fmt(x, 3)}" if np.isfinite(x) else "n/a")
    return fmt(x, 3) if np.isfinite(x) else "not visible"


def _allan_ratio(fits: np.ndarray, yaml_v: float, static: bool, is_rw: bool) -> str:
    if (is_rw and not static) or not np.isfinite(fits).any() or not yaml_v:
        return "n/a"
    ratio = f"{float(np.nanmean(fits)) / yaml_v:.3g}×"
    return ratio if static else f"≤ {ratio}"


def allan_section(inp: ReportInputs, allan: ImuAllan | None, error: str | None) -> Html:
    cal = inp.sequence.calibration
    if allan is None:
        return section("allan", TITLE["allan"], missing_box(f"Not available: {error or 'no IMU data'}."))
    if allan.static:
        where = (f"Computed on the {len(allan.segments_s)} stretch(es) where the IMU is at rest "
                 f"({allan.used_s:.1f} s in total; longest {max(b - a for a, b in allan.segments_s):.1f} s), "
                 "pooled. This is the sensor's own noise.")
        cls = None
    else:
        why = " ".join(allan.notes)
        where = (f"Computed on the whole recording ({allan.used_s:.1f} s) because {why or 'it has no rest'}. "
                 "Motion dominates the curves then: they show the motion, not the sensor noise, so only an upper "
                 "bound of the white noise is given and the bias random walk cannot be read. Record a few minutes "
                 "at rest for a real noise estimate.")
        cls = "warnbox"
    parts = [tag("div", where, class_=cls) if cls else p(where),
             p("Overlapping Allan deviation per axis. Dotted line: white noise (slope −½, its value at τ = 1 s is "
               "the noise density); dash-dotted line: bias random walk (slope +½, its value at τ = 3 s is the random "
               "walk). Black: fitted to this recording; orange: the calibration.")]
    # a calibration nobody gave (a bag, a CSV) is the datasheet default: the legend says so
    defaulted = cal.defaulted()
    label = "default (EuRoC ADIS16448)" if defaulted else "sensor.yaml"
    parts.append(figure_img(plots.allan_figure(
        allan.taus, allan.adev_gyro, title="Gyroscope", unit="rad/s", white=allan.gyro_white,
        random_walk=allan.gyro_rw, sensor_white=cal.gyro_noise_density, sensor_random_walk=cal.gyro_random_walk,
        fits_are_bounds=not allan.static, sensor_label=label),
        "gyroscope Allan deviation", "Gyroscope Allan deviation."))
    parts.append(figure_img(plots.allan_figure(
        allan.taus, allan.adev_acc, title="Accelerometer", unit="m/s²", white=allan.acc_white,
        random_walk=allan.acc_rw, sensor_white=cal.acc_noise_density, sensor_random_walk=cal.acc_random_walk,
        fits_are_bounds=not allan.static, sensor_label=label),
        "accelerometer Allan deviation", "Accelerometer Allan deviation."))
    rows = []
    for label, fits, yaml_v, unit, is_rw in (
        ("gyro white noise", allan.gyro_white, cal.gyro_noise_density, "rad/s/√Hz", False),
        ("gyro bias random walk", allan.gyro_rw, cal.gyro_random_walk, "rad/s²/√Hz", True),
        ("accelerometer white noise", allan.acc_white, cal.acc_noise_density, "m/s²/√Hz", False),
        ("accelerometer bias random walk", allan.acc_rw, cal.acc_random_walk, "m/s³/√Hz", True),
    ):
        rows.append([label, *[allan_cell(x, allan.static, is_rw) for x in fits], fmt(yaml_v, 4),
                     _allan_ratio(fits, yaml_v, allan.static, is_rw), unit])
    parts.append(table(["parameter", "x", "y", "z", "calibration", "fit / calibration", "unit"], rows, numeric_from=1,
                       text_cols=[6]))
    if allan.static:
        parts.append(p("“not visible”: the curve does not rise significantly above the white-noise line within a "
                       "tenth of the longest segment, so the bias random walk cannot be read off this recording "
                       "(the rest periods are too short or the sensor too quiet).", class_="small"))
    else:
        parts.append(p("“≤”: with motion in the data only an upper bound of the white noise can be read (motion adds "
                       "to the curve everywhere); the bias random walk cannot be separated from the motion.",
                       class_="small"))
    return section("allan", TITLE["allan"], join(parts))
