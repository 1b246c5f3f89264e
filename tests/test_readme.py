"""The README's Python snippets run as they are written (issue: the front door)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from real2sim.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


def test_the_readme_is_a_front_door():
    text = README.read_text()
    lines = text.splitlines()
    assert len(lines) <= 250
    first_command = next(i for i, line in enumerate(lines) if line.startswith(("pip ", "make ", "real2sim ")))
    assert first_command < 40
    for target in re.findall(r"\]\(((?:docs|CHANGELOG|LICENSE|CITATION)[^)#]*)\)", text):
        assert (README.parent / target).exists(), f"README links to {target}, which does not exist"


def test_the_python_snippets_run(tmp_path, monkeypatch):
    """The quick start's build snippet, then the loading snippet, on the can the README exports."""
    blocks = python_blocks()
    build = next(b for b in blocks if "real2sim.build_asset" in b)
    load = next(b for b in blocks if "MultibodyPlant" in b)
    monkeypatch.chdir(tmp_path)
    assert main(["objects", "export", "can", "can.obj"]) == 0
    exec(compile(build, "README.md (build)", "exec"), {})
    namespace: dict = {}
    exec(compile(load, "README.md (load)", "exec"), namespace)
    assert namespace["plant"].num_bodies() >= 2
    assert namespace["model"].nbody >= 2
