"""What ``recovery.json`` says of the IMU intrinsics: the terms estimated, those the bias absorbed, one sentence.

Pure functions of arrays and of ``recovery.json``'s data (no solve), so that the quality report can
say what actually ran (:func:`intrinsics_sentence`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

#: Names of the nine terms of a 3x3 matrix in row-major order (``S[r, c]``).
TERMS = tuple(f"{'xyz'[r]}{'xyz'[c]}" for r in range(3) for c in range(3))
#: A group's readable name in sentences.
GROUP_WORDS = {"gyro_scale_misalignment": "gyro scale/misalignment", "acc_scale_misalignment":
               "accelerometer scale/misalignment", "gyro_g_sensitivity": "gyro g-sensitivity"}


def term_table(values: dict[str, np.ndarray], sigma: dict[str, np.ndarray], observable: dict[str, np.ndarray],
               in_model: dict[str, np.ndarray], left: dict[str, np.ndarray], dropped: list[str],
               groups: tuple[str, ...]) -> dict[str, list[dict[str, Any]]]:
    """The ``estimated`` and ``absorbed_by_bias`` lists of ``recovery.json``'s ``intrinsics``.

    Args:
        values: Per group, the 3x3 total terms (``M - I``, ``G``; raw readings' convention).
        sigma / observable: The last fit's, per group 3x3.
        in_model: Per group 3x3 booleans: the terms the readings were corrected for.
        left: Per group 3x3: what the final readings still carry of each term left out (the fit's estimate).
        dropped: ``group[term]`` names dropped after the last round.
        groups: The groups fitted.

    Returns:
        ``{"estimated": [{term, value, sigma}], "absorbed_by_bias": [{term, estimate, sigma, why}]}``;
        a term is named ``group[rc]`` (row r, column c).
    """
    estimated, absorbed = [], []
    for group in groups:
        used = np.asarray(in_model.get(group, np.zeros((3, 3), bool)), bool).ravel()
        for i, name in enumerate(TERMS):
            term = f"{group}[{name}]"
            s = float(np.asarray(sigma[group], float).ravel()[i])
            s_json = s if np.isfinite(s) else None
            if used[i]:
                estimated.append({"term": term, "value": float(np.asarray(values[group]).ravel()[i]), "sigma": s_json})
                continue
            if not bool(np.asarray(observable[group]).ravel()[i]):
                why = "not observable from this motion"
            elif term in dropped:
                why = "dropped after the last round (within 3 sigma of zero)"
            else:
                why = "not significant (within 3 sigma of zero)"
            absorbed.append({"term": term, "estimate": float(np.asarray(left[group]).ravel()[i]), "sigma": s_json,
                             "why": why})
    return {"estimated": estimated, "absorbed_by_bias": absorbed}


def intrinsics_report(total, last, rounds: int) -> dict:
    """The ``intrinsics`` entry of ``recovery.json`` (``total``: :class:`recovery.intrinsics.estimate.ImuIntrinsics`,
    ``last``: the last :class:`recovery.intrinsics.estimate.IntrinsicsFit`)."""
    return {
        "method": "alternating: least-squares fit on the solved trajectory, full solve on corrected readings",
        "rounds": rounds,
        "gyro_matrix": total.gyro_matrix.tolist(),
        "acc_matrix": total.acc_matrix.tolist(),
        "gyro_g_sensitivity": total.gyro_g_sensitivity.tolist(),
        "sigma": {k: np.where(np.isfinite(v), v, None).tolist() for k, v in last.sigma.items()},
        "observable": {k: v.tolist() for k, v in last.observable.items()},
        "residual_rms": last.residual_rms,
        "terms": "row-major 3x3, rows/columns x, y, z",
    }


def unobservable_warning(fit) -> str | None:
    """A warning naming the terms too weak to correct the readings for (the bias keeps them, within their
    posterior under the datasheet prior)."""
    missing = [f"{group}[{TERMS[i]}]" for group in fit.estimated
               for i in np.flatnonzero(~fit.observable[group].ravel())]
    if not missing:
        return None
    return ("IMU intrinsics not observable from this motion, left in the readings (the bias sigma holds them, "
            "within the datasheet prior): " + ", ".join(missing[:12])
            + (", ..." if len(missing) > 12 else "") + "; record rotations about and accelerations along every axis")


def _names(entries: list[Mapping[str, Any]], limit: int = 6) -> str:
    names = [str(e.get("term")) for e in entries]
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def intrinsics_clause(recovery: Mapping[str, Any] | None) -> str:
    """The quality report's "Not checked" clause on the IMU intrinsics, from what the recovery ran.

    Args:
        recovery: ``recovery.json``'s data (None: not given).
    """
    words = "IMU scale, misalignment and g-sensitivity"
    if recovery is None:
        return f"{words} (no recovery.json: whether they were estimated is unknown; if not, the bias absorbs them)"
    entry = recovery.get("intrinsics") if isinstance(recovery.get("intrinsics"), Mapping) else None
    auto = recovery.get("intrinsics_auto") if isinstance(recovery.get("intrinsics_auto"), Mapping) else None
    if entry is None:
        if auto is not None and not auto.get("estimated", False):
            why = str(auto.get("reason") or "no intrinsic error found").rstrip(".")
            state = "not checked" if why.startswith("not checked: ") else "not estimated"
            why = why.removeprefix("not checked: ")
            return f"{words} ({state}: {why}; any the IMU has, the bias absorbs)"
        return f"{words} (not estimated: turned off; any the IMU has, the bias absorbs)"
    if entry.get("method") == "not estimated":
        return f"{words} (not estimated: {str(entry.get('reason', '')).rstrip('.')}; the bias absorbs them)"
    estimated = [e for e in entry.get("estimated") or [] if isinstance(e, Mapping)]
    absorbed = [e for e in entry.get("absorbed_by_bias") or [] if isinstance(e, Mapping)]
    per_group = {g: sum(str(e.get("term", "")).startswith(g + "[") for e in estimated) for g in GROUP_WORDS}
    counted = ", ".join(f"{n} {GROUP_WORDS[g]}" for g, n in per_group.items() if n)
    text = f"IMU intrinsics beyond the {len(estimated)} terms estimated ({counted or 'none'}; recovery.json)"
    if not absorbed:
        return text + ": none was left to the bias"
    unobservable = [e for e in absorbed if str(e.get("why", "")).startswith("not observable")]
    return (text + f": {len(absorbed)} terms could not be told from the bias ({_names(absorbed)}"
            + (f"; not observable from this motion: {_names(unobservable)}" if unobservable else "")
            + "), which absorbs them; its sigma includes them")
