"""Sections 3 and 4 of the quality report: what the recovery estimated, and the bias.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.errors import BiasgtError
from recovery.intrinsics.gyro_consistency import rate_coupling
from reports import plots
from validation.plausibility import gravity_tilt_deg
from recovery.noise.allan import ImuAllan
from reports.html import Html, code_words, esc, figure_img, fmt, fmt_unc, join, p, section, table, tag
from reports.quality_inputs import TITLE, ReportInputs, missing_box, num, rel_s
from reports.quality_residuals import allan_cell, calibration_origin
from reports.quality_verdict import implausible_frame

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- section 3: calibration


def _rotation_text(quat_wxyz: list[float]) -> tuple[str, str, np.ndarray]:
    rot = Rotation.from_quat(np.asarray(quat_wxyz, dtype=float), scalar_first=True)
    rv = rot.as_rotvec()
    ang = float(np.degrees(np.linalg.norm(rv)))
    axis = rv / np.linalg.norm(rv) if ang > 1e-9 else np.array([0.0, 0.0, 1.0])
    rpy = rot.as_euler("xyz", degrees=True)
    aa = f"{ang:.3f} deg about axis [{axis[0]:.3f}, {axis[1]:.3f}, {axis[2]:.3f}]"
    return aa, f"roll {rpy[0]:.3f}, pitch {rpy[1]:.3f}, yaw {rpy[2]:.3f} deg", rot.as_matrix()


def _vec(v: Any, digits: int = 4, scale: float = 1.0) -> str:
    try:
        arr = np.asarray(v, dtype=float).reshape(-1) * scale
    except (TypeError, ValueError):
        return "n/a"
    return "[" + ", ".join(fmt(x, digits) for x in arr) + "]"


def _vec_to(v: Any, std: Any, scale: float = 1.0) -> str:
    """A vector rounded to the two significant digits of its smallest sigma (4 significant digits without
    sigmas), so a value never shows more digits than its uncertainty."""
    try:
        sig = np.abs(np.asarray(std, dtype=float).reshape(-1)) * scale
        arr = np.asarray(v, dtype=float).reshape(-1) * scale
    except (TypeError, ValueError):
        return _vec(v, 4, scale)
    sig = sig[np.isfinite(sig) & (sig > 0)]
    if not len(sig) or not np.isfinite(arr).all():
        return _vec(v, 4, scale)
    decimals = max(0, 1 - math.floor(math.log10(float(sig.min()))))
    return "[" + ", ".join(f"{x:.{decimals}f}" for x in arr) + "]"


def calibration_section(inp: ReportInputs, allan: ImuAllan | None) -> Html:
    rec = inp.recovery.data if inp.recovery is not None else None  # the JSON object: display fields
    cal = inp.sequence.calibration
    if rec is None:
        return section("calibration", TITLE["calibration"],
                       missing_box("Not available: the recovery output (recovery.json) is missing. The sensor's "
                                    "datasheet noise values are shown in section 7."))
    rows = _estimate_rows(rec)
    parts = [
        p(f"What the recovery estimated for pose stream '{rec.get('pose_stream', 'n/a')}' "
          f"({rec.get('pose_source_kind', 'n/a')}, pose factors: {rec.get('pose_factor_mode', 'n/a')}). "
          "Uncertainties are 1σ where the recovery gives them."),
        implausible_frame(inp, "gravity_tilt", table(["quantity", "value", "uncertainty (1σ)", "notes"], rows,
                                                     numeric_from=99)),
    ]
    ext = rec.get("extrinsic") if isinstance(rec.get("extrinsic"), dict) else {}
    diff = ext.get("difference_from_calibration")
    if isinstance(diff, dict):
        parts.append(tag("div", _difference_text(diff),
                         class_="warnbox" if diff.get("exceeds") else "small"))
    if rec.get("extrinsic_rotation_observable") is False:
        parts.append(tag("div", "The motion did not excite rotation enough to observe the extrinsic rotation: "
                                "the calibration's (or identity) rotation was used.", class_="warnbox"))
    noise = rec.get("noise") if isinstance(rec.get("noise"), dict) else {}
    nrows = _noise_rows(rec, noise, cal, allan)
    parts.append(tag("h3", "Noise strengths: used by the recovery vs. the calibration"))
    parts.append(table(["parameter", "used", "calibration", "used / calibration", "Allan fit (section 7)", "unit",
                        "calibration from"], nrows, numeric_from=1, text_cols=[5, 6]))
    extra = _noise_notes(noise)
    if extra:
        parts.append(p("; ".join(extra) + ".", class_="small"))
    fusion = rec.get("pose_fusion") if isinstance(rec.get("pose_fusion"), dict) else {}
    if fusion.get("enabled") and num(fusion, "samples_per_keyframe_mean") is not None:
        parts.append(p(
            f"Pose fusion: {fmt(num(fusion, 'samples_per_keyframe_mean'), 3)} pose samples per "
            f"{fmt(num(fusion, 'keyframe_rate_hz'), 3)}-Hz keyframe, moved to it through the IMU and fused; "
            f"{int(num(fusion, 'samples_rejected') or 0)} samples rejected as outliers; scatter about the "
            f"keyframes {fmt(num(fusion, 'within_bin_position_rms_m'), 3)} m / "
            f"{fmt(num(fusion, 'within_bin_rotation_rms_rad'), 3)} rad RMS.", class_="small"))
    floor = rec.get("accuracy_floor") if isinstance(rec.get("accuracy_floor"), dict) else {}
    if num(floor, "acc_mps2") is not None:
        gyro_txt = (f"gyro {fmt(num(floor, 'gyro_radps'), 3)} rad/s, " if num(floor, "gyro_radps") is not None
                    else "")
        parts.append(p(
            f"Accuracy floor for this noise (optimal smoother, per axis): {gyro_txt}accelerometer "
            f"{fmt(num(floor, 'acc_mps2'), 3)} m/s²: no recovery of this recording is more accurate; the bias "
            "sigmas of section 4 sit somewhat above it.", class_="small"))
    return section("calibration", TITLE["calibration"], join(parts))


def _estimate_rows(rec: dict) -> list[list[Any]]:
    """Table rows of the recovery's estimates: clock offset, extrinsic translation and rotation, gravity."""
    rows = []
    off = num(rec, "pose_time_offset_s")
    off_std = num(rec, "pose_time_offset_std_s")
    fixed = off_std == 0.0
    value = fmt_unc(None if off is None else 1e3 * off, None if off_std is None else 1e3 * off_std, "ms")
    rows.append(["Clock offset of the pose stream",
                 value.split(" ± ")[0] + (" ms" if " ± " in value else ""),
                 "none: set, not estimated" if fixed else fmt(None if off_std is None else 1e3 * off_std, 2, "ms"),
                 f"add it to the pose stamps to put them on the IMU clock; method: "
                 f"{code_words(str(rec.get('pose_time_offset_method', 'n/a')))}"])
    T = rec.get("T_imu_pose") if isinstance(rec.get("T_imu_pose"), dict) else {}
    ext = rec.get("extrinsic") if isinstance(rec.get("extrinsic"), dict) else {}
    how = f"source: {ext.get('source', 'n/a')}" + (f", mode: {ext['mode']}" if "mode" in ext else "")
    frame = rec.get("pose_frame") or "pose"
    rows.append([f"Extrinsic translation (pose frame '{frame}' in the IMU frame)",
                 _vec_to(T.get("p_m"), ext.get("translation_std_m"), 1e3) + " mm",
                 _vec(ext.get("translation_std_m"), 2, 1e3) + " mm" if ext.get("translation_std_m") else "n/a", how])
    if T.get("quat_wxyz") is not None:
        try:
            aa, rpy, _ = _rotation_text(T["quat_wxyz"])
        except (ValueError, TypeError):
            aa, rpy = "n/a", "n/a"
        rows.append(["Extrinsic rotation", Html(esc(aa) + tag("br") + esc(rpy)),
                     _vec(ext.get("rotation_std_deg"), 2) + " deg" if ext.get("rotation_std_deg") else "n/a",
                     "roll/pitch/yaw about the fixed x, y, z axes; std per rotation-vector axis"])
    g = rec.get("gravity_world_mps2")
    if g is not None:
        gi = rec.get("gravity") if isinstance(rec.get("gravity"), dict) else {}
        tilt_std = num(gi, "tilt_std_rad")
        rows.append(["Gravity in the world frame", _vec(g, 5) + f" m/s² (|g| = {fmt(np.linalg.norm(g), 5)})",
                     "n/a", "estimated" if gi.get("estimated") else "as configured"])
        rows.append(["Tilt of gravity from the world −z axis", f"{gravity_tilt_deg(g):.3f} deg",
                     "n/a" if tilt_std is None else f"{math.degrees(tilt_std):.3f} deg",
                     "0 means the pose world frame is z-up"])
        lt = gi.get("level_test") if isinstance(gi.get("level_test"), dict) else {}
        measured, measured_std = num(lt, "tilt_deg"), num(lt, "tilt_std_deg")
        if lt.get("level") and measured is not None:
            rows.append(["Tilt the data measured (frame kept level)", f"{measured:.3f} deg",
                         "n/a" if measured_std is None else f"{measured_std:.3f} deg",
                         f"{lt.get('reason', '')}; the bias is the one consistent with the nominal gravity"])
    return rows


