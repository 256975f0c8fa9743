"""Figures of the quality report (matplotlib, Agg; no pyplot state, no display needed).

Each function returns a :class:`matplotlib.figure.Figure`; :func:`reports.html.figure_img`
embeds it as a PNG. Time axes are seconds from the first IMU sample.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

AXIS_COLORS = ("#d62728", "#2ca02c", "#1f77b4")
AXIS_NAMES = ("x", "y", "z")
SOURCE_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#17becf")
#: Longest series drawn point by point; longer ones are decimated (the curves are smooth).
MAX_PLOT_POINTS = 4000


def _stride(n: int) -> int:
    return max(1, int(np.ceil(n / MAX_PLOT_POINTS)))


def bias_figure(
    t_s: np.ndarray,
    bias: np.ndarray,
    std: np.ndarray | None,
    *,
    quantity: str,
    unit: str,
    dataset_t_s: np.ndarray | None = None,
    dataset_bias: np.ndarray | None = None,
) -> Figure:
    """Three stacked panels (x, y, z) of a recovered bias with a +-3 sigma band.

    Args:
        t_s: Keyframe times [K] (s).
        bias: Recovered bias [K, 3].
        std: Marginal 1-sigma [K, 3] or None (no band).
        quantity: ``"Gyroscope bias"`` / ``"Accelerometer bias"``.
        unit: Axis unit label.
        dataset_t_s / dataset_bias: The dataset's own bias [M] / [M, 3], overlaid when given.
    """
    fig = Figure(figsize=(10, 6.2))
    axes = fig.subplots(3, 1, sharex=True)
    k = _stride(len(t_s))
    t, b = t_s[::k], bias[::k]
    s = None if std is None else std[::k]
    for i, ax in enumerate(axes):
        if s is not None and np.isfinite(s[:, i]).any():
            ax.fill_between(t, b[:, i] - 3 * s[:, i], b[:, i] + 3 * s[:, i], color=AXIS_COLORS[i], alpha=0.18,
                            linewidth=0, label="recovered ± 3σ")
        ax.plot(t, b[:, i], color=AXIS_COLORS[i], linewidth=1.3, label="recovered")
        if dataset_bias is not None and dataset_t_s is not None:
            kd = _stride(len(dataset_t_s))
            ax.plot(dataset_t_s[::kd], dataset_bias[::kd, i], color="black", linewidth=1.0, linestyle="--",
                    label="dataset's own bias")
        ax.set_ylabel(f"{AXIS_NAMES[i]} [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.ticklabel_format(axis="y", style="plain", useOffset=False)  # the unit says the scale
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[0].set_title(quantity)
    axes[-1].set_xlabel("time since the first IMU sample [s]")
    fig.tight_layout()
    return fig


def pose_residual_figure(
    t_s: np.ndarray,
    pos_err_m: np.ndarray,
    rot_err_deg: np.ndarray | None,
    outlier_t_s: np.ndarray | None = None,
) -> Figure:
    """Distance (mm) and angle (deg) between the recovered trajectory and the pose stream, over time."""
    rows = 2 if rot_err_deg is not None else 1
    fig = Figure(figsize=(10, 2.4 * rows + 0.6))
    axes = np.atleast_1d(fig.subplots(rows, 1, sharex=True))
    k = _stride(len(t_s))
    axes[0].plot(t_s[::k], 1e3 * pos_err_m[::k], color="#1f77b4", linewidth=0.9)
    axes[0].set_ylabel("position [mm]")
    if rot_err_deg is not None:
        axes[1].plot(t_s[::k], rot_err_deg[::k], color="#9467bd", linewidth=0.9)
        axes[1].set_ylabel("rotation [deg]")
    if outlier_t_s is not None and len(outlier_t_s):
        for ax in axes:
            for x in outlier_t_s[:200]:
                ax.axvline(x, color="#c9302c", alpha=0.5, linewidth=0.8)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].set_title("Recovered trajectory vs. the pose stream (moved into the IMU frame and clock)")
    axes[-1].set_xlabel("time since the first IMU sample [s]")
    fig.tight_layout()
    return fig


#: Axis labels of the recovery's residual columns (residuals.csv); others keep their name.
RESIDUAL_LABELS = {
    "pose_whitened_rms": "pose residual\n[σ, whitened RMS]",
    "imu_whitened_rms": "IMU residual\n[σ, whitened RMS]",
}


def residual_series_figure(t_s: np.ndarray, series: Mapping[str, np.ndarray],
                           outliers: np.ndarray | None = None) -> Figure:
    """One panel per residual series (whitened pose and IMU residuals per keyframe), labelled with what it is
    and its unit; keyframes rejected as outliers (``outliers``, bool [K]) are red vertical lines across every
    panel (a rejected pose has no pose residual to mark), not a 0/1 line."""
    names = list(series)
    fig = Figure(figsize=(10, 2.2 * len(names) + 0.6))
    axes = np.atleast_1d(fig.subplots(len(names), 1, sharex=True))
    k = _stride(len(t_s))
    for ax, name, color in zip(axes, names, SOURCE_COLORS):
        values = np.asarray(series[name], dtype=float)
        ax.plot(t_s[::k], values[::k], color=color, linewidth=0.9)
        if outliers is not None and np.any(outliers):
            ax.vlines(t_s[outliers], 0, 1, transform=ax.get_xaxis_transform(), color="red", linewidth=0.8,
                      alpha=0.6, label="rejected as outlier")
        ax.set_ylabel(RESIDUAL_LABELS.get(name, name), fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0].set_title("Residuals per keyframe (from the recovery)")
    axes[-1].set_xlabel("time since the first IMU sample [s]")
    fig.tight_layout()
    return fig


def error_distribution_figure(
    sources: Sequence[str],
    pos_err_m: Sequence[np.ndarray],
    rot_err_deg: Sequence[np.ndarray],
) -> Figure:
    """Box plots (log scale) of per-window position and rotation errors, one box per bias source."""
    fig = Figure(figsize=(10, 3.8))
    ax_p, ax_r = fig.subplots(1, 2)
    labels = [s if len(s) <= 22 else s[:20] + "…" for s in sources]
    for ax, data, unit, title in ((ax_p, [1e3 * np.asarray(x) for x in pos_err_m], "mm", "position error"),
                                  (ax_r, [np.asarray(x) for x in rot_err_deg], "deg", "rotation error")):
        clean = [np.maximum(d[np.isfinite(d)], 1e-9) if len(d) else np.array([np.nan]) for d in data]
        bp = ax.boxplot(clean, whis=(5, 95), showfliers=True, patch_artist=True,
                        flierprops={"markersize": 2, "alpha": 0.4})
        for patch, color in zip(bp["boxes"], SOURCE_COLORS):
            patch.set_facecolor(color)
            patch.set_alpha(0.45)
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=20, ha="right", fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel(f"{title} after one window [{unit}]")
        ax.grid(True, axis="y", alpha=0.3, which="both")
    ax_p.set_title("Position error per window")
    ax_r.set_title("Rotation error per window")
    fig.tight_layout()
    return fig


def window_errors_over_time_figure(
    t_s: np.ndarray,
    pos_err_m: np.ndarray,
    rot_err_deg: np.ndarray,
    flagged: np.ndarray | None,
    source: str,
) -> Figure:
    """Per-window errors of one source over time, flagged windows marked."""
    fig = Figure(figsize=(10, 4.2))
    ax_p, ax_r = fig.subplots(2, 1, sharex=True)
    ax_p.plot(t_s, 1e3 * pos_err_m, ".", markersize=2.5, color="#1f77b4")
    ax_r.plot(t_s, rot_err_deg, ".", markersize=2.5, color="#9467bd")
    if flagged is not None and flagged.any():
        ax_p.plot(t_s[flagged], 1e3 * pos_err_m[flagged], "o", mfc="none", color="#c9302c", markersize=6,
                  label="flagged")
        ax_r.plot(t_s[flagged], rot_err_deg[flagged], "o", mfc="none", color="#c9302c", markersize=6)
        ax_p.legend(loc="upper right", fontsize=8)
    ax_p.set_ylabel("position [mm]")
    ax_r.set_ylabel("rotation [deg]")
    for ax in (ax_p, ax_r):
        ax.set_yscale("log")
        ax.grid(True, alpha=0.3)
    ax_p.set_title(f"Integration error of '{source}' per window, over time")
    ax_r.set_xlabel("window start, time since the first IMU sample [s]")
    fig.tight_layout()
    return fig


def allan_figure(
    taus: np.ndarray,
    adev: np.ndarray,
    *,
    title: str,
    unit: str,
    white: np.ndarray,
    random_walk: np.ndarray,
    sensor_white: float | None,
    sensor_random_walk: float | None,
    fits_are_bounds: bool = False,
    sensor_label: str = "sensor.yaml",
) -> Figure:
    """Allan deviation per axis (log-log) with the fitted -1/2 and +1/2 lines and the calibration's
    (labelled ``sensor_label``: where the values come from).

    With ``fits_are_bounds`` (a recording in motion) the white-noise line is labelled as an
    upper bound and no random-walk line is drawn.
    """
    fig = Figure(figsize=(7.2, 4.6))
    ax = fig.subplots()
    tt = np.geomspace(float(taus[0]), float(taus[-1]), 50)
    for i in range(adev.shape[1]):
        ax.loglog(taus, adev[:, i], "-", color=AXIS_COLORS[i], linewidth=1.4, label=f"{AXIS_NAMES[i]}")
    w_mean = float(np.nanmean(white)) if np.isfinite(white).any() else float("nan")
    k_mean = float(np.nanmean(random_walk)) if np.isfinite(random_walk).any() else float("nan")
    if np.isfinite(w_mean):
        ax.loglog(tt, w_mean / np.sqrt(tt), ":", color="#333333", linewidth=1.2,
                  label="white-noise upper bound (motion)" if fits_are_bounds else "fit: white noise (−½)")
        ax.plot([1.0], [w_mean], "o", color="#333333", markersize=4)
    if np.isfinite(k_mean) and not fits_are_bounds:
        ax.loglog(tt, k_mean * np.sqrt(tt / 3.0), "-.", color="#333333", linewidth=1.2,
                  label="fit: bias random walk (+½)")
        ax.plot([3.0], [k_mean], "s", color="#333333", markersize=4)
    if sensor_white:
        ax.loglog(tt, sensor_white / np.sqrt(tt), ":", color="#ff7f0e", linewidth=1.4,
                  label=f"{sensor_label} white noise")
    if sensor_random_walk:
        ax.loglog(tt, sensor_random_walk * np.sqrt(tt / 3.0), "-.", color="#ff7f0e", linewidth=1.4,
                  label=f"{sensor_label} random walk")
    lo = float(np.nanmin(adev[adev > 0])) if np.any(adev > 0) else 1e-6
    hi = float(np.nanmax(adev)) if np.isfinite(adev).any() else 1.0
    # keep sensor.yaml's lines in view (within two decades of the data)
    ends = [v for v in (sensor_white and sensor_white / np.sqrt(tt[-1]),
                        sensor_random_walk and sensor_random_walk * np.sqrt(tt[0] / 3.0)) if v]
    if ends:
        lo = max(min([lo, *ends]), lo / 100.0)
    ax.set_ylim(lo / 3.0, hi * 3.0)
    ax.set_xlabel("cluster time τ [s]")
    ax.set_ylabel(f"Allan deviation [{unit}]")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7.5, loc="best")
    fig.tight_layout()
    return fig
