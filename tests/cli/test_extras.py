"""A verb whose optional extra is missing says which extra to install, in one line, exit 2; the
wheel installs with the core alone and builds an asset (issue: the front door)."""

from __future__ import annotations

import os
import subprocess
import sys
import venv
from pathlib import Path

import pytest

from real2sim.cli.extras import EXTRA_MODULES, VERB_EXTRAS
from real2sim.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]

#: Run real2sim with the modules named in argv[1] (comma-separated) hidden, as if not installed.
HIDDEN = """
import importlib.abc, sys
hidden = set(sys.argv[1].split(","))
class Hide(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in hidden:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None
sys.meta_path.insert(0, Hide())
from real2sim.cli import main
sys.exit(main(sys.argv[2:]))
"""


def run_without(modules: str, *argv: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", HIDDEN, modules, *argv], capture_output=True, text=True, cwd=cwd)


def test_every_verb_and_extra_is_known():
    import argparse

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert set(VERB_EXTRAS) <= set(sub.choices)
    assert {extra for extras in VERB_EXTRAS.values() for extra in extras} <= set(EXTRA_MODULES)
    declared = (ROOT / "pyproject.toml").read_text()
    assert all(f"\n{extra} = [" in declared for extra in EXTRA_MODULES)


@pytest.mark.parametrize("argv, extra", [
    (["evaluate", "A", "--out", "R"], "sim"),
    (["capture", "can", "--out", "D"], "sim"),
    (["board", "--out", "b.pdf"], "phone"),
    (["asset", "m.obj", "--mass-kg", "1", "--out", "A", "--format", "usd"], "usd"),
])
def test_a_missing_extra_is_one_line_naming_it(tmp_path, argv, extra):
    done = run_without(",".join(EXTRA_MODULES[extra]), *argv, cwd=tmp_path)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert f"pip install 'real2sim[{extra}]'" in lines[0]
    assert not any(tmp_path.iterdir()), "nothing is written before the check"


def test_asset_needs_no_extra(tmp_path):
    hidden = ",".join(m for extra, modules in EXTRA_MODULES.items() for m in modules)
    assert run_without(hidden, "objects", "export", "can", "can.obj", cwd=tmp_path).returncode == 0
    done = run_without(hidden, "asset", "can.obj", "--mass-kg", "0.4", "--collision", "spheres:4", "--iterations", "20",
                       "--out", "can_asset", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "can_asset" / "spheres_4" / "model.urdf").is_file()


def test_the_wheel_installs_with_the_core_alone(tmp_path):
    """Build the wheel, check it, install it with its core dependencies only into a fresh virtual
    environment (torch from the local CPU wheel first), build an asset, and see evaluate ask for [sim]."""
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(dist), str(ROOT)], check=True,
                   capture_output=True)
    wheel = next(dist.glob("real2sim-*.whl"))
    subprocess.run([sys.executable, "-m", "twine", "check", str(wheel)], check=True, capture_output=True)
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", "torch==2.13.0"], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "-q", str(wheel)], check=True)
    work = tmp_path / "work"
    work.mkdir()
    exe = env_dir / "bin" / "real2sim"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    subprocess.run([str(exe), "objects", "export", "can", "can.obj"], check=True, cwd=work, env=env)
    subprocess.run([str(exe), "asset", "can.obj", "--mass-kg", "0.4", "--collision", "spheres:4", "--iterations", "20",
                    "--out", "can_asset"], check=True, cwd=work, env=env)
    assert (work / "can_asset" / "spheres_4" / "model.urdf").is_file()
    done = subprocess.run([str(exe), "evaluate", "can_asset", "--out", "results"], cwd=work, env=env,
                          capture_output=True, text=True)
    assert done.returncode == 2 and "pip install 'real2sim[sim]'" in done.stderr
