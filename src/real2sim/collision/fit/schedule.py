"""The fit's step size at each iteration and when it stops (:attr:`FitConfig.lr_schedule`).

Why the plateau schedule is an option and not the default, with the measurements: docs/design-notes/collision.md#convergence-stop.
"""

from __future__ import annotations

import math

from real2sim.collision.fit.config import FitConfig


class StepSchedule:
    """The step size of each iteration and the stop (FitConfig.lr_schedule): "plateau" holds the
    step size while the smoothed loss makes progress, cuts it by ``lr_decay`` after
    ``decay_patience`` steps without, and stops once its floor has gone as long without; "cosine"
    and "constant" follow their curve and stop after ``patience`` steps without progress."""

    def __init__(self, config: FitConfig):
        self.config = config
        self.lr = self._cosine(0) if config.lr_schedule == "cosine" else config.lr
        self.floor = config.lr * config.final_lr_fraction
        self.smooth = self.best = math.inf
        self.since_best = 0

    def step(self, iteration: int, value: float) -> str:
        """Take iteration ``iteration``'s (1-based) minibatch loss; set :attr:`lr` for the next
        iteration; return the stop reason, or "" to go on."""
        c = self.config
        self.smooth = value if math.isinf(self.smooth) else 0.95 * self.smooth + 0.05 * value
        if self.smooth < self.best * (1 - c.plateau_tolerance):
            self.best, self.since_best = self.smooth, 0
        else:
            self.since_best += 1
        if c.lr_schedule == "plateau":
            if self.since_best < c.decay_patience:
                return ""
            if self.lr <= self.floor:
                return "converged" if iteration >= c.min_iterations else ""
            self.lr = max(self.floor, self.lr * c.lr_decay)
            self.best, self.since_best = self.smooth, 0
            return ""
        if c.lr_schedule == "cosine":
            self.lr = self._cosine(iteration)
        return "plateau" if iteration >= c.min_iterations and self.since_best >= c.patience else ""

    def _cosine(self, done: int) -> float:
        """The cosine schedule's step size after ``done`` steps."""
        c, f = self.config, self.config.final_lr_fraction
        return c.lr * (f + (1 - f) * 0.5 * (1 + math.cos(math.pi * done / max(1, c.max_iterations))))
