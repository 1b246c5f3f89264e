"""MkDocs hook: the command-line reference page (``cli.md``), generated from the parser at build time.

Every verb's ``real2sim VERB --help`` as the program prints it, and a table of its flags, each linked
to the configuration field it sets (``real2sim.cli.fields``) on the configuration reference page, or
with the reason it sets none. A flag whose class is not on that page is a build warning, so
``mkdocs build --strict`` fails until the page documents it.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
from pathlib import Path

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.cli_reference")

#: The generated page, and the hand-written page whose ``::: module.Class`` blocks the links point at.
PAGE = "cli.md"
CONFIG_PAGE = "config.md"
#: Help text width, so the page does not depend on the terminal that builds it.
COLUMNS = "100"


def _config_classes(docs_dir: Path) -> dict[str, str]:
    """Class name -> dotted path of every ``::: real2sim....Class`` block of the configuration page."""
    text = (docs_dir / CONFIG_PAGE).read_text()
    return {m.group(1).rsplit(".", 1)[1]: m.group(1) for m in re.finditer(r"^::: (real2sim\.[\w.]+)", text, re.M)}


def _verbs(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """(verb, one-line help, its parser), in ``real2sim --help`` order."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help or "" for a in sub._choices_actions}
    seen, verbs = set(), []
    for name, verb_parser in sub.choices.items():
        if id(verb_parser) not in seen:
            seen.add(id(verb_parser))
            verbs.append((name, helps.get(name, ""), verb_parser))
    return verbs


def _field_cell(flags: list[str], classes: dict[str, str]) -> str:
    """What one option sets: a link to its field, or the reason it sets none."""
    from real2sim.cli.fields import FIELD_OF_FLAG, NOT_A_FIELD

    # a --no-X switch of its own sets the field of --X, off
    flags = flags + [f"--{f[5:]}" for f in flags if f.startswith("--no-")]
    for flag in flags:
        if flag in FIELD_OF_FLAG:
            entry = FIELD_OF_FLAG[flag]
            target, why = (entry, "") if isinstance(entry, str) else entry
            cls, _, name = target.partition(".")
            if cls not in classes:
                log.warning(f"{flag} sets {target}, but {CONFIG_PAGE} documents no {cls}: add '::: module.{cls}'")
                return f"`{target}`"
            link = f"[`{target}`][{classes[cls]}.{name}]"
            return f"{link} ({why})" if why else link
        if flag in NOT_A_FIELD:
            return f"sets no field: {NOT_A_FIELD[flag]}"
    return ""


def _row_text(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def cli_reference(docs_dir: Path) -> str:
    """The markdown of the command-line reference."""
    from real2sim.cli import build_parser

    classes = _config_classes(docs_dir)
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = COLUMNS
    try:
        parser = build_parser()
        top_help = parser.format_help()
        verbs = [(name, line, p, p.format_help()) for name, line, p in _verbs(parser)]
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    out = ["# Command line", "",
           "Generated from the program's own parser when the site is built: each verb's `--help`, then "
           "its options, each linked to the configuration field it sets (the field's docstring is the "
           "full description; [Configuration](config.md) has them all), or with the reason it sets "
           "none. Every flag is named after its field, with the unit in its name. Exit status and "
           "outputs follow the [reliability contract](reliability.md).", "",
           "```text", top_help.rstrip(), "```", ""]
    for name, line, verb_parser, help_text in verbs:
        out += [f"## real2sim {name}", "", (line[:1].upper() + line[1:] + ".") if line else "", "",
                "```text", help_text.rstrip(), "```", ""]
        rows = []
        for action in verb_parser._actions:
            flags = [s for s in action.option_strings if s.startswith("--")]
            if not flags or flags == ["--help"]:
                continue
            rows.append(f"| `{'`, `'.join(flags)}` | {_row_text(_field_cell(flags, classes))} |")
        if rows:
            out += ["| option | sets |", "| --- | --- |", *rows, ""]
    return "\n".join(out) + "\n"


def on_files(files, config):
    """Add the generated ``cli.md`` to the site's files (it is not on disk)."""
    content = cli_reference(Path(config["docs_dir"]))
    files.append(File.generated(config, PAGE, content=content))
    return files
