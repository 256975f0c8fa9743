"""Bias models: one ``BiasModel`` wrapper around the network of a registered method (:mod:`training.networks`).

Every model reads the IMU window (and optionally the IMU temperature), normalised with the
train-split statistics held by its :class:`training.data.normalizer.Normalizer` submodule, and predicts
the bias at IMU rate in raw units (rad/s, m/s^2).

* Diffusion (objective ``diffusion``): DDPM with epsilon prediction and an MSE
  loss. biasgt diffuses the **normalised** bias (zero mean, unit std per channel over the train
  split), so one noise schedule suits gyro and accelerometer alike; the released code diffuses
  the bias in raw units. Its RELEASED sampler's [-1, 1] clip is applied in raw units, as there.
* Regression (objective ``regression``): MSE on the normalised bias.
* Indirect (objective ``indirect``): AirIMU-style. The regressor's output is a bias correction; it is
  subtracted from the readings, which :func:`pipeline.geometry.integration.integrate` integrates from the
  reference start state; the loss compares the end state with the reference end state
  (rotation error ``||Log(R_gt^T R)||^2`` in rad^2, velocity and position errors squared), so no
  bias label is read.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from pipeline.errors import DataError
from pipeline.geometry.integration import integrate
from pipeline.geometry.so3_torch import so3_log
from training.data.batch import WindowBatch
from training.config import IMU_CHANNELS, STEPS, ModelConfig, Sampler
from training.data.normalizer import Normalizer
from pipeline.types import DEFAULT_GRAVITY_MPS2
from training.models.scheduler import ClipCount, NoiseScheduler, WindowNoise, randn

__all__ = ["BiasModel", "build_model", "count_parameters", "integration_errors", "DEFAULT_GRAVITY_MPS2"]

#: Gravity used by the indirect loss when a batch carries none: pipeline.types.DEFAULT_GRAVITY_MPS2.


class BiasModel(nn.Module):
    """A bias predictor with its normaliser (see the module docstring).

    The network's objective (:class:`training.networks.Objective`) chooses the one loss and the one
    prediction. A network may declare, as attributes:

    * ``label_weight`` and ``integration_weights`` (rotation, velocity, position): the weights of the
      label term (diffusion: the noise loss) and of the integration term (diffusion: of its x0
      estimate, each window weighted by ``min(SNR_t, 1)``); by default the objective's: the label term
      alone (diffusion, regression) or the integration alone with the training's ``indirect_weights``;
    * ``per_window``: a diffusion network that draws one bias [6] per window, held over it;
    * ``base(context) -> [B, 6]``: a diffusion network's normalised base (it draws the residual).

    Args:
        config: Sizes and method.
        normalizer: Train-split statistics (a submodule: saved in the ``state_dict``).
        indirect_weights: Weights of the rotation, velocity and position terms (an indirect method).
    """

    def __init__(self, config: ModelConfig, normalizer: Normalizer,
                 indirect_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> None:
        super().__init__()
        self.config = config
        self.method = config.method
        self.spec = config.spec
        self.normalizer = normalizer
        self.indirect_weights = tuple(float(w) for w in indirect_weights)
        self.use_temperature = config.condition_channels > IMU_CHANNELS
        self.net = self.spec.build(config)
        self.scheduler = NoiseScheduler(config.train_timesteps, config.beta_start, config.beta_end)
        self.per_window = bool(getattr(self.net, "per_window", False))
        indirect = self.spec.is_indirect
        self.label_weight = float(getattr(self.net, "label_weight", 0.0 if indirect else 1.0))
        weights = getattr(self.net, "integration_weights", self.indirect_weights if indirect else None)
        self.integration_weights = tuple(float(w) for w in weights) if weights is not None and any(weights) else None

    def _condition(self, batch: WindowBatch) -> torch.Tensor:
        """Normalised condition [B, T, 6 or 7]."""
        return self.normalizer.condition(batch.condition(self.use_temperature))

    def _context(self, batch: WindowBatch, like: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``(context [B, F'],)`` for a network that reads it (:attr:`training.networks.Network.context`), else ``()``."""
        if not self.spec.context:
            return ()
        if batch.context is None:
            raise DataError(f"{self.method} reads each window's context from its sequence's record, and the batch "
                            "carries none", hint="train and evaluate it on a window dataset with records "
                            "(context/, written by 'biasgt windows'), with 'biasgt train' / 'biasgt evaluate'")
        return (batch.context.to(like),)

    def _base(self, batch: WindowBatch, like: torch.Tensor) -> torch.Tensor | None:
        """A diffusion network's normalised base [B, 6] (None: it draws the bias itself)."""
        return self.net.base(*self._context(batch, like)) if hasattr(self.net, "base") else None

    def state_shape(self, samples: int) -> tuple[int, ...]:
        """Shape of one window's diffused state: [T, 6], or [6] for a ``per_window`` network."""
        return (IMU_CHANNELS,) if self.per_window else (samples, IMU_CHANNELS)

    def draw_noise(self, shape: tuple[int, ...], generator: torch.Generator | None = None,
                   device: torch.device | str = "cpu") -> tuple[torch.Tensor, torch.Tensor]:
        """Diffusion noise of ``shape`` ([B, *state_shape]) and steps [B] (noise drawn first)."""
        noise = randn(shape, generator, device, torch.float32)
        dev = generator.device if generator is not None else device
        t = torch.randint(0, self.scheduler.train_timesteps, (shape[0],), generator=generator, device=dev).to(device)
        return noise, t

    def loss(self, batch: WindowBatch, generator: torch.Generator | None = None, *,
             noise: torch.Tensor | None = None, t: torch.Tensor | None = None) -> torch.Tensor:
        """Training loss of one batch (scalar).

        Args:
            batch: The windows.
            generator: Draws the diffusion noise and steps (:meth:`draw_noise`) unless given.
            noise: Diffusion noise [B, *state_shape] (data-parallel training draws it for the global batch).
            t: Diffusion steps [B].
        """
        cond = self._condition(batch)
        if self.spec.is_diffusion:
            return self._diffusion_loss(cond, batch, generator, noise, t)
        pred = self.net(cond, *self._context(batch, cond))
        terms = []
        if self.label_weight:
            mse = F.mse_loss(pred, self.normalizer.bias(batch.bias))
            terms.append(mse if self.label_weight == 1.0 else self.label_weight * mse)
        if self.integration_weights is not None:
            terms.append(self._integration_loss(batch, self.normalizer.unbias(pred), self.integration_weights))
        return terms[0] if len(terms) == 1 else terms[0] + terms[1]

    def _diffusion_loss(self, cond: torch.Tensor, batch: WindowBatch, generator: torch.Generator | None,
                        noise: torch.Tensor | None, t: torch.Tensor | None) -> torch.Tensor:
        """The noise MSE of the normalised bias (a ``per_window`` network's window mean, less its base),
        plus, with integration weights, the integration of its x0 estimate weighted by ``min(SNR_t, 1)``."""
        x0 = self.normalizer.bias(batch.bias)
        if self.per_window:
            x0 = x0.mean(1)
        base = self._base(batch, x0)
        if base is not None:
            x0 = x0 - base
        if noise is None or t is None:
            noise, t = self.draw_noise(tuple(x0.shape), generator, x0.device)
        noise, t = noise.to(x0), t.to(x0.device)
        x_t = self.scheduler.add_noise(x0, noise, t)
        eps = self.net.denoise(x_t, t, self.net.encode(cond, *self._context(batch, cond)))
        mse = F.mse_loss(eps, noise)
        if self.integration_weights is None:
            return mse if self.label_weight == 1.0 else self.label_weight * mse
        ab = self.scheduler.alphas_cumprod[t].to(x0).reshape(-1, *(1,) * (x0.dim() - 1))
        x0_hat = (x_t - (1.0 - ab).sqrt() * eps) / ab.sqrt()
        snr_weights = (ab / (1.0 - ab)).clamp(max=1.0).reshape(len(x0), -1)[:, 0]  # x0's error counts as eps's
        bias = x0_hat if base is None else x0_hat + base
        if self.per_window:
            bias = bias[:, None].expand(-1, cond.shape[1], -1)
        integration = self._integration_loss(batch, self.normalizer.unbias(bias), self.integration_weights, snr_weights)
        return self.label_weight * mse + integration

    def _integration_loss(self, batch: WindowBatch, bias: torch.Tensor, weights: tuple[float, float, float] | None = None,
                          window_weights: torch.Tensor | None = None) -> torch.Tensor:
        """End-state error of the windows integrated (float64) with ``bias`` [B, T, 6] removed:
        ``sum_i w_i (weights . (rot_i, vel_i, pos_i)) / B`` (``weights``: the model's integration weights
        by default; ``window_weights`` w [B], default 1).

        Windows are integrated in groups of equal gravity (``batch.gravity_mps2`` [B, 3], else
        :data:`DEFAULT_GRAVITY_MPS2`), since the integrator takes one gravity vector per call.
        """
        f64 = torch.float64
        gravity = batch.gravity_mps2
        if gravity is None:
            gravity = torch.tensor(DEFAULT_GRAVITY_MPS2, dtype=f64).expand(len(batch), 3)
        gravity = gravity.to(device=batch.imu.device, dtype=f64)
        values, group = torch.unique(gravity, dim=0, return_inverse=True)
        terms = torch.zeros(3, dtype=f64, device=batch.imu.device)
        for g in range(len(values)):
            i = (group == g).nonzero().squeeze(1)
            rot, vel, pos = integration_errors(batch.imu[i], bias[i], batch.dt_s[i], batch.start_R[i],
                                               batch.start_v[i], batch.start_p[i], batch.end_R[i], batch.end_v[i],
                                               batch.end_p[i], values[g])
            if window_weights is not None:
                w = window_weights[i].to(f64)
                rot, vel, pos = w * rot, w * vel, w * pos
            terms = terms + torch.stack([rot.sum(), vel.sum(), pos.sum()])
        weights = weights if weights is not None else self.integration_weights or self.indirect_weights
        weights_t = torch.tensor(weights, dtype=f64, device=terms.device)
        return ((weights_t * terms).sum() / len(batch)).to(batch.imu.dtype)

    def forward(self, batch: WindowBatch, generator: torch.Generator | None = None, *,
                noise: torch.Tensor | None = None, t: torch.Tensor | None = None) -> torch.Tensor:
        """The training loss (so that DistributedDataParallel's hooks wrap it)."""
        return self.loss(batch, generator, noise=noise, t=t)

    def x0_clip(self) -> float | tuple[torch.Tensor, torch.Tensor] | None:
        """The DDIM / DDPM clip of the x0 estimate in the normalised space: per-channel ``(lo, hi)``
        from ``config.clip_x0_bounds`` (raw units), else ``clip_x0_sigmas`` (None: no clipping)."""
        c = self.config
        if c.clip_x0_sigmas is None:
            return None
        if c.clip_x0_bounds is None:
            return float(c.clip_x0_sigmas)
        nz = self.normalizer
        lo, hi = (nz.bias(torch.tensor(b, dtype=torch.float64).to(nz.bias_mean)) for b in c.clip_x0_bounds)
        return lo, hi

    def released_clip(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The RELEASED sampler's clip, ``[-clip_sample, clip_sample]`` in raw units, normalised."""
        nz = self.normalizer
        return ((-self.config.clip_sample - nz.bias_mean) / nz.bias_std,
                (self.config.clip_sample - nz.bias_mean) / nz.bias_std)

    @torch.inference_mode()
    def sample(self, batch: WindowBatch, num_samples: int = 1, *, sampler: Sampler = Sampler.DDIM,
               steps: int = STEPS, generator: torch.Generator | WindowNoise | None = None, eta: float = 0.0,
               clip_count: ClipCount | None = None,
               denoise: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor] | None = None
               ) -> torch.Tensor:
        """Predicted bias [B, K, T, 6] in raw units (rad/s, m/s^2): the one prediction of every network.

        Regression and indirect models return K identical copies. Only ``batch.imu`` (the temperature,
        a context network's ``batch.context``) is read. ``generator`` (on the model's device, or a
        :class:`training.models.scheduler.WindowNoise` of the B windows) draws the initial noise.
        ``clip_count`` adds how often the sampler's clip bound
        (:class:`training.models.scheduler.ClipCount`). A network with a base draws its residual: the
        clips apply to the bias, so they are moved by the base. ``denoise`` replaces the network's
        ``denoise(x_t, t, code)`` (a sampling backend's, :mod:`training.models.backends`).
        """
        cond = self._condition(batch)
        B, T, _ = cond.shape
        K = int(num_samples)
        context = self._context(batch, cond)
        if not self.spec.is_diffusion:
            return self.normalizer.unbias(self.net(cond, *context))[:, None].expand(B, K, T, IMU_CHANNELS).clone()
        code = self.net.encode(cond, *context).repeat_interleave(K, dim=0)  # [B*K, C], window b's samples adjacent
        clip, clip_x0 = self.released_clip(), self.x0_clip()
        base = self._base(batch, cond)
        if base is not None:
            base = base.repeat_interleave(K, dim=0)
            clip = (clip[0] - base, clip[1] - base)
            clip_x0 = None if clip_x0 is None else (
                (-clip_x0 - base, clip_x0 - base) if isinstance(clip_x0, float) else (clip_x0[0] - base, clip_x0[1] - base))
        denoise = self.net.denoise if denoise is None else denoise
        z = self.scheduler.sample(lambda x, t: denoise(x, t, code), (B * K, *self.state_shape(T)),
                                  sampler=Sampler(sampler), steps=steps, eta=eta, generator=generator,
                                  device=cond.device, dtype=cond.dtype, clip=clip, clip_x0=clip_x0,
                                  clip_count=clip_count)
        if base is not None:
            z = z + base
        if self.per_window:
            z = z[:, None].expand(-1, T, -1)
        return self.normalizer.unbias(z).reshape(B, K, T, IMU_CHANNELS)


