"""The dataset page's figure: every sequence's recovered bias, one identifiable trace per sequence.

Each sequence has its own colour and a legend entry ``name · split · verdict``; the line style says
the verdict (PASS solid, WARN dashed, FAIL dotted, not validated dash-dot). One sequence whose bias
is far larger than the others' on a channel (:func:`channel_outliers`) does not set that panel's
scale: the panel is scaled to the others, the outlier's trace is clipped at the panel's edge and
named in the panel ("clipped: ...") and in the caption. Two layouts of the same figure: ``wide``
(3 x 2 panels, for a screen) and ``narrow`` (6 x 1, for a phone); the page shows the one that fits
(an HTML ``<picture>``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from pipeline.types import NS_PER_S, Verdict
from reports.dataset_inputs import SequenceRow

__all__ = ["CHANNELS", "OUTLIER_FACTOR", "VERDICT_STYLES", "bias_overview_figure", "channel_outliers",
           "trace_label"]

CHANNELS = ("gyro x", "gyro y", "gyro z", "acc x", "acc y", "acc z")
UNITS = ("rad/s",) * 3 + ("m/s²",) * 3
#: A sequence is an outlier on a channel when its peak |bias| is more than this many times the median
#: peak of the other sequences (needs two other sequences).
OUTLIER_FACTOR = 5.0
#: Line style per verdict (None: not validated).
VERDICT_STYLES = {Verdict.PASS: "-", Verdict.WARN: "--", Verdict.FAIL: ":", None: "-."}


def trace_label(row: SequenceRow) -> str:
    """The legend entry of a sequence: ``name · split · verdict``."""
    verdict = row.verdict.value if row.verdict is not None else "not validated"
    split = row.split if row.split and row.split != "none" else "no split"
    return f"{row.name} · {split}{' (left out)' if row.left_out else ''} · {verdict}"


def _drawn(rows: Sequence[SequenceRow]) -> list[SequenceRow]:
    return [r for r in rows if r.bias is not None and len(r.bias.t_ns)]


def channel_outliers(rows: Sequence[SequenceRow]) -> dict[int, list[tuple[str, float]]]:
    """Channel index -> ``[(sequence, peak |bias|)]`` of the sequences that would set its scale alone.

    A sequence is an outlier on channel ``c`` when its peak |bias| exceeds :data:`OUTLIER_FACTOR` times
    the median peak of the other drawn sequences (at least two others; none otherwise).
    """
    drawn = _drawn(rows)
    if len(drawn) < 3:
        return {}
    peaks = np.array([[float(np.nanmax(np.abs(r.bias.bias[:, c]))) for c in range(6)] for r in drawn])
    out: dict[int, list[tuple[str, float]]] = {}
    for c in range(6):
        for i, r in enumerate(drawn):
            others = np.delete(peaks[:, c], i)
            if peaks[i, c] > OUTLIER_FACTOR * max(float(np.median(others)), 1e-12):
                out.setdefault(c, []).append((r.name, float(peaks[i, c])))
    return out


def _colors(n: int) -> list[tuple[float, ...]]:
    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def bias_overview_figure(rows: Sequence[SequenceRow], layout: str = "wide") -> Figure | None:
    """Six panels (gyro x/y/z, acc x/y/z) with every sequence's recovered bias against the seconds from its
    first keyframe, one colour and legend entry per sequence (:func:`trace_label`), line style by verdict,
    outliers clipped and named (:func:`channel_outliers`). ``layout``: ``wide`` (3 x 2) or ``narrow``
    (6 x 1). None when no sequence has a bias."""
    drawn = _drawn(rows)
    if not drawn:
        return None
    narrow = layout == "narrow"
    legend_rows = len(drawn) if narrow else -(-len(drawn) // 2)
    legend_in = 0.2 * legend_rows + 0.35
    fig = Figure(figsize=(4.2, 12.5 + legend_in) if narrow else (11, 6.8 + legend_in))
    axes = fig.subplots(6, 1, sharex=True).ravel() if narrow else fig.subplots(3, 2, sharex=True).T.ravel()
    outliers = channel_outliers(drawn)
    handles = []
    for r, color in zip(drawn, _colors(len(drawn))):
        t_s = (r.bias.t_ns - r.bias.t_ns[0]) / NS_PER_S
        k = max(1, len(t_s) // 2000)
        for c, ax in enumerate(axes):
            (line,) = ax.plot(t_s[::k], r.bias.bias[::k, c], color=color, linewidth=1.1, alpha=0.9,
                              linestyle=VERDICT_STYLES.get(r.verdict, "-"))
        handles.append(line)
    for c, ax in enumerate(axes):
        clipped = dict(outliers.get(c, []))
        if clipped:
            kept = np.concatenate([r.bias.bias[:, c] for r in drawn if r.name not in clipped])
            lo, hi = float(np.nanmin(kept)), float(np.nanmax(kept))
            pad = 0.1 * max(hi - lo, 1e-9)
            ax.set_ylim(lo - pad, hi + pad)
            ax.text(0.01, 0.97, "clipped: " + ", ".join(f"{n} (peak {v:.3g})" for n, v in clipped.items()),
                    transform=ax.transAxes, va="top", fontsize=7, color="#a4231f",
                    bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "#a4231f", "linewidth": 0.6})
        ax.set_ylabel(f"{CHANNELS[c]} [{UNITS[c]}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
    for ax in ((axes[5],) if narrow else (axes[2], axes[5])):
        ax.set_xlabel("time since the recording's first keyframe [s]", fontsize=8)
    fig.legend(handles, [trace_label(r) for r in drawn], loc="lower center", ncol=1 if narrow else 2,
               fontsize=8, title="sequence · split · verdict (line: PASS solid, WARN dashed, FAIL dotted)",
               title_fontsize=8)
    height = fig.get_size_inches()[1]
    fig.tight_layout(rect=(0, (legend_in + 0.1) / height, 1, 1))
    return fig
