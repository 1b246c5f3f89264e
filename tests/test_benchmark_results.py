"""The benchmarks' results as results: every cited result file exists, every file is stamped and cited.

Benchmarks write their latest result to ``benchmarks/results/<name>.md`` and ``.json``
(benchmarks/common.py); the pages, design notes, docstrings and the CHANGELOG cite them. A citation of a
file that is gone, a result without its machine, date and command, a result that nothing cites, or a
link to a design note's measurement that has no heading of that name fails here.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
FORMER = "docs/" + "benchmarks"  # the folder the results left; spelt in two so this file cites nothing
CITED = re.compile(r"(?<![\w/.-])(?:\.\./)*(" + re.escape(FORMER) + r"/[\w.*\[\]-]+|benchmarks/results/[\w.*\[\]-]+)")
NOTE_ANCHOR = re.compile(r"(?<![\w/.-])(?:\.\./)*(?:docs/)?design-notes/(\w+)\.md#(\w+_[\w-]*)")
"""A link to a measurement a design note holds: its heading is the benchmark's name (``#phone_remask_islands``)."""
SUFFIXES = {".py", ".md", ".toml", ".txt", ".cfg", ".yml", ".yaml"}


def _citing_files() -> list[Path]:
    files = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "Makefile"]
    for folder in ("src", "tests", "docs", "benchmarks"):
        files += [p for p in (ROOT / folder).rglob("*")
                  if p.is_file() and p.suffix in SUFFIXES and "__pycache__" not in p.parts and "out" not in
                  p.relative_to(ROOT).parts[:2] and not p.name.endswith(".egg-info")]
    return [p for p in files if p.exists()]


def _citations() -> list[tuple[Path, int, str]]:
    """(file, line, cited path) for every results path written anywhere, bar the commands of stamps (history)."""
    found = []
    for path in _citing_files():
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if "_Machine:" in line:
                continue
            found += [(path, number, m.group(1)) for m in CITED.finditer(line)]
    return found


def _is_file_name(cited: str) -> bool:
    """A cited file (``.md``/``.json``), not the folder or a pattern (``name_TAG.md``, ``x[_TAG].md``)."""
    name = cited.rsplit("/", 1)[1]
    return name.endswith((".md", ".json")) and not re.search(r"[*\[\]]|TAG|SECTION|<", name) and name[:-3] != ""


def _declares_output(path: Path, number: int) -> bool:
    """A benchmark's own "Writes benchmarks/results/<name>.md" (its output, which a benchmark not yet run
    lacks): the line or the one before says write/writes/writing."""
    if path.parent != ROOT / "benchmarks":
        return False
    lines = path.read_text(errors="replace").splitlines()[max(0, number - 2):number]
    return bool(re.search(r"\b[Ww]rit(e|es|ing)\b", " ".join(lines)))


def test_every_cited_result_exists():
    missing = [f"{p.relative_to(ROOT)}:{n}: {c}" for p, n, c in _citations()
               if _is_file_name(c) and not (ROOT / c.rstrip(".,;:)`")).is_file() and not _declares_output(p, n)]
    assert not missing, "cited results that do not exist:\n" + "\n".join(missing)


def test_the_former_benchmark_folder_is_gone():
    assert not (ROOT / FORMER).exists() and not (ROOT / (FORMER + ".md")).exists()
    cited = [f"{p.relative_to(ROOT)}:{n}: {c}" for p, n, c in _citations() if c.startswith(FORMER) and _is_file_name(c)]
    assert not cited, "files of the former folder still cited:\n" + "\n".join(cited)


def test_every_result_is_stamped_and_cited():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from common import STAMP

    results = sorted(RESULTS.glob("*.md"))
    assert results
    cited = {c.rstrip(".,;:)`") for p, _, c in _citations() if p.parent != RESULTS}
    problems = []
    for md in results:
        rel = md.relative_to(ROOT).as_posix()
        stamps = list(STAMP.finditer(md.read_text()))
        if not stamps or not all(s["machine"].strip() and s["date"].strip() and s["command"].strip() for s in stamps):
            problems.append(f"{rel}: no stamp line (_Machine: ... Date: ... Command: `...`._)")
        record = json.loads(md.with_suffix(".json").read_text()) if md.with_suffix(".json").is_file() else None
        if record is None or not record.get("runs") or not all(
                r.get("machine") and r.get("date") and r.get("command") and "tables" in r for r in record["runs"]):
            problems.append(f"{rel}: no .json beside it with machine, date, command and tables for each run")
        elif len(record["runs"]) != len(stamps):
            problems.append(f"{rel}: {len(stamps)} stamps, {len(record['runs'])} runs in its .json")
        if rel not in cited:
            problems.append(f"{rel}: cited by no page, design note, docstring or the CHANGELOG")
    strays = [p.name for p in RESULTS.iterdir() if p.suffix not in (".md", ".json") or
              (p.suffix == ".json" and not p.with_suffix(".md").is_file())]
    assert not problems and not strays, "\n".join(problems + [f"stray file {s}" for s in strays])


def test_design_note_measurements_cited_exist():
    """A link to a design note's measurement (``design-notes/capture.md#phone_remask_islands``) has its heading."""

    def slug(text: str) -> str:  # Python-Markdown's toc slug, as the site and GitHub make it for these names
        return re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", text).strip().lower())

    headings = {p.stem: {slug(h) for h in re.findall(r"^#+ (.+?)\s*$", p.read_text(), re.M)}
                for p in (ROOT / "docs" / "design-notes").glob("*.md")}
    broken = []
    for path in _citing_files():
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            for m in NOTE_ANCHOR.finditer(line):
                if m.group(1) in headings and m.group(2) not in headings[m.group(1)]:
                    broken.append(f"{path.relative_to(ROOT)}:{number}: {m.group(0)}")
    assert not broken, "design-note anchors with no heading:\n" + "\n".join(broken)


def test_writer_stamps_and_replaces(tmp_path, monkeypatch):
    """benchmarks/common.py's writer: the stamp, the tables as JSON, and a rerun replacing the first run."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import common

    monkeypatch.setattr(common, "RESULTS", tmp_path)
    body = "Intro.\n\n" + common.markdown_table(["object", "Chamfer (mm)", "ok"], [["can", 0.25, "yes"]])
    path = common.write_result("probe", "A probe", body, "python benchmarks/bench_probe.py --x 1")
    text = path.read_text()
    stamp = common.STAMP.search(text)
    assert text.startswith("# A probe\n") and stamp and stamp["command"] == "`python benchmarks/bench_probe.py --x 1`"
    record = json.loads(path.with_suffix(".json").read_text())
    assert record["runs"][0]["tables"] == [{"columns": ["object", "Chamfer (mm)", "ok"], "rows": [["can", 0.25, "yes"]]}]
    common.write_result("probe", "A probe", "Second.", "python benchmarks/bench_probe.py")
    assert "Second." in path.read_text() and "Chamfer" not in path.read_text()
    assert json.loads(path.with_suffix(".json").read_text())["runs"][0]["tables"] == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["probe.json", "probe.md"]


if __name__ == "__main__":
    raise SystemExit(pytest.main([__file__, "-q"]))
