"""A regression network: the normalised window through two linear layers."""

from dataclasses import dataclass

import torch
from torch import nn


@dataclass(frozen=True)
class DemoOptions:
    width: int = 16


class DemoNet(nn.Module):
    def __init__(self, config) -> None:
        super().__init__()
        self.a = nn.Linear(config.condition_channels, config.network.width)
        self.b = nn.Linear(config.network.width, 6)

    def forward(self, condition: torch.Tensor) -> torch.Tensor:
        return self.b(self.a(condition))
