"""Shared by the benchmarks: machine description and writing results into docs/.

Each benchmark writes its own section, docs/benchmarks/<name>.md, and then
docs/benchmarks.md is rebuilt as the index of all sections, so one benchmark
can be re-run without losing the others' numbers.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = ROOT / "docs" / "benchmarks"
INDEX = ROOT / "docs" / "benchmarks.md"


def machine_description() -> str:
    """One line: CPU model, cores available, memory, OS, Python, torch and Drake versions."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    try:
        mem_gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        mem_gib = float("nan")
    from importlib.metadata import PackageNotFoundError, version

    versions = []
    for dist in ("torch", "drake"):
        try:
            versions.append(f"{dist} {version(dist)}")
        except PackageNotFoundError:
            pass
    gpu = ""
    try:
        import torch

        if torch.cuda.is_available():
            gpu = f", GPU {torch.cuda.get_device_name(0)}"
    except ImportError:
        pass
    return (f"{cpu}, {cores} cores, {mem_gib:.0f} GiB{gpu}, {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}, " + ", ".join(versions))


def today() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def dataclass_settings(cls, items: list[str] | None, option: str) -> dict:
    """``FIELD=VALUE`` strings as settings of the dataclass ``cls`` (int, float, optional float or bool fields); ValueError
    with one line naming ``option`` and the fields when one is not."""
    import dataclasses

    fields = {f.name: f.type for f in dataclasses.fields(cls)}
    settings = {}
    for item in items or []:
        name, _, value = item.partition("=")
        kind = str(fields.get(name, ""))
        if kind not in ("int", "float", "bool", "float | None", str(int), str(float), str(bool)) or not value:
            raise ValueError(f"{option} {item!r}: expected FIELD=VALUE with FIELD a number setting among "
                             f"{', '.join(fields)}")
        settings[name] = (value.lower() in ("1", "true", "yes") if "bool" in kind
                          else int(value) if "int" in kind else float(value))
    return settings


def markdown_table(header: list[str], rows: list[list]) -> str:
    def fmt(v) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def write_section(name: str, title: str, body: str, command: str) -> Path:
    """Write docs/benchmarks/<name>.md (with machine, date and the command) and rebuild the index."""
    SECTIONS.mkdir(parents=True, exist_ok=True)
    path = SECTIONS / f"{name}.md"
    path.write_text(
        f"## {title}\n\n_Machine: {machine_description()}. Date: {today()}. Command: `{command}`._\n\n{body.strip()}\n"
    )
    rebuild_index()
    return path


def rebuild_index() -> None:
    parts = [
        "# Benchmarks\n",
        "Every number here is written by a script in `benchmarks/` (run `make bench`, or one script alone). "
        "Each section names its machine, date and command. Tests never assert timings.\n",
    ]
    for section in sorted(SECTIONS.glob("*.md")):
        parts.append(section.read_text().strip() + "\n")
    INDEX.write_text("\n".join(parts))