def _noise_rows(rec: dict, noise: dict, cal: Any, allan: ImuAllan | None) -> list[list[Any]]:
    """Table rows of the noise strengths: used by the recovery, the calibration's, their ratio, the Allan fit."""
    nrows = []
    for key, label, unit, al in (
        ("gyro_noise_density", "gyro white noise", "rad/s/√Hz", None if allan is None else allan.gyro_white),
        ("gyro_random_walk", "gyro bias random walk", "rad/s²/√Hz", None if allan is None else allan.gyro_rw),
        ("acc_noise_density", "accelerometer white noise", "m/s²/√Hz", None if allan is None else allan.acc_white),
        ("acc_random_walk", "accelerometer bias random walk", "m/s³/√Hz", None if allan is None else allan.acc_rw),
    ):
        used = num(noise, key)
        if used is None:
            used = num(rec, key)
        yaml_v = float(getattr(cal, key))
        ratio = "n/a" if used is None or yaml_v == 0 else f"{used / yaml_v:.3g}×"
        if al is None:
            al_v = "n/a"
        elif not np.isfinite(al).any():
            al_v = "not visible" if allan is not None and allan.static else "n/a"
        else:
            al_v = allan_cell(float(np.nanmean(al)), allan is not None and allan.static, "random_walk" in key)
        nrows.append([label, fmt(used, 4), fmt(yaml_v, 4), ratio, al_v, unit, calibration_origin(cal, key)])
    return nrows


