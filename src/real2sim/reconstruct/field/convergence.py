"""When a stage of the field's training has converged: its learning rates decay as its loss stops improving.

A stage's grid learning rate decays tenfold, ``base * 0.1 ** fraction`` with ``fraction`` going
from 0 to 1. On a fixed schedule ``fraction`` is the share of the stage's steps done. With the
convergence rule the training loss is averaged over windows of ``window_steps`` steps (the
smoothed loss); a window whose mean is not below the best earlier window's by ``rel_tolerance``
is a plateau, and each plateau moves ``fraction`` on by ``1 / decays`` (the rate drops by
``10 ** (-1 / decays)``); a plateau at the final rate ends the stage. ``fraction`` never lags
the fixed schedule's, so a stage whose loss keeps falling runs, and decays, as before, to its
cap (why: docs/design-notes/reconstruct.md#field-convergence).
"""

from __future__ import annotations

from dataclasses import dataclass

STOP_CAP = "cap"  # the stage ran all its steps
STOP_CONVERGED = "converged"  # its loss stopped improving at the final rate


@dataclass(frozen=True)
class ConvergenceConfig:
    """The rule that ends each training stage of the field once its smoothed loss has stopped improving,
    and drives its learning-rate decay by that progress (why: docs/design-notes/reconstruct.md#field-convergence)."""

    enabled: bool = True
    """End a stage (coarse or fine grid) once its loss has flattened, its steps (``coarse_steps``,
    ``fine_steps``) being the caps; False: every stage runs its steps with the rate decaying by the count
    (on by default: the fine grid trained 40 % fewer steps at the same Chamfer, why:
    docs/design-notes/reconstruct.md#field-convergence)."""
    window_steps: int = 40
    """Steps whose training losses are averaged into one point of the smoothed loss the rule compares
    (and the loss curve reports), on a CPU; >= 2. 40: the fixed schedule's reporting window on the fine
    grid, whose means vary by about 1 % from window to window once the loss is flat (why:
    docs/design-notes/reconstruct.md#field-convergence)."""
    rel_tolerance: float = 0.02
    """A window is a plateau when its mean loss is not below the lowest earlier window's by this share of
    it; in [0, 1). 0.02: twice the windows' own scatter, so sampling noise alone rarely makes a plateau."""
    decays: int = 2
    """Plateaus that take the grid's rate from its start to a tenth of it, each dropping it by
    ``10 ** (-1 / decays)``; the plateau after those ends the stage; >= 1."""

    def on_device(self, scale: int) -> "ConvergenceConfig":
        """These settings for steps ``scale`` times as large (FieldConfig.on_device): as many times fewer
        steps a window, so that a window sees the same rays."""
        from dataclasses import replace

        return self if scale == 1 else replace(self, window_steps=max(self.window_steps // scale, 2))

    def validate(self) -> None:
        from real2sim.plumbing.errors import UserInputError

        if int(self.window_steps) < 2 or int(self.decays) < 1 or not 0 <= self.rel_tolerance < 1:
            raise UserInputError("field convergence needs window_steps >= 2, decays >= 1 and a tolerance in [0, 1) "
                                 f"(got {self.window_steps}, {self.decays}, {self.rel_tolerance})")


class StageSchedule:
    """The decay of one stage of ``steps`` steps, fixed (``config`` None or off) or driven by its loss; feed
    it each window's losses (:meth:`observe`) and read :meth:`fraction` and :attr:`stopped`."""

    def __init__(self, steps: int, config: ConvergenceConfig | None = None, report_every: int | None = None):
        self.steps = max(int(steps), 1)
        self.rule = config if config is not None and config.enabled else None
        # the losses are read once a window: a GPU sync
        self.window = int(self.rule.window_steps) if self.rule else (report_every or max(self.steps // 20, 1))
        self.plateaus = 0
        self.best = float("inf")
        self.stopped: str | None = None
        self.windows: list[float] = []  # each window's mean loss
        self.trained = 0  # steps done

    def fraction(self, step: int) -> float:
        """The share of the tenfold decay done before step ``step`` (0-based) of this stage, in [0, 1]."""
        by_count = step / self.steps
        return min(max(by_count, self.plateaus / self.rule.decays), 1.0) if self.rule else by_count

    def observe(self, mean: float, count: int, step: int) -> float:
        """Take the mean training loss of a window of ``count`` steps ending after step ``step`` (0-based);
        returns it. Marks the stage stopped at its cap or once its loss flattened at the final rate."""
        self.windows.append(mean)
        self.trained = step + 1
        if self.rule is not None and count == self.window:
            if mean > (1.0 - self.rule.rel_tolerance) * self.best:
                if self.plateaus >= self.rule.decays:
                    self.stopped = STOP_CONVERGED
                self.plateaus += 1
            self.best = min(self.best, mean)
        if step + 1 >= self.steps and self.stopped is None:
            self.stopped = STOP_CAP
        return mean
