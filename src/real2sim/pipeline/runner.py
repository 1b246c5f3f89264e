"""How `run` runs one stage: skipped when current, else run and recorded in run.json with the
warnings it raised; the whole run's progress through one display; a failing stage named."""

from __future__ import annotations

from typing import Any, Callable

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress
from real2sim.pipeline import manifest as mf


class RunProgress:
    """The whole run through one :class:`~real2sim.plumbing.progress.ProgressFn`.

    A stage's end is a message ("[3/7] reconstruct: done", "... unchanged, skipped"); called as a
    ProgressFn itself, it passes the running stage's work on with the stage in front
    ("[3/7] reconstruct - training field ..."). A stage's start is no message of its own: a stage
    that stops on bad input before any work leaves only its error.
    """

    def __init__(self, progress: ProgressFn | None = None):
        self.progress = progress or null_progress
        self.label = ""

    def stage(self, name: str, index: int, count: int, status: str) -> None:
        """``status``: "running", "skipped" (unchanged), "done"."""
        self.label = f"[{index}/{count}] {name}"
        if status != "running":
            self.progress(f"{self.label}: {'unchanged, skipped' if status == 'skipped' else 'done'}", 0, 0)

    def __call__(self, message: str, done: int, total: int) -> None:
        self.progress(f"{self.label} - {message}", done, total)


class StageFailed(RuntimeError):
    """A stage raised; the finished stages stay recorded in run.json for a resume."""

    def __init__(self, stage: str, cause: BaseException):
        self.stage, self.cause = stage, cause
        text = str(cause).splitlines()[0] if str(cause) else type(cause).__name__
        super().__init__(f"stage {stage} failed: {type(cause).__name__}: {text}")


class Paused(Exception):
    """Raised before stage ``stage`` when the runner's ``pause`` asks to stop there: the stages before
    it are recorded, and the next call of `run` resumes from it (a batch runs an object's stages as
    separate tasks, each with the resources its stages need)."""

    def __init__(self, stage: str):
        self.stage = stage
        super().__init__(f"paused before stage {stage}")


class Runner:
    """Runs the stages in order, skipping the current ones; records each finished stage. ``pause``:
    called with each stage's name before it runs or is skipped; True stops the run there (:class:`Paused`)."""

    def __init__(self, manifest: mf.Manifest, progress: RunProgress, count: int,
                 pause: Callable[[str], bool] | None = None):
        self.manifest, self.progress, self.count = manifest, progress, count
        self.pause = pause
        self.index = 0
        self.statuses: dict[str, str] = {}

    def stage(self, name: str, inputs: dict, settings: Any, upstream: str | None, outputs: list[str] | None,
              work: Callable[[], dict | None]) -> str:
        """Run ``work`` unless the stage is current. ``outputs`` None: ``work`` returns {"outputs": [...]}."""
        if self.pause is not None and self.pause(name):
            raise Paused(name)
        self.index += 1
        key = mf.stage_key(inputs, settings, upstream)
        if self.manifest.is_current(name, key):
            self.statuses[name] = "skipped"
            self.progress.stage(name, self.index, self.count, "skipped")
            return key
        self.progress.stage(name, self.index, self.count, "running")
        self.manifest.forget(name)
        measured = mf.reset_stage_peak()
        # a warning raised while the stage builds its output under a temporary name names the output
        final = mf.final_names(outputs or [])
        with mf.timed() as clock, mf.recorded_warnings(final) as raised:  # shown now, recorded for the summary
            try:
                extra = work() or {}
            except (KeyboardInterrupt, StageFailed):
                raise
            except UserInputError as exc:
                raise UserInputError(f"stage {name}: {exc}") from exc
            except Exception as exc:  # noqa: BLE001 -- one line naming the stage; the traceback is chained
                raise StageFailed(name, exc) from exc
        if outputs is None:  # known only now: the warnings shown already keep their names, run.json's do not
            outputs = extra.pop("outputs")
            raised = list(dict.fromkeys(map(mf.final_names(outputs), raised)))
        if raised:  # kept in run.json, so that a resumed run that skips the stage still repeats them
            extra["warnings"] = raised
        self.manifest.record(name, key=key, inputs=inputs, settings=settings, outputs=outputs,
                             wall_seconds=clock[0], stage_peak=mf.stage_peak_mb() if measured else None,
                             extra=extra)
        self.manifest.own(name, sorted({out.split("/")[0] for out in outputs} - {mf.RUN_DIRNAME}))
        self.statuses[name] = "ran"
        self.progress.stage(name, self.index, self.count, "done")
        return key

    def warnings(self) -> list[dict]:
        """Every warning of this run's stages so far, run now or skipped as unchanged (recorded in
        run.json when they ran), in stage order: ``{"stage": ..., "message": ...}``."""
        return [{"stage": name, "message": text} for name in self.statuses
                for text in (self.manifest.entry(name) or {}).get("warnings", [])]