def integration_errors(imu: torch.Tensor, bias: torch.Tensor, dt_s: torch.Tensor, start_R: torch.Tensor,
                       start_v: torch.Tensor, start_p: torch.Tensor, end_R: torch.Tensor, end_v: torch.Tensor,
                       end_p: torch.Tensor, gravity_mps2: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Squared end errors [B] of windows integrated (float64, differentiable,
    :func:`pipeline.geometry.integration.integrate`) from their reference start with ``imu - bias``
    (``bias`` [B, T, 6], or [B, 6] held over the window) under one gravity [3]: rotation ``|Log(R_gt^T R)|^2``
    (rad^2), velocity (m^2/s^2) and position (m^2)."""
    f64 = torch.float64
    imu, b = imu.to(f64), bias.to(f64)
    if b.dim() == 2:
        b = b[:, None].expand_as(imu)
    res = integrate(imu[..., :3], imu[..., 3:], dt_s.to(f64), start_R.to(f64), start_v.to(f64), start_p.to(f64),
                    gravity_mps2=gravity_mps2.to(f64), bias_gyro_radps=b[..., :3], bias_acc_mps2=b[..., 3:])
    rot = so3_log(end_R.to(f64).transpose(-1, -2) @ res.R).square().sum(-1)
    vel = (res.v - end_v.to(f64)).square().sum(-1)
    pos = (res.p - end_p.to(f64)).square().sum(-1)
    return rot, vel, pos


def build_model(config: ModelConfig, normalizer: Normalizer,
                indirect_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> BiasModel:
    """A freshly initialised :class:`BiasModel` (seed torch before calling for reproducibility)."""
    return BiasModel(config, normalizer, indirect_weights)


def count_parameters(model: nn.Module) -> int:
    """Trainable parameters of ``model``."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