def _noise_notes(noise: dict) -> list[str]:
    """The other noise values the recovery chose (pose sigmas, scales, correlated pose error) and how."""
    extra = []
    for key, label in (("position_sigma_m", "pose position sigma [m]"), ("rotation_sigma_rad", "pose rotation "
                       "sigma [rad]")):
        if num(noise, key) is not None:
            extra.append(f"{label}: {fmt(num(noise, key), 3)}")
    for key, label in (("gyro_random_walk_scale", "gyro random walk"), ("acc_random_walk_scale", "acc random walk"),
                       ("gyro_density_scale", "gyro white noise"), ("acc_density_scale", "acc white noise")):
        if num(noise, key) is not None:
            extra.append(f"{label}: {scale_words(num(noise, key))}")
    pose_error = noise.get("pose_error")
    if isinstance(pose_error, dict):
        extra.append("correlated pose error (Gauss-Markov): "
                     f"{fmt(num(pose_error, 'rotation_sigma_rad'), 3)} rad over {fmt(num(pose_error, 'rotation_tau_s'), 3)} s, "
                     f"{fmt(num(pose_error, 'position_sigma_m'), 3)} m over {fmt(num(pose_error, 'position_tau_s'), 3)} s")
    if noise.get("method"):
        extra.append(f"chosen by: {code_words(str(noise['method']))}")
    if noise.get("pose_sigma_method"):
        extra.append(f"pose sigmas from: {str(noise['pose_sigma_method']).replace('_', ' ')}")
    return extra


#: A noise scale within [1/x, x] of the calibration's reads "as calibrated".
AS_CALIBRATED = 3.0


