"""``ASSETDIR/.run/run.json``: what each stage of `real2sim run` read, with which settings, and what it wrote.

A stage is skipped when its recorded *key* equals the key it would run with now
and every output it recorded is still present. The key is the SHA-256 of

* the **content** hashes (SHA-256 of the bytes) of its input files: the dataset's
  transforms.json, every image and mask the frames name, and ground_truth/mesh.obj,
  object_pose.json and transforms.json when present; for later stages the files
  the previous stage wrote (mesh.obj, canonical_transform.json, ...). Bytes, not
  size + mtime: a copied or touched dataset is the same dataset, an edited mask is
  not. (A 200-view 640x480 capture is ~100 MB: well under a second to hash.)
* the stage's **settings** (the dataclass fields, as JSON);
* the **upstream** stage's key, so that a stage that runs again makes every
  stage after it run again, even when its outputs come out byte-identical.

Memory: each stage's ``peak_memory_mb`` is its own peak resident memory. On Linux the
kernel's high-water mark is reset when a stage starts (``/proc/self/clear_refs``) and read
(VmHWM) when it ends; note that this also resets what ``getrusage(RUSAGE_SELF).ru_maxrss``
reports to the rest of the process. Elsewhere it is the process's peak so far
(ru_maxrss); ``peak_memory_scope`` says which. Worker processes (the evaluation's pool)
are in ``children_peak_memory_mb``.

A stage is recorded only after its outputs are in place (each is written to a
temporary name and renamed), and run.json itself is replaced atomically, so a
Ctrl-C or a killed process leaves the finished stages recorded and nothing else.

Warnings: a stage's entry lists, under ``warnings``, every Python warning shown while it ran (a
fallback, pose refinement that kept the given poses, ...), one plain sentence each, so that a run
that skips the stage as unchanged still repeats them (:func:`recorded_warnings`); a path in one names the
stage's output, not the temporary name it was built under (:func:`final_names`).

Ownership: ``owned`` maps each entry of ASSETDIR that `run` wrote (outside ``.run/``) to the
stage that wrote it and, for a folder, the files in it as written. A rerun replaces or removes
only these entries, and refuses to replace a folder holding files it did not write
(:meth:`Manifest.foreign_files`): everything else in ASSETDIR is the user's. The record
outlives a forgotten stage entry, so an interrupted rerun still knows what it made.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import resource
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from real2sim.formats.dataset import write_json_atomic as _write_json_atomic
from real2sim.plumbing.digests import all_files, file_sha256

MANIFEST_VERSION = 1
RUN_DIRNAME = ".run"
MANIFEST_NAME = "run.json"


def _jsonable(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return value.tolist()
    return str(value)


def settings_record(settings: Any) -> Any:
    """The JSON form of a stage's settings (dataclasses field by field, paths as strings)."""
    return _jsonable(settings)


