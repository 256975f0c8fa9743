"""The context residual drawn by a conditional diffusion model instead of regressed.

Same inputs and base as :class:`training.context.model.ContextResidual` (the window, the causal
context vector, a constant base); what is learned is the distribution of the window's residual
``r = (bias - base) / bias_std`` [6] (normalised bias units, one per window, held over it).

Notation (:mod:`training.models.scheduler`): ``x_0 = r``, ``x_t`` the noised residual at step ``t``,
``alpha_bar_t`` the schedule's cumulative product, ``c`` the condition ``[code, mean(x), features]``
(:meth:`training.context.model.WindowEncoder.summary`).

1. Forward process (DDPM eq. 4): ``x_t = sqrt(alpha_bar_t) r + sqrt(1 - alpha_bar_t) eps``.
2. Noise predictor: ``eps_hat = mlp(x_t, step_embedding(t), c)``.
3. Loss (DDPM eq. 14): ``|eps - eps_hat|^2``; with ``both`` also the 1-s integration error of the
   bias from ``x0_hat`` (DDIM eq. 9), weighted per window by ``min(SNR_t, 1)``, ``SNR_t = alpha_bar_t
   / (1 - alpha_bar_t)`` (min-SNR weighting, Hang et al. 2023): ``x0_hat``'s error is ``eps``'s
   divided by ``sqrt(SNR_t)``, so a noisy step weighs as its noise error.
4. Sampling: DDIM (eta 0) from ``x_T ~ N(0, I)``; ``bias = base + bias_std * x_0`` [B, K, 6].
"""

from __future__ import annotations

import torch
from torch import nn

from training.config import STEPS, Sampler
from training.context.model import ContextModelConfig, NormalisedInput, Stats, WindowEncoder
from training.models.layers import StepEncoder
from training.models.scheduler import NoiseScheduler, randn

__all__ = ["ContextDiffusion"]

#: Size of the diffusion step's embedding.
STEP_DIM = 32


class ContextDiffusion(NormalisedInput):
    """``bias = base + bias_std * r``, ``r ~ p(r | window, context)`` by DDIM (module docstring).

    Args:
        config: Sizes and inputs (``config.diffusion`` is True).
        stats: Train-split statistics (stored as buffers).
    """

    stochastic = True

    def __init__(self, config: ContextModelConfig, stats: Stats) -> None:
        super().__init__(config, stats)
        self.encoder = WindowEncoder(self.c_in, config.channels)
        self.step_encoder = StepEncoder(STEP_DIM, nn.GELU)
        h = config.hidden
        self.denoiser = nn.Sequential(nn.Linear(6 + STEP_DIM + config.channels + self.c_in + config.features(), h),
                                      nn.GELU(), nn.Linear(h, h), nn.GELU(), nn.Linear(h, 6))
        self.scheduler = NoiseScheduler()

    def condition(self, imu: torch.Tensor, features: torch.Tensor,
                  temperature_degc: torch.Tensor | None = None) -> torch.Tensor:
        """The condition ``c`` [B, D] of raw ``imu`` [B, T, 6], ``features`` [B, F] (and [B, T] temperature)."""
        return self.encoder.summary(self.normalise(imu, temperature_degc), features)

    def eps(self, x_t: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """Step 2: the noise estimate [B, 6] of ``x_t`` [B, 6] at steps ``t`` [B] under ``cond`` [B, D]."""
        return self.denoiser(torch.cat([x_t, self.step_encoder(t), cond], dim=-1))

    def losses(self, cond: torch.Tensor, residual: torch.Tensor,
               generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Steps 1-3 for target residuals [B, 6]: the noise MSE (scalar), ``x0_hat`` [B, 6] and the
        integration term's weights [B] (``min(SNR_t, 1)`` of the drawn steps)."""
        B = len(residual)
        t = torch.randint(0, self.scheduler.train_timesteps, (B,), generator=generator)
        noise = randn(tuple(residual.shape), generator, residual.device, residual.dtype)
        x_t = self.scheduler.add_noise(residual, noise, t)
        eps = self.eps(x_t, t, cond)
        ab = self.scheduler.alphas_cumprod[t].to(residual)[:, None]
        x0 = (x_t - (1.0 - ab).sqrt() * eps) / ab.sqrt()
        weights = (ab / (1.0 - ab)).clamp(max=1.0)[:, 0]  # min(SNR_t, 1): the x0 error counts as the eps error
        return (eps - noise).square().mean(), x0, weights

    def unnormalise(self, base: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        """Bias (raw units) of a residual [..., 6] on a base [B, 6] (broadcast over the middle axes)."""
        shape = (len(base),) + (1,) * (residual.dim() - 2) + (6,)
        return base.reshape(shape).to(residual) + residual * self.bias_std

    @torch.no_grad()
    def sample(self, imu: torch.Tensor, features: torch.Tensor, base: torch.Tensor, num_samples: int,
               temperature_degc: torch.Tensor | None = None, generator: torch.Generator | None = None,
               steps: int = STEPS) -> torch.Tensor:
        """Step 4: ``num_samples`` biases [B, K, 6] (raw units) per window."""
        cond = self.condition(imu, features, temperature_degc).repeat_interleave(num_samples, dim=0)
        z = self.scheduler.sample(lambda x, t: self.eps(x, t, cond), (len(cond), 6), sampler=Sampler.DDIM,
                                  steps=steps, generator=generator, dtype=cond.dtype)
        return self.unnormalise(base, z.reshape(len(imu), num_samples, 6))
