"""An exponential moving average of the online weights, published for acting instead of them.

At batch 8 one update moves the greedy pose enough to flip whole evaluation episodes
(push_button went 100 % -> 25 % -> 95 % in 100 updates, BENCHMARKS.md). Actors and the
evaluator can act with an average of the recent online weights instead, as behaviour-cloning
and diffusion policies commonly evaluate an EMA; training itself (online and target
networks, TD targets) is unchanged. ``decay`` 0 publishes the online weights (the reference).
"""

from __future__ import annotations

import torch


class ActingAverage:
    """``average <- decay * average + (1 - decay) * online`` after every applied update."""

    def __init__(self, decay: float):
        if not 0.0 <= decay < 1.0:
            raise ValueError(f"acting_average decay must be in [0, 1), got {decay}")
        self.decay = float(decay)
        self._average: dict[str, torch.Tensor] = {}

    @property
    def enabled(self) -> bool:
        return self.decay > 0.0

    @torch.no_grad()
    def update(self, online: dict[str, torch.Tensor]) -> None:
        """Fold in the online weights (``C2FARM.weights()``: detached CPU copies)."""
        if not self.enabled:
            return
        if self._average.keys() != online.keys():  # first update, or another network: start from it
            self._average = {k: t.float().clone() for k, t in online.items()}
            return
        for k, t in online.items():
            self._average[k].mul_(self.decay).add_(t.float(), alpha=1.0 - self.decay)

    def weights(self, online: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """What to publish: the average (in the online weights' dtypes), or ``online`` when off or empty."""
        if not self.enabled or self._average.keys() != online.keys():
            return online
        return {k: self._average[k].to(online[k].dtype) for k in online}

    def state_dict(self) -> dict[str, torch.Tensor]:
        return dict(self._average)

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self._average = {k: t.float().clone() for k, t in state.items()}
