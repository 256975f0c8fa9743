"""Whether a recovered bias's sigma holds up held out, checked without the truth.

The cross-validation (:mod:`validation.crossval.blocks`) gives, in every block, a bias from a recovery that
never saw the block's poses, with that recovery's sigma. Where the in-sample sigma is honest, the held-out
and in-sample bias of a block differ by about the sigma of their difference; where the recovery's
sigma is too small (a pose error or an IMU error it does not model, absorbed into the bias), they differ
by more, and by more than chance allows over the blocks.

Per IMU stamp ``t`` with a held-out bias, per axis, the difference and its variance

    d_t = heldout_bias_t - insample_bias_t
    s_t^2 = max(heldout_std_t^2 - insample_std_t^2, MIN_VARIANCE_FRACTION * heldout_std_t^2)   (h >= i)
    s_t^2 = heldout_std_t^2 + insample_std_t^2                                              (h < i)

(the variance of the difference of an estimate and a less informed one of the same quantity is the
difference of their variances: the in-sample recovery sees the held-out one's data and more; its floor,
a fraction of the held-out variance, keeps a held-out sigma barely above the in-sample one from blowing the
statistic up). A held-out sigma below the in-sample one cannot be the same model's with less data: the
fold's own noise search chose another model (a stiffer walk), and the two errors are taken as independent;
the nested form would read the models' disagreement as the sigma's. Per block ``b``,
``z_b^2 = mean_t (d_t / s_t)^2`` (1 in expectation with honest sigmas), and per axis
``chi2 = sum_b z_b^2``. The stamps of a block are strongly correlated (the bias is smooth), blocks apart
far less: ``chi2`` is taken as chi-square with as many degrees of freedom as blocks, which is conservative
(averaging within a block only narrows its spread). An axis beyond the chi-square bound at ``alpha``
(Bonferroni over the six axes) does not confirm its sigma, and the factor that widens it to cover the blocks
is ``sqrt(chi2 / blocks)``.

The marginal sigma of a keyframe bias is not the sigma of a block's mean bias (its errors average out over
a block: on clean simulations the block means' NEES is 0.02-0.2), so block means would hide a sigma several
times too small; the per-stamp form compares like with like.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.bias_table import BiasTrack

__all__ = ["ALPHA", "MIN_BLOCK_SAMPLES", "MIN_VARIANCE_FRACTION", "SigmaCheck", "heldout_sigma_check"]

#: False-alarm probability of the check over the six axes of one recording.
ALPHA = 0.01
#: Floor of the difference's variance, as a fraction of the held-out variance.
MIN_VARIANCE_FRACTION = 0.25
#: A block counts with at least this many IMU stamps that have both biases.
MIN_BLOCK_SAMPLES = 20
AXES = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")


@dataclass(frozen=True)
class SigmaCheck:
    """The held-out test of a recovered sigma (module docstring).

    Attributes:
        blocks: Blocks compared.
        chi2: Per axis, the sum over blocks of the normalised squared differences, [6].
        bound: The chi-square quantile at ``1 - alpha / 6`` with ``blocks`` degrees of freedom.
        factor: Per axis, the factor that widens the sigma to cover the held-out differences
            (``sqrt(chi2 / blocks)`` where beyond the bound, else 1), [6].
    """

    blocks: int
    chi2: np.ndarray
    bound: float
    factor: np.ndarray

    @property
    def unconfirmed(self) -> list[str]:
        """The axes whose sigma the held-out blocks do not confirm."""
        return [a for a, c in zip(AXES, self.chi2) if c > self.bound]

    def to_dict(self) -> dict[str, Any]:
        return {"blocks": int(self.blocks), "chi2": [float(x) for x in self.chi2], "bound": float(self.bound),
                "alpha": ALPHA, "factor": [float(x) for x in self.factor], "unconfirmed": self.unconfirmed}


def heldout_sigma_check(heldout: BiasTrack, insample: BiasTrack, block_of: np.ndarray) -> SigmaCheck | None:
    """Test the in-sample sigma against the held-out blocks.

    Args:
        heldout: The cross-validated bias and sigma at the IMU stamps, [N] (NaN where a fold was dropped).
        insample: The recovery's bias and sigma at the same stamps, [N] (``clamped`` stamps are left out).
        block_of: Each stamp's block, int [N] (:meth:`validation.crossval.blocks.BlockFolds.block`).

    Returns:
        The check, or None with fewer than two blocks to compare.
    """
    from scipy.stats import chi2 as chi2_dist

    ok = np.isfinite(heldout.bias).all(1) & np.isfinite(heldout.std).all(1) & np.isfinite(insample.bias).all(1)
    if insample.clamped is not None:
        ok &= ~np.asarray(insample.clamped, dtype=bool)
    z2 = []
    for b in np.unique(block_of[ok]):
        m = ok & (block_of == b)
        if m.sum() < MIN_BLOCK_SAMPLES:
            continue
        var_h, var_i = heldout.std[m] ** 2, insample.std[m] ** 2
        var_d = np.where(var_h >= var_i, np.maximum(var_h - var_i, MIN_VARIANCE_FRACTION * var_h), var_h + var_i)
        z2.append(((heldout.bias[m] - insample.bias[m]) ** 2 / np.maximum(var_d, 1e-300)).mean(0))
    if len(z2) < 2:
        return None
    chi2 = np.sum(z2, axis=0)
    n = len(z2)
    bound = float(chi2_dist.ppf(1.0 - ALPHA / len(AXES), n))
    factor = np.where(chi2 > bound, np.sqrt(chi2 / n), 1.0)
    return SigmaCheck(n, chi2, bound, np.maximum(factor, 1.0))
