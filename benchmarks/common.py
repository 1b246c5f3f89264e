"""Shared by the benchmarks: machine description and writing stamped results into benchmarks/results/.

Each benchmark writes its latest result, benchmarks/results/<name>.md (a title, the stamp: machine, date
and command, then the figures as tables) and benchmarks/results/<name>.json (the same stamp and every
table of the body as columns and rows), replacing what an earlier run of the same benchmark wrote; git
keeps the history. docs/results.md curates the headline figures from these files. A run given a
``--tag`` writes ``<name>_<tag>``: a named configuration, kept only while a page cites it
(tests/test_benchmark_results.py checks that every file here is cited and stamped).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import re
from pathlib import Path

from real2sim.plumbing.cores import usable_cores

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


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
    cores = usable_cores()
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


STAMP = re.compile(r"^_Machine: (?P<machine>.+?)\. Date: (?P<date>.+?)\. Commands?: (?P<command>.+)\._$", re.M)
"""The stamp line of a results file: machine, date and command (tests/test_benchmark_results.py reads it)."""


def _cell(value: str):
    value = value.strip()
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


def markdown_tables(body: str) -> list[dict]:
    """Every markdown table of ``body`` as ``{"columns": [...], "rows": [[...]]}`` (numbers parsed)."""
    tables, lines = [], body.splitlines()
    for i in range(len(lines) - 1):
        starts = lines[i].startswith("|") and (i == 0 or not lines[i - 1].startswith("|"))
        if starts and re.match(r"^\|[\s:|-]+\|?$", lines[i + 1]):
            rows = []
            for line in lines[i + 2:]:
                if not line.startswith("|"):
                    break
                rows.append([_cell(c) for c in line.strip().strip("|").split("|")])
            tables.append({"columns": [c.strip() for c in lines[i].strip().strip("|").split("|")], "rows": rows})
    return tables


def write_result(name: str, title: str, body: str, command: str) -> Path:
    """Write benchmarks/results/<name>.md and .json (machine, date, command; the figures as tables and
    as JSON), replacing an earlier run's; returns the .md path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    machine, date = machine_description(), today()
    path = RESULTS / f"{name}.md"
    path.write_text(f"# {title}\n\n_Machine: {machine}. Date: {date}. Command: `{command}`._\n\n{body.strip()}\n")
    record = {"benchmark": name, "title": title,
              "runs": [{"machine": machine, "date": date, "command": command, "tables": markdown_tables(body)}]}
    path.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
    return path


