"""Exponential moving average of model weights (diffusion_policy's ``EMAModel`` rule).

At its ``n``-th update (counted from 0) the average moves with decay ``d_n = 0`` for ``n <= 1``
and ``d_n = min(1 - n^-power, max_decay)`` after (so the average starts as a copy of the
weights and its memory grows as training goes on):
``ema = d ema + (1 - d) w`` for every floating parameter; buffers (the normaliser) are copied.
"""

from __future__ import annotations

import copy
from typing import Any

import torch
from torch import nn

__all__ = ["EMA"]


class EMA:
    """Holds an averaged copy of a model.

    Args:
        model: The model being trained (copied, the copy is put in eval mode).
        max_decay: Upper bound of the decay.
        power: Warm-up power.
    """

    def __init__(self, model: nn.Module, max_decay: float = 0.999, power: float = 0.75) -> None:
        self.model = copy.deepcopy(model).eval()
        self.model.requires_grad_(False)
        self.max_decay = float(max_decay)
        self.power = float(power)
        self.optimization_step = 0

    def decay(self) -> float:
        """Decay used by the next :meth:`update`."""
        step = self.optimization_step - 1
        if step <= 0:
            return 0.0
        return max(0.0, min(1.0 - (1.0 + step) ** -self.power, self.max_decay))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        """Move the average towards ``model``'s current weights."""
        d = self.decay()
        for ema_p, p in zip(self.model.parameters(), model.parameters(), strict=True):
            ema_p.mul_(d).add_(p.detach(), alpha=1.0 - d)
        for ema_b, b in zip(self.model.buffers(), model.buffers(), strict=True):
            ema_b.copy_(b)
        self.optimization_step += 1

    def state_dict(self) -> dict[str, Any]:
        return {"model": self.model.state_dict(), "optimization_step": self.optimization_step}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.model.load_state_dict(state["model"])
        self.optimization_step = int(state["optimization_step"])
