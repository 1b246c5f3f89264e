"""bench_field_budget.py's variants: NAME=FIELD=VALUE[,...] as FieldConfig settings, a bad one refused in one line."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import bench_field_budget as bfb  # noqa: E402


def test_a_variant_names_its_settings():
    assert bfb.parse_variant("fewer=rays_per_step=2048,coarse_steps=250") == (
        "fewer", ["rays_per_step=2048", "coarse_steps=250"])
    with pytest.raises(ValueError, match="NAME=FIELD=VALUE"):
        bfb.parse_variant("rays_per_step")


def test_an_unknown_field_stops_the_benchmark_before_any_capture(capsys):
    with pytest.raises(SystemExit) as stop:
        bfb.main(["--variant", "x=no_such_field=3"])
    assert stop.value.code == 2
    assert "no_such_field" in capsys.readouterr().err
