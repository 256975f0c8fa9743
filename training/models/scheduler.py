"""The diffusion noise schedule and its samplers (DDPM, DDIM, and the released code's sampler).

Notation (Ho et al. 2020, "DDPM"; Song et al. 2021, "DDIM"): ``beta_t`` the forward-process
variances (linear from ``beta_start`` to ``beta_end`` over ``N`` steps), ``alpha_t = 1 - beta_t``,
``alpha_bar_t = prod_{s<=t} alpha_s`` (``alphas_cumprod``); ``t_prev = t - N // S`` for ``S``
sampling steps, with ``alpha_bar_{t_prev} = 1`` below 0; ``alpha'_t = alpha_bar_t / alpha_bar_prev``,
``beta'_t = 1 - alpha'_t``.

1. Forward process (DDPM eq. 4): ``x_t = sqrt(alpha_bar_t) x_0 + sqrt(1 - alpha_bar_t) eps``.
2. Timesteps (``set_timesteps(S)``, "leading" as diffusers): ``t_i = i * (N // S)``, from
   ``(S - 1) * (N // S)`` down to 0.
3. x0 estimate (DDPM eq. 15, DDIM eq. 9): ``x0_hat = (x_t - sqrt(1 - alpha_bar_t) eps) / sqrt(alpha_bar_t)``.
4. Clip (diffusers' ``clip_sample``): ``x0_hat`` clamped to ``[-c, c]`` or per-channel ``[lo, hi]``
   (in sigmas of the train split; :class:`training.config.ClipRange`); ``eps`` is not re-derived,
   the last step returns the clipped ``x0_hat`` and :class:`ClipCount` counts how often it binds.
5. DDPM step (eqs. 6-7, "fixed small" variance): ``mu = sqrt(alpha_bar_prev) beta'_t / (1 -
   alpha_bar_t) x0_hat + sqrt(alpha'_t) (1 - alpha_bar_prev) / (1 - alpha_bar_t) x_t``,
   ``sigma^2 = (1 - alpha_bar_prev) / (1 - alpha_bar_t) beta'_t``; no noise at t = 0.
6. DDIM step (eq. 12 with eq. 16's sigma): ``sigma = eta sqrt((1 - alpha_bar_prev) / (1 -
   alpha_bar_t)) sqrt(1 - alpha'_t)``, ``x_prev = sqrt(alpha_bar_prev) x0_hat + sqrt(1 -
   alpha_bar_prev - sigma^2) eps + sigma z``; deterministic for eta = 0.
7. RELEASED (ShenghaoZhou/ioo_diffusion ``scheduler/ddim.py``): steps ``t = S-1 .. 0`` with
   ``alpha_bar_prev = 1``, so every step returns the x0 estimate clipped to [-1, 1]. Ablation only.

Every formula is checked against diffusers' ``DDPMScheduler`` / ``DDIMScheduler`` in the tests.
Why the clip matters for z-scored biases: ``docs/internals.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from training.config import STEPS, Sampler

__all__ = ["ClipCount", "NoiseScheduler", "WindowNoise", "randn"]

#: A clip of the x0 estimate: ``c`` for ``[-c, c]``, per-channel ``(lo, hi)`` (broadcast over the last axis), or None.
Clip = float | tuple[torch.Tensor, torch.Tensor] | None


@dataclass
class ClipCount:
    """How often the clip bound over :meth:`NoiseScheduler.sample` calls, per channel (the last axis).

    Attributes:
        values: Sample values counted per channel.
        on_bound: Values whose last step clipped the x0 estimate (the returned sample is on a bound), [C].
        any_step: Values clipped at one step or more, [C].
    """

    values: int = 0
    on_bound: torch.Tensor | None = None
    any_step: torch.Tensor | None = None

    def add(self, last: torch.Tensor, any_step: torch.Tensor) -> None:
        """Count the boolean masks [..., C] of one sampling run."""
        C = last.shape[-1]
        self.values += last.numel() // C
        last, any_step = last.reshape(-1, C).sum(0).cpu(), any_step.reshape(-1, C).sum(0).cpu()
        self.on_bound = last if self.on_bound is None else self.on_bound + last
        self.any_step = any_step if self.any_step is None else self.any_step + any_step

    def fractions(self) -> tuple[list[float], list[float]]:
        """``(on_bound, any_step)`` as fractions of the counted values per channel."""
        if not self.values or self.on_bound is None:
            return [], []
        return ((self.on_bound.double() / self.values).tolist(), (self.any_step.double() / self.values).tolist())


class WindowNoise:
    """Noise drawn per window: of every draw of ``B * K`` rows (window ``b``'s ``K`` samples in rows
    ``b*K .. b*K+K-1``, as :meth:`training.models.bias_model.BiasModel.sample` orders them), window
    ``b``'s rows come from its own generator. So a window's samples do not depend on which windows share
    its model call, nor on how the windows are chunked.

    Args:
        generators: One CPU generator per window, in batch order.
    """

    def __init__(self, generators: Sequence[torch.Generator]) -> None:
        self.generators = list(generators)

    @classmethod
    def seeded(cls, seed: int, keys: Sequence[int]) -> WindowNoise:
        """One generator per window, seeded from ``seed`` and the window's key (its first stamp, ns)."""
        return cls([torch.Generator().manual_seed(int(seed) * 1_000_003 + int(k) % 1_000_003) for k in keys])

    def __len__(self) -> int:
        return len(self.generators)

    def subset(self, start: int, stop: int) -> WindowNoise:
        """The generators of windows ``start .. stop-1`` (the same objects: their draws continue)."""
        return WindowNoise(self.generators[start:stop])

    def randn(self, shape: tuple[int, ...], device: torch.device | str, dtype: torch.dtype) -> torch.Tensor:
        """Standard normal noise of ``shape`` [B*K, ...], window ``b``'s rows from generator ``b``.

        Raises:
            ValueError: ``shape[0]`` is not a multiple of the windows.
        """
        B = len(self.generators)
        if B == 0 or shape[0] % B:
            raise ValueError(f"{shape[0]} rows do not split over {B} windows")
        rows = (shape[0] // B, *shape[1:])
        return torch.cat([torch.randn(rows, generator=g, dtype=dtype) for g in self.generators]).to(device)


def randn(shape: tuple[int, ...], generator: torch.Generator | WindowNoise | None, device: torch.device | str,
          dtype: torch.dtype) -> torch.Tensor:
    """Standard normal noise drawn on the generator's device and moved to ``device`` (so a CPU
    generator serves a CUDA model, and the same seed gives the same noise on every device);
    a :class:`WindowNoise` draws each window's rows from its own generator."""
    if isinstance(generator, WindowNoise):
        return generator.randn(shape, device, dtype)
    where = generator.device if generator is not None else device
    return torch.randn(shape, generator=generator, device=where, dtype=dtype).to(device)


class NoiseScheduler:
    """Linear-beta diffusion schedule with ``add_noise``, ``set_timesteps`` and the three steps.

    The schedule is computed in float32 as in diffusers and the released code (``linspace`` then
    ``cumprod``), so the steps agree with theirs to float32 rounding, and is cast to the sample's
    dtype and device at use.

    Args:
        train_timesteps: ``N``, steps of the forward process.
        beta_start: ``beta_0``.
        beta_end: ``beta_{N-1}``.
    """

    def __init__(self, train_timesteps: int = 1000, beta_start: float = 1e-4, beta_end: float = 0.02) -> None:
        self.train_timesteps = int(train_timesteps)
        self.betas = torch.linspace(beta_start, beta_end, self.train_timesteps, dtype=torch.float32)
        self.alphas = 1.0 - self.betas
        self.alphas_cumprod = torch.cumprod(self.alphas, dim=0)
        self.num_inference_steps = 0
        self.sampler = Sampler.DDIM
        self.timesteps = torch.arange(self.train_timesteps - 1, -1, -1)

    def _alpha_bar(self, t: torch.Tensor | int, like: torch.Tensor) -> torch.Tensor:
        """``alpha_bar_t`` as a tensor of ``like``'s dtype/device (1 where t < 0), shaped [B, 1, 1]
        for a [B] ``t`` or a scalar for an int."""
        t = torch.as_tensor(t).cpu()
        ab = torch.where(t >= 0, self.alphas_cumprod[t.clamp_min(0)], torch.ones((), dtype=torch.float32))
        ab = ab.to(device=like.device, dtype=like.dtype)
        return ab.reshape(-1, *([1] * (like.dim() - 1))) if ab.dim() else ab

    def add_noise(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Forward process (DDPM eq. 4): ``x_t`` from ``x_0`` [B, ...], ``noise`` like it, ``t`` [B]."""
        ab = self._alpha_bar(t, x0)
        return ab.sqrt() * x0 + (1.0 - ab).sqrt() * noise

    def set_timesteps(self, steps: int, sampler: Sampler = Sampler.DDIM) -> torch.Tensor:
        """Choose the ``steps`` timesteps a sampler visits, descending; returns them ([steps])."""
        sampler = Sampler(sampler)
        if not 1 <= steps <= self.train_timesteps:
            raise ValueError(f"steps must be in 1..{self.train_timesteps}, got {steps}")
        self.num_inference_steps = int(steps)
        self.sampler = sampler
        ratio = 1 if sampler is Sampler.RELEASED else self.train_timesteps // steps  # the released bug: S // S
        self.timesteps = torch.arange(steps - 1, -1, -1, dtype=torch.int64) * ratio
        return self.timesteps

    def _prev(self, t: int) -> int:
        return int(t) - self.train_timesteps // self.num_inference_steps

    def predict_x0(self, eps: torch.Tensor, t: int, x_t: torch.Tensor) -> torch.Tensor:
        """``x0_hat`` from the noise estimate (DDPM eq. 15 / DDIM eq. 9)."""
        ab = self._alpha_bar(int(t), x_t)
        return (x_t - (1.0 - ab).sqrt() * eps) / ab.sqrt()

    def ddpm_step(self, eps: torch.Tensor, t: int, x_t: torch.Tensor,
                  generator: torch.Generator | WindowNoise | None = None,
                  clip_x0: Clip = None, clipped: torch.Tensor | None = None) -> torch.Tensor:
        """One ancestral step ``x_t -> x_{t_prev}`` (DDPM eqs. 6-7, fixed-small variance;
        ``clip_x0``: clamp ``x0_hat`` to ``[-clip_x0, clip_x0]`` or ``(lo, hi)``, diffusers'
        ``clip_sample``; ``clipped``: a boolean tensor like ``x_t`` set to where it clamped)."""
        ab_t = self._alpha_bar(int(t), x_t)
        ab_prev = self._alpha_bar(self._prev(t), x_t)
        alpha_t = ab_t / ab_prev  # alpha'_t, the step's alpha when steps are skipped
        beta_t = 1.0 - alpha_t
        x0 = _clamp(self.predict_x0(eps, t, x_t), clip_x0, clipped)
        mean = (ab_prev.sqrt() * beta_t / (1.0 - ab_t)) * x0 + (alpha_t.sqrt() * (1.0 - ab_prev) / (1.0 - ab_t)) * x_t
        if int(t) <= 0:
            return mean
        var = ((1.0 - ab_prev) / (1.0 - ab_t) * beta_t).clamp_min(1e-20)
        return mean + var.sqrt() * randn(x_t.shape, generator, x_t.device, x_t.dtype)

    def ddim_step(self, eps: torch.Tensor, t: int, x_t: torch.Tensor, eta: float = 0.0,
                  generator: torch.Generator | WindowNoise | None = None, clip_x0: Clip = None,
                  clipped: torch.Tensor | None = None) -> torch.Tensor:
        """One DDIM step ``x_t -> x_{t_prev}`` (DDIM eq. 12, sigma of eq. 16 scaled by ``eta``;
        ``clip_x0`` and ``clipped`` as in :meth:`ddpm_step`)."""
        ab_t = self._alpha_bar(int(t), x_t)
        ab_prev = self._alpha_bar(self._prev(t), x_t)
        x0 = _clamp(self.predict_x0(eps, t, x_t), clip_x0, clipped)
        sigma = eta * ((1.0 - ab_prev) / (1.0 - ab_t) * (1.0 - ab_t / ab_prev)).sqrt()
        x_prev = ab_prev.sqrt() * x0 + (1.0 - ab_prev - sigma**2).sqrt() * eps
        if eta > 0:
            x_prev = x_prev + sigma * randn(x_t.shape, generator, x_t.device, x_t.dtype)
        return x_prev

    def released_step(self, eps: torch.Tensor, t: int, x_t: torch.Tensor,
                      clip_lo: torch.Tensor | float = -1.0, clip_hi: torch.Tensor | float = 1.0,
                      clipped: torch.Tensor | None = None) -> torch.Tensor:
        """The released code's step: the clipped ``x0_hat`` (its ``alpha_bar_prev`` is always 1).

        ``clip_lo`` / ``clip_hi`` are the clip range in the sample's space (broadcastable);
        ``clipped`` as in :meth:`ddpm_step`.
        """
        x0 = self.predict_x0(eps, t, x_t)
        return _clamp(x0, (torch.as_tensor(clip_lo), torch.as_tensor(clip_hi)), clipped)

    def sample(
        self,
        predict_eps: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
        shape: tuple[int, ...],
        *,
        sampler: Sampler = Sampler.DDIM,
        steps: int = STEPS,
        eta: float = 0.0,
        generator: torch.Generator | WindowNoise | None = None,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        clip: tuple[torch.Tensor, torch.Tensor] | None = None,
        clip_x0: Clip = None,
        clip_count: ClipCount | None = None,
    ) -> torch.Tensor:
        """Run a sampler from ``x_T ~ N(0, I)`` of ``shape``.

        Args:
            predict_eps: ``(x_t [B, ...], t [B] int64) -> eps [B, ...]``.
            shape: Sample shape [B, ...].
            sampler: Which :class:`Sampler`.
            steps: Sampling steps S.
            eta: DDIM's eta (0: deterministic given ``x_T``).
            generator: Source of ``x_T`` and of any added noise (a :class:`WindowNoise`: per window).
            device: Device of the samples.
            dtype: Floating dtype of the samples.
            clip: ``(lo, hi)`` clip range of the RELEASED sampler (default [-1, 1]).
            clip_x0: DDIM / DDPM: clamp each step's ``x0_hat`` to ``[-clip_x0, clip_x0]`` or to
                per-channel ``(lo, hi)`` (None: off).
            clip_count: Adds how often the clip bound (RELEASED's ``clip`` or ``clip_x0``).

        Returns:
            ``x_0`` samples of ``shape``.
        """
        x = randn(shape, generator, device, dtype)
        counting = clip_count is not None
        last = torch.zeros(shape, dtype=torch.bool, device=device) if counting else None
        seen = torch.zeros(shape, dtype=torch.bool, device=device) if counting else None
        for t in self.set_timesteps(steps, sampler).tolist():
            eps = predict_eps(x, torch.full((shape[0],), t, dtype=torch.int64, device=device))
            if sampler is Sampler.DDIM:
                x = self.ddim_step(eps, t, x, eta=eta, generator=generator, clip_x0=clip_x0, clipped=last)
            elif sampler is Sampler.DDPM:
                x = self.ddpm_step(eps, t, x, generator=generator, clip_x0=clip_x0, clipped=last)
            else:
                x = self.released_step(eps, t, x, *(clip if clip is not None else (-1.0, 1.0)), clipped=last)
            if counting:
                seen |= last
        if counting:
            clip_count.add(last, seen)
        return x


def _clamp(x0: torch.Tensor, clip_x0: Clip, clipped: torch.Tensor | None = None) -> torch.Tensor:
    """``x0`` clamped to ``[-clip_x0, clip_x0]`` or ``(lo, hi)`` (unchanged for None); ``clipped``,
    when given, is set to where the clamp changed a value."""
    if clip_x0 is None:
        out = x0
    elif isinstance(clip_x0, tuple):
        lo, hi = (torch.as_tensor(b).to(dtype=x0.dtype, device=x0.device) for b in clip_x0)
        out = torch.maximum(torch.minimum(x0, hi), lo)
    else:
        out = x0.clamp(-float(clip_x0), float(clip_x0))
    if clipped is not None:
        torch.ne(out, x0, out=clipped)
    return out