def calibration_word(scale: float) -> str:
    """A noise scale against the calibration's in words: larger than / smaller than / as calibrated."""
    return ("larger than calibrated" if scale > AS_CALIBRATED else "smaller than calibrated"
            if scale < 1.0 / AS_CALIBRATED else "as calibrated")


def scale_words(scale: float) -> str:
    """A noise scale against the calibration's in words: ``10.2× the calibration's (larger than calibrated)``."""
    return f"{fmt(scale, 3)}× the calibration's ({calibration_word(scale)})"


def _difference_text(diff: dict) -> str:
    """One sentence: the estimated extrinsic against the calibration file's, in its sigmas."""
    def part(value: float | None, sigmas: float | None, unit: str, scale: float) -> str:
        if value is None:
            return "n/a"
        z = f" ({sigmas:.1f} σ)" if sigmas is not None and math.isfinite(sigmas) else ""
        return f"{value * scale:.2f} {unit}{z}"

    rot = part(num(diff, "rotation_deg"), num(diff, "rotation_sigmas"), "deg", 1.0)
    trans = part(num(diff, "translation_m"), num(diff, "translation_sigmas"), "cm", 100.0)
    verdict = (f"beyond {fmt(num(diff, 'max_sigmas'), 2)} σ: the calibration file is off (or the tracked body "
               "was moved); the estimate was used" if diff.get("exceeds") else "within the calibration's prior")
    return f"Estimated extrinsic against the calibration file's: {rot} in rotation, {trans} in translation; {verdict}."


# ----------------------------------------------------------------------------- section 4: bias


def bias_section(inp: ReportInputs) -> Html:
    if inp.bias is None:
        return section("bias", TITLE["bias"], missing_box(
            "Not available: the recovery's bias.csv is missing or could not be read (see the notes in section 1)."))
    b = inp.bias
    t_s = rel_s(b.t_ns, inp.t0_ns)
    gt = inp.sequence.ground_truth
    gt_t = None if gt is None else rel_s(gt.t_ns, inp.t0_ns)
    std = np.asarray(b.std, dtype=float)
    parts = [p(f"{len(b.t_ns):,} keyframes over {fmt(t_s[-1] - t_s[0], 5)} s. The shaded band is ± 3 marginal "
               "standard deviations of the recovery" + (
                   "; the dashed black line is the dataset's own bias estimate." if gt is not None else
                   "; the dataset has no bias of its own to compare with."))]
    # milli-units: bias values need no matplotlib offset ("1e-3") on the axis
    parts.append(figure_img(plots.bias_figure(t_s, 1e3 * b.bias[:, :3], 1e3 * std[:, :3], quantity="Gyroscope bias",
                                              unit="mrad/s", dataset_t_s=gt_t,
                                              dataset_bias=None if gt is None else 1e3 * gt.bias_gyro_radps),
                            "gyroscope bias over time", "Gyroscope bias (x, y, z) with ± 3σ."))
    parts.append(figure_img(plots.bias_figure(t_s, 1e3 * b.bias[:, 3:], 1e3 * std[:, 3:],
                                              quantity="Accelerometer bias", unit="10⁻³ m/s²", dataset_t_s=gt_t,
                                              dataset_bias=None if gt is None else 1e3 * gt.bias_acc_mps2),
                            "accelerometer bias over time", "Accelerometer bias (x, y, z) with ± 3σ."))
    rows = []
    names = ["gyro x", "gyro y", "gyro z", "acc x", "acc y", "acc z"]
    gt_b = None if gt is None else np.hstack([gt.bias_gyro_radps, gt.bias_acc_mps2])
    for c in range(6):  # in the units of the bias plots above: mrad/s and 10^-3 m/s^2
        v = 1e3 * b.bias[:, c]
        row = [names[c], fmt(v.mean(), 4), fmt(v.min(), 4), fmt(v.max(), 4),
               fmt(1e3 * np.nanmean(std[:, c]) if np.isfinite(std[:, c]).any() else None, 3)]
        if gt_b is not None:
            ref = 1e3 * np.interp(b.t_ns.astype(float), gt.t_ns.astype(float), gt_b[:, c])
            inside = (b.t_ns >= gt.t_ns[0]) & (b.t_ns <= gt.t_ns[-1])
            row.append(fmt(np.sqrt(np.mean((v[inside] - ref[inside]) ** 2)) if inside.any() else None, 3))
        row.append("mrad/s" if c < 3 else "10⁻³ m/s²")
        rows.append(row)
    headers = ["axis", "mean", "min", "max", "mean σ"] + (["RMS diff. to dataset"] if gt_b is not None else [])
    parts.append(implausible_frame(inp, "bias_range", table(headers + ["unit"], rows, numeric_from=1,
                                                            text_cols=[len(headers)])))
    note = _calibration_uncertainty_note(inp.recovery.data if inp.recovery is not None else None)
    if note is not None:
        parts.append(note)
    note = implausible_frame(inp, "frame_swap", gyro_consistency_note(inp))
    if note is not None:
        parts.append(note)
    return section("bias", TITLE["bias"], join(parts))


