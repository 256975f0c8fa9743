"""The 1-D conditional U-Net (after diffusion_policy's ``ConditionalUnet1D``) and its two uses.

Structure: residual blocks of two (Conv1d, GroupNorm, Mish) layers with FiLM conditioning (a
per-channel bias from Mish + Linear of the global condition, added after the first layer); per
level of ``down_dims`` two blocks and a stride-2 downsampling convolution (not after the last),
two middle blocks, the mirrored upsampling path (ConvTranspose1d) with skip concatenation, and a
final (Conv1d, GroupNorm, Mish) + 1x1 convolution. The global condition is ``[step embedding,
condition code]`` for the noise predictor (paper size: 42,814,022 parameters) and the condition
code alone for regression.

Windows whose length is not a multiple of ``2^(levels - 1)`` (the project's windows have
``T = rate * window_s + 1`` samples) are padded at the end by repeating the last sample and the
output is cropped back to T.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from training.config import IMU_CHANNELS, ModelConfig
from training.models.layers import StepEncoder, TcnEncoder

__all__ = ["ConditionalUnet1D", "UnetDenoiser", "UnetRegressor"]


class _ConvBlock(nn.Sequential):
    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int) -> None:
        super().__init__(nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2), nn.GroupNorm(groups, c_out), nn.Mish())


class _ResBlock(nn.Module):
    """[B, C_in, T] and condition [B, D] -> [B, C_out, T] (FiLM bias after the first conv block)."""

    def __init__(self, c_in: int, c_out: int, cond_dim: int, kernel: int, groups: int) -> None:
        super().__init__()
        self.block1 = _ConvBlock(c_in, c_out, kernel, groups)
        self.block2 = _ConvBlock(c_out, c_out, kernel, groups)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, c_out))
        self.residual = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        out = self.block1(x) + self.film(cond)[..., None]
        return self.block2(out) + self.residual(x)


class ConditionalUnet1D(nn.Module):
    """[B, T, c_in] sample and global condition [B, cond_dim] -> [B, T, c_out].

    Args:
        c_in: Channels of the input sample.
        c_out: Channels of the output.
        cond_dim: Size of the global (FiLM) condition.
        dims: Channels per level (down dims).
        kernel: Convolution kernel size.
        groups: GroupNorm groups.
    """

    def __init__(self, c_in: int, c_out: int, cond_dim: int, dims: tuple[int, ...], kernel: int, groups: int) -> None:
        super().__init__()
        all_dims = [c_in, *dims]
        levels = list(zip(all_dims[:-1], all_dims[1:]))
        self.down = nn.ModuleList()
        for i, (a, b) in enumerate(levels):
            last = i == len(levels) - 1
            self.down.append(nn.ModuleList([
                _ResBlock(a, b, cond_dim, kernel, groups), _ResBlock(b, b, cond_dim, kernel, groups),
                nn.Identity() if last else nn.Conv1d(b, b, 3, stride=2, padding=1)]))
        self.mid = nn.ModuleList([_ResBlock(dims[-1], dims[-1], cond_dim, kernel, groups) for _ in range(2)])
        self.up = nn.ModuleList()
        for a, b in reversed(levels[1:]):
            self.up.append(nn.ModuleList([
                _ResBlock(2 * b, a, cond_dim, kernel, groups), _ResBlock(a, a, cond_dim, kernel, groups),
                nn.ConvTranspose1d(a, a, 4, stride=2, padding=1)]))
        self.final = nn.Sequential(_ConvBlock(dims[0], dims[0], kernel, groups), nn.Conv1d(dims[0], c_out, 1))
        self.multiple = 2 ** (len(dims) - 1)

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        T = x.shape[1]
        pad = (-T) % self.multiple
        h = x.transpose(1, 2)
        if pad:
            h = F.pad(h, (0, pad), mode="replicate")
        skips = []
        for res1, res2, downsample in self.down:
            h = res2(res1(h, cond), cond)
            skips.append(h)
            h = downsample(h)
        for block in self.mid:
            h = block(h, cond)
        for res1, res2, upsample in self.up:
            h = torch.cat([h, skips.pop()], dim=1)
            h = upsample(res2(res1(h, cond), cond))
        return self.final(h)[..., :T].transpose(1, 2)


class UnetDenoiser(nn.Module):
    """The released U-Net noise predictor (``diffusion_unet``): FiLM from [step embedding, code]."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.encoder = TcnEncoder(config.condition_channels, config.tcn_channels, config.tcn_kernel,
                                  config.tcn_dropout, config.cond_dim)
        self.step_encoder = StepEncoder(config.step_embed_dim, nn.Mish)
        self.unet = ConditionalUnet1D(IMU_CHANNELS, IMU_CHANNELS, config.step_embed_dim + config.cond_dim,
                                      config.unet_dims, config.unet_kernel, config.unet_groups)

    def encode(self, condition: torch.Tensor) -> torch.Tensor:
        """Normalised condition [B, T, C_in] -> code [B, cond_dim]."""
        return self.encoder(condition)

    def denoise(self, x_t: torch.Tensor, t: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        """Noise estimate [B, T, 6] from x_t [B, T, 6], steps t [B] and codes [B, cond_dim]."""
        return self.unet(x_t, torch.cat([self.step_encoder(t), code], dim=-1))


class UnetRegressor(nn.Module):
    """Direct regression with the same U-Net (``regression_unet``): the input sample is the
    normalised condition [B, T, C_in] itself, FiLM from the code; output the normalised bias."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.encoder = TcnEncoder(config.condition_channels, config.tcn_channels, config.tcn_kernel,
                                  config.tcn_dropout, config.cond_dim)
        self.unet = ConditionalUnet1D(config.condition_channels, IMU_CHANNELS, config.cond_dim,
                                      config.unet_dims, config.unet_kernel, config.unet_groups)

    def forward(self, condition: torch.Tensor) -> torch.Tensor:
        return self.unet(condition, self.encoder(condition))
