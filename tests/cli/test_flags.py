"""Every flag of every verb sets a named configuration field or says why not; flags carry their units;
one concept has one flag and one default on every verb (real2sim.cli.fields)."""

from __future__ import annotations

import argparse
import dataclasses
import re

import pytest

from real2sim.asset.config import AssetConfig
from real2sim.capture.masks.methods import MaskConfig
from real2sim.capture.poses.refine_config import RefineConfig
from real2sim.capture.sim.capture_config import CaptureConfig
from real2sim.capture.sim.handheld_config import HandheldConfig
from real2sim.cli import build_parser
from real2sim.cli.fields import FIELD_OF_FLAG, NOT_A_FIELD
from real2sim.collision.decomposition import CoacdConfig, VhacdConfig
from real2sim.collision.fit.config import FitConfig
from real2sim.evaluate.sweep import EvaluationConfig
from real2sim.formats.contact import ContactProperties
from real2sim.identify.stage import ExciteConfig
from real2sim.pipeline.batch import BatchConfig
from real2sim.pipeline.phone import PhoneConfig
from real2sim.pipeline.run_config import RunConfig
from real2sim.reconstruct.carving.config import CarvingConfig
from real2sim.reconstruct.config import ReconstructConfig
from real2sim.reconstruct.field.train import FieldConfig

CONFIGS = {c.__name__: c for c in (AssetConfig, MaskConfig, RefineConfig, CaptureConfig, HandheldConfig, CoacdConfig,
                                   VhacdConfig, FitConfig, EvaluationConfig, ContactProperties, ExciteConfig,
                                   BatchConfig, PhoneConfig, RunConfig, CarvingConfig, ReconstructConfig, FieldConfig)}

#: metavar -> the unit suffix a flag with it must end in.
UNIT_OF_METAVAR = {"M": "-m", "MM": "-mm", "KG": "-kg", "S": "-s", "PA": "-pa", "N_PER_M": "-n-per-m",
                   "S_PER_M": "-s-per-m", "NM": "-n-m", "PX": "-px", "DEG": "-deg", "STOPS": "-stops"}


def verb_options() -> list[tuple[str, argparse.Action]]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    found = [("real2sim", a) for a in parser._actions if a.option_strings and a.dest != "help"]
    for verb, verb_parser in sub.choices.items():
        found += [(verb, a) for a in verb_parser._actions if a.option_strings and a.dest != "help"]
    return found


def concept(action: argparse.Action) -> str:
    """The flag an action is registered under: ``--no-x`` of a negating switch is ``--x``'s concept."""
    flag = action.option_strings[0]
    if flag not in FIELD_OF_FLAG and flag not in NOT_A_FIELD and flag.startswith("--no-"):
        return "--" + flag[len("--no-"):]
    return flag


OPTIONS = verb_options()


def test_every_flag_sets_a_field_or_says_why_not():
    missing = sorted({f"{verb} {concept(a)}" for verb, a in OPTIONS
                      if concept(a) not in FIELD_OF_FLAG and concept(a) not in NOT_A_FIELD})
    assert not missing, f"flags neither in cli.fields.FIELD_OF_FLAG nor NOT_A_FIELD: {missing}"
    assert not set(FIELD_OF_FLAG) & set(NOT_A_FIELD)
    used = {concept(a) for _, a in OPTIONS}
    assert not (set(FIELD_OF_FLAG) | set(NOT_A_FIELD)) - used, "entries for flags no verb has"


@pytest.mark.parametrize("flag", sorted(FIELD_OF_FLAG))
def test_the_field_exists_and_the_flag_is_named_after_it(flag):
    entry = FIELD_OF_FLAG[flag]
    target, why = (entry, None) if isinstance(entry, str) else entry
    class_name, field = target.split(".")
    assert field in {f.name for f in dataclasses.fields(CONFIGS[class_name])}, f"{flag}: no field {target}"
    same_name = flag[2:].replace("-", "_") == field
    assert same_name or why, f"{flag} sets {target} under another name: rename one, or say why"
    assert not (same_name and why), f"{flag} is named after {target}: drop the reason"


@pytest.mark.parametrize("verb,action", OPTIONS, ids=[f"{v} {a.option_strings[0]}" for v, a in OPTIONS])
def test_a_flag_with_a_unit_says_it(verb, action):
    metavar = action.metavar if isinstance(action.metavar, str) else None
    unit = UNIT_OF_METAVAR.get(metavar or "")
    if unit:
        assert action.option_strings[0].endswith(unit), f"{verb} {action.option_strings[0]} takes {metavar}"
    for flag in action.option_strings:  # bare unit words that hide a unit: --duration, --threshold-mm ok
        assert not re.fullmatch(r"--(mass|duration|height|width|seconds|address|weights|threshold)", flag), flag


#: flags whose default rightly differs between verbs, and why.
DEFAULT_DIFFERS = {
    "--out": "each verb's output is its own",
    "--views": "a robot ring and a handheld walk take different numbers of photos",
    "--fov-deg": "a wrist camera and a phone have different lenses",
    "--pose-noise-mm": "capture adds this noise; refine-poses' None reads what the capture recorded",
    "--pose-noise-deg": "capture adds this noise; refine-poses' None reads what the capture recorded",
}


def test_one_concept_has_one_default_on_every_verb():
    defaults: dict[str, dict[str, object]] = {}
    for verb, action in OPTIONS:
        if action.default is not argparse.SUPPRESS:
            defaults.setdefault(concept(action), {})[verb] = action.default
    differing = {flag: by_verb for flag, by_verb in defaults.items()
                 if flag not in DEFAULT_DIFFERS and len({repr(d) for d in by_verb.values()}) > 1}
    assert not differing, f"one concept, several defaults: {differing}"


@pytest.mark.parametrize("flag", sorted(f for f, e in FIELD_OF_FLAG.items() if isinstance(e, str)))
def test_a_flag_named_after_its_field_has_the_field_default(flag):
    class_name, field = FIELD_OF_FLAG[flag].split(".")  # type: ignore[union-attr]
    spec = next(f for f in dataclasses.fields(CONFIGS[class_name]) if f.name == field)
    actions = [a for _, a in OPTIONS if concept(a) == flag and a.option_strings[0] == flag]
    for action in actions:
        if spec.default is dataclasses.MISSING or action.default is None or spec.default is None:
            continue
        default = action.default
        if isinstance(spec.default, tuple) and isinstance(default, str):
            default = tuple(default.split(","))  # a comma-separated list flag
        elif isinstance(spec.default, int) and isinstance(default, str):
            default = int(default)  # a choice of numbers written as strings
        assert default == spec.default, f"{flag} defaults to {action.default!r}, {class_name}.{field} to {spec.default!r}"