def gyro_consistency_note(inp: ReportInputs) -> Html | None:
    """Whether the gyro reads a share of the rate against the fitted pose stream: the sentence the
    recovery's ``intrinsics: auto`` decided on, else :func:`recovery.intrinsics.gyro_consistency.rate_coupling`
    on the recovered offset and extrinsic; None without a 6-DoF pose stream long enough for it."""
    rec, seq = inp.recovery, inp.sequence
    poses = seq.poses.get(rec.pose_stream) if rec is not None and rec.pose_stream else None
    if poses is None or poses.quat_wxyz is None or seq.imu is None:
        return None
    auto = rec.data.get("intrinsics_auto")
    if isinstance(auto, Mapping) and auto.get("coupling") is not None:
        sentence = str(auto.get("reason"))
    else:
        try:
            sentence = rate_coupling(seq.imu, poses, R_imu_pose=rec.T_imu_pose[:3, :3],
                                     offset_s=rec.time_offset_s).sentence()
        except BiasgtError:
            return None
    return p("Gyro against the pose stream's rotation, by frequency band: " + sentence + " "
             + intrinsics_sentence(rec.data), class_="small")


def intrinsics_sentence(rec: Mapping[str, Any]) -> str:
    """What the recovery did about the IMU intrinsics (recovery.json ``intrinsics``, ``intrinsics_auto``)."""
    est = rec.get("intrinsics")
    if isinstance(est, Mapping) and "gyro_matrix" in est:
        terms = {"gyro": np.asarray(est["gyro_matrix"], float) - np.eye(3),
                 "accelerometer": np.asarray(est["acc_matrix"], float) - np.eye(3)}
        largest = "; ".join(f"{name} largest scale/misalignment {m.flat[np.argmax(np.abs(m))]:+.4f}"
                            for name, m in terms.items())
        return (f"The recovery estimated the intrinsics ({est.get('rounds')} rounds; {largest}) and its bias is "
                "free of them.")
    auto = rec.get("intrinsics_auto")
    if isinstance(auto, Mapping) and not auto.get("estimated"):
        return "The recovery estimated no intrinsics (intrinsics: auto)."
    return "The recovery estimated no intrinsics (intrinsics: off)."


def _calibration_uncertainty_note(rec: dict[str, Any] | None) -> Html | None:
    """Whether the σ include the estimated calibration's uncertainty (recovery.json ``calibration_uncertainty``)."""
    cu = rec.get("calibration_uncertainty") if isinstance(rec, dict) else None
    if not isinstance(cu, dict):
        return None
    params = ", ".join(str(x).replace("_", " ") for x in cu.get("parameters") or [])
    if not cu.get("included_in_bias_std"):
        return p("The σ treat the calibration as exact" + (f" ({params} estimated: not propagated for this pose "
                                                           "stream)." if params else " (all of it given)."),
                 class_="small")
    mean, peak = cu.get("std_inflation_mean") or [], cu.get("std_inflation_max") or []
    growth = ", ".join(f"{(m - 1) * 100:.1f} % ({(x - 1) * 100:.0f} % max)" for m, x in zip(mean, peak))
    return p(f"The σ include the uncertainty of the estimated {params} (first-order propagation); it grew them per "
             f"axis (gyro x, y, z, acc x, y, z) by {growth}.", class_="small")
