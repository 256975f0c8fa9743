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
from training.models.scheduler import ClipCount, NoiseScheduler, randn

__all__ = ["BiasModel", "build_model", "count_parameters", "DEFAULT_GRAVITY_MPS2"]

#: Gravity used by the indirect loss when a batch carries none: pipeline.types.DEFAULT_GRAVITY_MPS2.


class BiasModel(nn.Module):
    """A bias predictor with its normaliser (see the module docstring).

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

    def _condition(self, batch: WindowBatch) -> torch.Tensor:
        """Normalised condition [B, T, 6 or 7]."""
        return self.normalizer.condition(batch.condition(self.use_temperature))

    def _net(self, cond: torch.Tensor, batch: WindowBatch) -> torch.Tensor:
        """A regression / indirect network's normalised bias [B, T, 6] (a context network also reads
        ``batch.context``)."""
        if not self.spec.context:
            return self.net(cond)
        if batch.context is None:
            raise DataError(f"{self.method} reads each window's context from its sequence's record, and the batch "
                            "carries none", hint="train and evaluate it on a window dataset with records "
                            "(context/, written by 'biasgt windows'), with 'biasgt train' / 'biasgt evaluate'")
        return self.net(cond, batch.context.to(cond))

    def draw_noise(self, shape: tuple[int, ...], generator: torch.Generator | None = None,
                   device: torch.device | str = "cpu") -> tuple[torch.Tensor, torch.Tensor]:
        """Diffusion noise [B, T, 6] and steps [B] for a batch of ``shape`` (noise drawn first)."""
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
            noise: Diffusion noise [B, T, 6] (data-parallel training draws it for the global batch).
            t: Diffusion steps [B].
        """
        cond = self._condition(batch)
        if self.spec.is_diffusion:
            x0 = self.normalizer.bias(batch.bias)
            if noise is None or t is None:
                noise, t = self.draw_noise(tuple(x0.shape), generator, x0.device)
            noise, t = noise.to(x0), t.to(x0.device)
            eps = self.net.denoise(self.scheduler.add_noise(x0, noise, t), t, self.net.encode(cond))
            return F.mse_loss(eps, noise)
        pred = self._net(cond, batch)
        if self.spec.is_indirect:
            return self._integration_loss(batch, self.normalizer.unbias(pred))
        return F.mse_loss(pred, self.normalizer.bias(batch.bias))

    def _integration_loss(self, batch: WindowBatch, bias: torch.Tensor) -> torch.Tensor:
        """End-state error of the windows integrated (float64) with ``bias`` [B, T, 6] removed.

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
            imu, b = batch.imu[i].to(f64), bias[i].to(f64)
            res = integrate(imu[..., :3], imu[..., 3:], batch.dt_s[i].to(f64), batch.start_R[i].to(f64),
                            batch.start_v[i].to(f64), batch.start_p[i].to(f64), gravity_mps2=values[g],
                            bias_gyro_radps=b[..., :3], bias_acc_mps2=b[..., 3:])
            rot = so3_log(batch.end_R[i].to(f64).transpose(-1, -2) @ res.R).square().sum(-1)
            vel = (res.v - batch.end_v[i].to(f64)).square().sum(-1)
            pos = (res.p - batch.end_p[i].to(f64)).square().sum(-1)
            terms = terms + torch.stack([rot.sum(), vel.sum(), pos.sum()])
        weights = torch.tensor(getattr(self.net, "integration_weights", self.indirect_weights), dtype=f64,
                               device=terms.device)
        return ((weights * terms).sum() / len(batch)).to(batch.imu.dtype)

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

    @torch.no_grad()
    def sample(self, batch: WindowBatch, num_samples: int = 1, *, sampler: Sampler = Sampler.DDIM,
               steps: int = STEPS, generator: torch.Generator | None = None, eta: float = 0.0,
               clip_count: ClipCount | None = None) -> torch.Tensor:
        """Predicted bias [B, K, T, 6] in raw units (rad/s, m/s^2).

        Regression and indirect models return K identical copies. Only ``batch.imu`` (and the
        temperature) are read. ``generator`` (on the model's device) draws the initial noise.
        ``clip_count`` adds how often the sampler's clip bound (:class:`training.models.scheduler.ClipCount`).
        """
        cond = self._condition(batch)
        B, T, _ = cond.shape
        K = int(num_samples)
        if not self.spec.is_diffusion:
            return self.normalizer.unbias(self._net(cond, batch))[:, None].expand(B, K, T, IMU_CHANNELS).clone()
        code = self.net.encode(cond).repeat_interleave(K, dim=0)  # [B*K, C], window b's samples adjacent
        z = self.scheduler.sample(lambda x, t: self.net.denoise(x, t, code), (B * K, T, IMU_CHANNELS),
                                  sampler=Sampler(sampler), steps=steps, eta=eta, generator=generator,
                                  device=cond.device, dtype=cond.dtype, clip=self.released_clip(),
                                  clip_x0=self.x0_clip(), clip_count=clip_count)
        return self.normalizer.unbias(z).reshape(B, K, T, IMU_CHANNELS)


def build_model(config: ModelConfig, normalizer: Normalizer,
                indirect_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> BiasModel:
    """A freshly initialised :class:`BiasModel` (seed torch before calling for reproducibility)."""
    return BiasModel(config, normalizer, indirect_weights)


def count_parameters(model: nn.Module) -> int:
    """Trainable parameters of ``model``."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
