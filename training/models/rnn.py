"""The GRU networks: the paper's noise predictor and the direct (regression / indirect) head."""

from __future__ import annotations

import torch
from torch import nn

from training.config import IMU_CHANNELS, ModelConfig
from training.models.layers import StepEncoder, TcnEncoder

__all__ = ["GruDenoiser", "GruRegressor"]


class _GruTrunk(nn.Module):
    """Linear in -> hidden, GRU (``gru_layers``), Linear hidden -> hidden, Linear hidden -> 6."""

    def __init__(self, c_in: int, config: ModelConfig) -> None:
        super().__init__()
        h = config.hidden
        self.fc_in = nn.Linear(c_in, h)
        self.gru = nn.GRU(h, h, num_layers=config.gru_layers, batch_first=True)
        self.fc = nn.Linear(h, h)
        self.out = nn.Linear(h, IMU_CHANNELS)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y, _ = self.gru(self.fc_in(x))
        return self.out(self.fc(y))


class GruDenoiser(nn.Module):
    """The released RNN noise predictor (``diffusion_rnn``).

    The step embedding [B, E] and the condition code [B, C] are broadcast to every timestep and
    concatenated with the noisy bias x_t [B, T, 6]; one Linear (6 + C + E -> hidden) fuses them;
    a GRU, a Linear and a Linear to 6 give the noise estimate [B, T, 6] at IMU rate. The paper
    size (256 / 256 / hidden 256 / 3 layers) has 2,192,710 parameters.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.encoder = TcnEncoder(config.condition_channels, config.tcn_channels, config.tcn_kernel,
                                  config.tcn_dropout, config.cond_dim)
        self.step_encoder = StepEncoder(config.step_embed_dim, nn.ReLU)
        self.trunk = _GruTrunk(IMU_CHANNELS + config.cond_dim + config.step_embed_dim, config)

    def encode(self, condition: torch.Tensor) -> torch.Tensor:
        """Normalised condition [B, T, C_in] -> code [B, cond_dim] (computed once per window)."""
        return self.encoder(condition)

    def denoise(self, x_t: torch.Tensor, t: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        """Noise estimate [B, T, 6] from x_t [B, T, 6], steps t [B] and codes [B, cond_dim]."""
        T = x_t.shape[1]
        step = self.step_encoder(t)
        h = torch.cat([x_t, code[:, None].expand(-1, T, -1), step[:, None].expand(-1, T, -1)], dim=-1)
        return self.trunk(h)


class GruRegressor(nn.Module):
    """Direct bias prediction with the same encoder and GRU (``regression_rnn``, ``indirect_rnn``).

    The condition code [B, C] is broadcast to every timestep (no x_t, no step input), fused by
    Linear C -> hidden, and the GRU trunk outputs the (normalised) bias [B, T, 6].
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.encoder = TcnEncoder(config.condition_channels, config.tcn_channels, config.tcn_kernel,
                                  config.tcn_dropout, config.cond_dim)
        self.trunk = _GruTrunk(config.cond_dim, config)

    def forward(self, condition: torch.Tensor) -> torch.Tensor:
        code = self.encoder(condition)
        return self.trunk(code[:, None].expand(-1, condition.shape[1], -1))
