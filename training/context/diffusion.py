"""The context residual drawn by a conditional diffusion model instead of regressed.

Same inputs and base as :class:`training.context.model.ContextNet` (the window, the causal context
vector, a constant base); what is learned is the distribution of the window's residual
``r = bias_n - base_n`` [6] (normalised bias units, one per window, held over it). The model
(:class:`training.models.bias_model.BiasModel`) diffuses, trains and samples it as every diffusion
network, with one state [6] per window (``per_window``) and the base this network gives (``base``).

Notation (:mod:`training.models.scheduler`): ``x_0 = r``, ``x_t`` the noised residual at step ``t``,
``alpha_bar_t`` the schedule's cumulative product, ``c`` the condition ``[code, mean(x), features]``
(:meth:`training.context.model.WindowEncoder.summary`).

1. Forward process (DDPM eq. 4): ``x_t = sqrt(alpha_bar_t) r + sqrt(1 - alpha_bar_t) eps``.
2. Noise predictor: ``eps_hat = mlp(x_t, step_embedding(t), c)``.
3. Loss (DDPM eq. 14): ``|eps - eps_hat|^2``; with loss ``both`` also the 1-s integration error of
   the bias from ``x0_hat`` (DDIM eq. 9), weighted per window by ``min(SNR_t, 1)``, ``SNR_t =
   alpha_bar_t / (1 - alpha_bar_t)`` (min-SNR weighting, Hang et al. 2023): ``x0_hat``'s error is
   ``eps``'s divided by ``sqrt(SNR_t)``, so a noisy step weighs as its noise error.
4. Sampling: the model's sampler from ``x_T ~ N(0, I)``; ``bias_n = base_n + x_0``.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from training.context.model import ContextInput, WindowEncoder
from training.models.layers import StepEncoder

__all__ = ["ContextDiffusionNet"]


class ContextDiffusionNet(ContextInput):
    """The noise predictor of the window's residual (module docstring).

    Args:
        config: A :class:`training.config.ModelConfig` whose options are
            :class:`training.networks.ContextDiffusionOptions`.
    """

    per_window = True

    def __init__(self, config: Any) -> None:
        super().__init__(config)
        o = config.network
        c_in = config.condition_channels
        self.encoder = WindowEncoder(c_in, o.channels)
        self.step_encoder = StepEncoder(o.step_dim, nn.GELU)
        h = o.hidden
        self.denoiser = nn.Sequential(nn.Linear(6 + o.step_dim + o.channels + c_in + self.features, h), nn.GELU(),
                                      nn.Linear(h, h), nn.GELU(), nn.Linear(h, 6))

    def encode(self, condition: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        """The condition ``c`` [B, D] of the normalised window [B, T, C_in] and its context [B, F + 6]."""
        return self.encoder.summary(condition, context[:, :self.features])

    def denoise(self, x_t: torch.Tensor, t: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        """Step 2: the noise estimate [B, 6] of ``x_t`` [B, 6] at steps ``t`` [B] under ``code`` [B, D]."""
        return self.denoiser(torch.cat([x_t, self.step_encoder(t), code], dim=-1))
