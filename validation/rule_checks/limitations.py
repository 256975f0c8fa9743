"""The verdict's rules on what limits a bias, read from the evidence beside the integration errors
(the input's findings, the recovery, the plausibility checks, the windows kept); registered in
:mod:`validation.rules`. A check takes the :class:`validation.rules.Evidence` and returns one text per
time its rule fires.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from pipeline.types import Severity

if TYPE_CHECKING:
    from validation.rules import Evidence

__all__ = ["dropped", "extrinsic_differs", "extrinsic_unobservable", "flagged", "given_fails", "given_limitations",
           "implausible", "input_finding", "no_baseline", "not_independent", "random_walk_at_edge", "random_walk_far",
           "sigma_not_confirmed"]


def given_fails(ev: Evidence) -> list[str]:
    return list(ev.given_fails)


def given_limitations(ev: Evidence) -> list[str]:
    return list(ev.given_limitations)


def implausible(ev: Evidence, check: str) -> list[str]:
    return [x.text for x in ev.inputs.implausible if x.check == check]


def input_finding(ev: Evidence, code: str) -> list[str]:
    return [f"input: {f.message}" for f in ev.inputs.findings if f.code == code and f.severity is Severity.WARNING]


def _random_walks(ev: Evidence) -> list[tuple[str, bool, float, list]]:
    """``(axis, at_edge, scale, grid)`` of each finite random-walk scale of the recovery."""
    report = ev.inputs.recovery or {}
    noise = report.get("noise") if isinstance(report.get("noise"), Mapping) else {}
    grid = (report.get("config") or {}).get("random_walk_scales") or []
    out = []
    for axis in ("gyro", "acc"):
        scale = noise.get(f"{axis}_random_walk_scale")
        if isinstance(scale, (int, float)) and math.isfinite(scale):
            out.append((axis, bool(noise.get("method") == "evidence" and grid and scale >= max(grid)), scale, grid))
    return out


def random_walk_at_edge(ev: Evidence) -> list[str]:
    # Only the upper edge limits the bias: a walk that wants to be looser than the search allows means
    # the bias absorbs other errors. At the lower edge (a nearly constant bias, e.g. the semi-real
    # sequences' EuRoC bias) the recovered bias is only a little less smooth than it could be, and its
    # sigma errs on the safe side.
    return [f"the {axis} bias random walk was chosen at the upper edge of its search ({scale:g}x the "
            f"calibration; searched {min(grid):g}x-{max(grid):g}x): the bias may absorb other errors"
            for axis, edge, scale, grid in _random_walks(ev) if edge]


def random_walk_far(ev: Evidence) -> list[str]:
    k = ev.config.max_random_walk_scale
    return [f"the {axis} bias random walk is {scale:.3g}x the calibration's: the bias likely absorbs unmodelled "
            "errors (scale, misalignment, pose artefacts) or the datasheet is off"
            for axis, edge, scale, _ in _random_walks(ev) if not edge and not 1.0 / k <= scale <= k]


def extrinsic_differs(ev: Evidence) -> list[str]:
    diff = ((ev.inputs.recovery or {}).get("extrinsic") or {}).get("difference_from_calibration") or {}
    if not diff.get("exceeds"):
        return []
    return [f"the extrinsic T_imu_pose estimated from the data differs from the calibration's by "
            f"{diff['rotation_deg']:.2f} deg and {100 * diff['translation_m']:.1f} cm, beyond "
            f"{diff['max_sigmas']:g} of its sigmas: the calibration file is off (or the tracked body moved); the "
            "bias is the one consistent with the estimate"]


def extrinsic_unobservable(ev: Evidence) -> list[str]:
    if (ev.inputs.recovery or {}).get("extrinsic_rotation_observable") is not False:
        return []
    return ["the rotation between the pose frame and the IMU was not observable (too little rotation): the "
            "calibration's or the identity was used, and the bias absorbs any error in it"]


def not_independent(ev: Evidence) -> list[str]:
    if not ev.inputs.not_independent:
        return []
    return ["not an independent test: the reference poses are those the recovery fitted, so pose errors that the "
            "bias absorbed are not seen" + (" (and no cross-validation fold could be recovered)"
                                            if ev.inputs.crossval_ran else "")]


def sigma_not_confirmed(ev: Evidence) -> list[str]:
    check = ev.inputs.sigma_check
    if not check or not check.get("unconfirmed"):
        return []
    from validation.crossval.sigma import AXES

    factors = ", ".join(f"{a} x{f:.1f}" for a, f in zip(AXES, check["factor"]) if a in check["unconfirmed"])
    return [f"the sigma is not confirmed held out: over {check['blocks']} blocks the held-out bias differs from the "
            f"in-sample bias beyond the chi-square bound ({check['bound']:.1f}) on {', '.join(check['unconfirmed'])}; "
            f"widening the sigma by {factors} covers it"]


def flagged(ev: Evidence) -> list[str]:
    cand, limit = ev.cand, ev.config.warn_flagged_fraction
    if not cand.windows or not float(np.mean(cand.flagged)) > limit:
        return []
    frac = float(np.mean(cand.flagged))
    return [f"{int(cand.flagged.sum())} of {cand.windows} windows ({frac:.1%}) of '{ev.candidate}' are flagged as "
            f"outliers (more than {limit:.0%})"]


def dropped(ev: Evidence) -> list[str]:
    limit = ev.config.warn_dropped_fraction
    if not ev.dropped_fraction > limit:
        return []
    return [f"{ev.dropped_fraction:.1%} of the windows were dropped (more than {limit:.0%}): the validation covers "
            "only part of the sequence"]


def no_baseline(ev: Evidence) -> list[str]:
    return [] if ev.baselines else [f"no baseline (constant or dataset bias) to compare '{ev.candidate}' with"]