def stage_key(inputs: dict, settings: Any, upstream: str | None) -> str:
    blob = json.dumps({"inputs": inputs, "settings": settings_record(settings), "upstream": upstream},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def write_json_atomic(path: Path, data: Any) -> None:
    """:func:`real2sim.formats.dataset.write_json_atomic`, any non-JSON value written as its text."""
    _write_json_atomic(path, data, default=str)


def peak_memory_mb(who: int = resource.RUSAGE_SELF) -> float:
    """Peak resident memory so far (ru_maxrss) of this process (or its finished children), MiB."""
    peak = resource.getrusage(who).ru_maxrss
    return round(peak / (1024 * 1024 if sys.platform == "darwin" else 1024), 1)


def reset_stage_peak() -> bool:
    """Reset the kernel's resident high-water mark (Linux: ``5`` into /proc/self/clear_refs), so that
    :func:`stage_peak_mb` measures one stage; False where that is not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def stage_peak_mb() -> float | None:
    """VmHWM of /proc/self/status (MiB): the peak resident memory since :func:`reset_stage_peak`."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024, 1)
    except (OSError, ValueError, IndexError):
        pass
    return None


class Manifest:
    """run.json of one asset folder: the dataset it belongs to and the finished stages."""

    def __init__(self, asset_dir: Path, dataset: Path, data: dict | None = None):
        self.asset_dir = Path(asset_dir)
        self.path = self.asset_dir / RUN_DIRNAME / MANIFEST_NAME
        # Relative to ASSETDIR: written files hold no absolute paths (they name people's home folders),
        # and a project folder holding both can be moved.
        self.data = data or {"version": MANIFEST_VERSION, "stages": {}, "owned": {},
                             "dataset": os.path.relpath(Path(dataset).resolve(), self.asset_dir.resolve())}
        #: run.json was written before ownership was recorded (``owned`` inferred below, files unknown)
        self.legacy = "owned" not in self.data
        if self.legacy:  # the stages' outputs
            self.data["owned"] = {out.split("/")[0]: {"stage": stage, "files": None}
                                  for stage, entry in self.data["stages"].items()
                                  for out in entry.get("outputs", []) if out.split("/")[0] != RUN_DIRNAME}

    @classmethod
    def load(cls, asset_dir: Path) -> "Manifest | None":
        """The manifest of ``asset_dir``, or None when it has none (or an unreadable one)."""
        path = Path(asset_dir) / RUN_DIRNAME / MANIFEST_NAME
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(data, dict) or data.get("version") != MANIFEST_VERSION or "dataset" not in data:
            return None
        data.setdefault("stages", {})
        return cls(asset_dir, Path(data["dataset"]), data)

    @property
    def dataset(self) -> Path:
        """The dataset's absolute path (stored relative to ASSETDIR)."""
        return (self.asset_dir.resolve() / self.data["dataset"]).resolve()

    def save(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.path, self.data)

    def entry(self, stage: str) -> dict | None:
        return self.data["stages"].get(stage)

    def is_current(self, stage: str, key: str) -> bool:
        """True when ``stage`` finished with ``key`` and all of its outputs are still there."""
        entry = self.entry(stage)
        if not entry or entry.get("key") != key:
            return False
        return all((self.asset_dir / rel).exists() for rel in entry.get("outputs", []))

    def record(self, stage: str, *, key: str, inputs: dict, settings: Any, outputs: list[str],
               wall_seconds: float, stage_peak: float | None = None, extra: dict | None = None) -> None:
        """``stage_peak``: this stage's own peak resident memory (MiB) when it could be measured;
        ``peak_memory_mb`` falls back to the process's peak so far (ru_maxrss)."""
        self.data["stages"][stage] = {
            "key": key,
            "inputs": inputs,
            "settings": settings_record(settings),
            "outputs": outputs,
            "wall_seconds": round(wall_seconds, 3),
            "peak_memory_mb": stage_peak if stage_peak is not None else peak_memory_mb(),
            "peak_memory_scope": "stage (VmHWM reset at its start)" if stage_peak is not None
            else "process so far (ru_maxrss)",
            "children_peak_memory_mb": peak_memory_mb(resource.RUSAGE_CHILDREN),
            "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            **(extra or {}),
        }
        self.save()

    def forget(self, stage: str) -> None:
        """Drop ``stage``'s record (it runs again); what it wrote stays owned (see the module docstring)."""
        if self.data["stages"].pop(stage, None) is not None:
            self.save()

    # ------------------------------------------------------------------ ownership

    def owned(self, stage: str | None = None) -> dict[str, dict]:
        """``{name: {"stage": ..., "files": [...] | None}}``: the ASSETDIR entries `run` wrote
        (``stage``: only those of that stage). ``files`` is None for a file or when unknown."""
        return {name: record for name, record in self.data["owned"].items()
                if stage is None or record["stage"] == stage}

    def own(self, stage: str, names: Iterable[str]) -> None:
        """Record the ASSETDIR entries ``names`` as written by ``stage``, with the files now in each folder."""
        for name in names:
            path = self.asset_dir / name
            self.data["owned"][name] = {"stage": stage, "files": all_files(path) if path.is_dir() else None}
        self.save()

    def claim(self, stage: str, files: dict[str, list[str] | None]) -> None:
        """Before ``stage`` moves new entries into ASSETDIR: ``{name: files of the new folder (None: a
        file)}`` are owned from now on, each folder's files added to those recorded before, so that a
        kill halfway through the swap leaves the old and the new entry both known as the run's."""
        for name, new in files.items():
            before = self.data["owned"].get(name, {}).get("files")
            merged = None if new is None else sorted(set(new) | set(before or []))
            self.data["owned"][name] = {"stage": stage, "files": merged}
        self.save()

    def add_owned_files(self, name: str, files: Iterable[str]) -> None:
        """Files a later stage wrote into the owned folder ``name`` (reports rewritten by ``truth``)."""
        record = self.data["owned"].get(name)
        if record is not None and record["files"] is not None:
            record["files"] = sorted(set(record["files"]) | set(files))
            self.save()

    def disown(self, names: Iterable[str]) -> None:
        for name in names:
            self.data["owned"].pop(name, None)
        self.save()

    def foreign_files(self, names: Iterable[str]) -> list[str]:
        """Files (relative to ASSETDIR) inside the owned folders ``names`` that `run` did not write:
        the user's, which replacing the folder would delete. Folders whose files are unknown
        (a run.json from before they were recorded) are taken as they are."""
        foreign = []
        for name in names:
            record, path = self.data["owned"].get(name), self.asset_dir / name
            if record is None or record["files"] is None or not path.is_dir():
                continue
            known = set(record["files"])
            foreign += [f"{name}/{rel}" for rel in all_files(path) if rel not in known and ".tmp-" not in rel]
        return foreign


@contextmanager
def timed() -> Iterator[list[float]]:
    """``with timed() as t: ...`` then ``t[0]`` holds the wall seconds."""
    box = [0.0]
    start = time.perf_counter()
    try:
        yield box
    finally:
        box[0] = time.perf_counter() - start


def plain_warning_text(message: Warning | str) -> str:
    """A warning's message as one plain sentence (its lines and spaces joined), as the command line prints it."""
    return " ".join(str(message).split())


def final_names(outputs: Iterable[str]) -> Callable[[str], str]:
    """A text rewrite that names each of a stage's ``outputs`` (paths relative to ASSETDIR) where a
    message names its temporary name (``.NAME.tmp-XXXXXXXX``, :func:`tempfile.mkdtemp`'s, with a file's
    suffix again): ``ASSETDIR/.run/.masked.tmp-1a2b3c4d/x`` -> ``ASSETDIR/.run/masked/x``. Only the names
    of these outputs and their folders, only right after a path separator, a space or a quote: a stage
    knows what it is about to rename, so this holds whether or not the temporary still exists."""
    names = sorted({part for out in outputs for part in Path(out).parts if part not in ("", ".", "..")},
                   key=len, reverse=True)
    if not names:
        return lambda text: text
    pattern = re.compile(r"(?:^|(?<=[/\s'\"(]))\.(" + "|".join(map(re.escape, names))
                         + r")\.tmp-[a-z0-9_]{8}(?:\.[A-Za-z0-9]{1,8})?(?=$|[/\s'\":,;)])")
    return lambda text: pattern.sub(r"\1", text)


@contextmanager
def recorded_warnings(rewrite: Callable[[str], str] | None = None) -> Iterator[list[str]]:
    """``with recorded_warnings() as raised: ...``: every Python warning shown while the block runs
    is also appended to ``raised`` (as :func:`plain_warning_text`, each text once, in order).
    ``rewrite``: applied to each warning's text before it is shown and recorded (a stage's temporary
    output names -> the outputs', :func:`final_names`).

    It is shown as before, by whatever displays warnings now (the command line's plain ``WARNING:``
    line): recording is added to the display, not put in its place, so the warning appears when it
    happens. Warnings the filters ignore are neither shown nor recorded. The filters' memory of
    what was shown is reset for the block (``catch_warnings``), so a stage that falls back the same
    way as a stage before it is still heard."""
    raised: list[str] = []
    with warnings.catch_warnings():  # puts the display back when the block ends
        show = warnings.showwarning

        def record(message, category, filename, lineno, file=None, line=None):
            text = plain_warning_text(message)
            if rewrite is not None and rewrite(text) != text:
                text = rewrite(text)
                message = _same_kind(message, category, text)
            if text not in raised:
                raised.append(text)
            show(message, category, filename, lineno, file, line)

        warnings.showwarning = record
        yield raised


def _same_kind(message: Warning | str, category: type, text: str) -> Warning | str:
    """A warning of ``message``'s category saying ``text`` (the text alone where the category cannot be
    made from one string), for the display: what it shows is what run.json records."""
    try:
        return category(text) if isinstance(message, Warning) else text
    except Exception:  # noqa: BLE001 -- a warning class with its own constructor: its text still shows
        return text
