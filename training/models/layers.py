"""Building blocks shared by the networks: the TCN condition encoder and the step embedding.

The TCN follows the released code (a TLIO-style TCN, itself after locuslab/TCN): temporal blocks
of two weight-normalised causal dilated convolutions (kernel 2, dilation ``2^i`` in block ``i``,
left padding removed by "chomping" the right end), activation and dropout after each, a 1x1
residual convolution where the channel count changes, and a ReLU after the residual sum. The
**last timestep** of the last block, projected by a linear layer, is the condition code.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn.utils.parametrizations import weight_norm

__all__ = ["TemporalBlock", "TcnEncoder", "SinusoidalEmbedding", "StepEncoder"]


class TemporalBlock(nn.Module):
    """Two causal dilated convolutions with a residual connection: [B, C_in, T] -> [B, C_out, T]."""

    def __init__(self, c_in: int, c_out: int, kernel: int, dilation: int, dropout: float) -> None:
        super().__init__()
        self.pad = (kernel - 1) * dilation
        self.conv1 = weight_norm(nn.Conv1d(c_in, c_out, kernel, padding=self.pad, dilation=dilation))
        self.conv2 = weight_norm(nn.Conv1d(c_out, c_out, kernel, padding=self.pad, dilation=dilation))
        self.act1, self.act2 = nn.GELU(), nn.GELU()
        self.drop1, self.drop2 = nn.Dropout(dropout), nn.Dropout(dropout)
        self.downsample = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else None
        with torch.no_grad():  # the released initialisation: N(0, 0.01) directions
            self.conv1.parametrizations.weight.original1.normal_(0, 0.01)
            self.conv2.parametrizations.weight.original1.normal_(0, 0.01)
            if self.downsample is not None:
                self.downsample.weight.normal_(0, 0.01)

    def _chomp(self, x: torch.Tensor) -> torch.Tensor:
        return x[..., : x.shape[-1] - self.pad] if self.pad else x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.drop1(self.act1(self._chomp(self.conv1(x))))
        out = self.drop2(self.act2(self._chomp(self.conv2(out))))
        res = x if self.downsample is None else self.downsample(x)
        return torch.relu(out + res)


class TcnEncoder(nn.Module):
    """Condition encoder: normalised readings [B, T, C] -> condition code [B, cond_dim].

    Args:
        c_in: Input channels (6, or 7 with temperature).
        channels: Output channels per temporal block (dilation ``2^i``).
        kernel: Kernel size.
        dropout: Dropout inside the blocks.
        cond_dim: Size of the code (linear projection of the last timestep).
    """

    def __init__(self, c_in: int, channels: tuple[int, ...], kernel: int, dropout: float, cond_dim: int) -> None:
        super().__init__()
        blocks, prev = [], c_in
        for i, c in enumerate(channels):
            blocks.append(TemporalBlock(prev, c, kernel, 2**i, dropout))
            prev = c
        self.network = nn.Sequential(*blocks)
        self.proj = nn.Linear(prev, cond_dim)
        with torch.no_grad():
            self.proj.weight.normal_(0, 0.01)

    @property
    def receptive_field(self) -> int:
        """Samples that reach the last output: ``1 + 2 (k - 1) (2^L - 1)``."""
        k = self.network[0].conv1.kernel_size[0]
        return 1 + 2 * (k - 1) * (2 ** len(self.network) - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.network(x.transpose(1, 2))  # [B, C, T]
        return self.proj(h[..., -1])


class SinusoidalEmbedding(nn.Module):
    """Transformer-style embedding of the diffusion step: [B] -> [B, dim] (sin half, cos half)."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.dim = dim

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        half = self.dim // 2
        freq = torch.exp(torch.arange(half, device=t.device, dtype=torch.float32) * (-math.log(10000) / (half - 1)))
        arg = t.to(torch.float32)[:, None] * freq[None, :]
        return torch.cat([arg.sin(), arg.cos()], dim=-1)


class StepEncoder(nn.Sequential):
    """Sinusoidal embedding, Linear dim -> 4 dim, activation, Linear 4 dim -> dim: [B] -> [B, dim]."""

    def __init__(self, dim: int, activation: type[nn.Module] = nn.ReLU) -> None:
        super().__init__(SinusoidalEmbedding(dim), nn.Linear(dim, 4 * dim), activation(), nn.Linear(4 * dim, dim))
