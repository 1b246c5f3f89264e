"""The results folder's CSV files: runs.csv (one row per simulation) and summary.csv (one
row per ``<representation>_<contactmodel>`` and simulator, the layout of the paper's Table I).

Written by the evaluation, read by the report; neither imports the other.

Torn rows: every runs.csv row ends with :data:`CHECK_COLUMN`, the CRC-32 of its other
fields, so a row cut mid-number (a crash or a full disk while an older version appended,
a copy cut short, a hand edit) is recognised: :func:`load_runs_csv` sets aside rows whose
checksum is missing or wrong, whose field count is wrong or whose numbers do not parse,
and reports their line numbers; the sweep simulates them again and the report leaves them
out. A runs.csv written before the column existed still reads (its rows are unverified,
but rows with the wrong field count or unparsable numbers are still set aside).

The simulator: every row says which simulator made it (:data:`SIMULATORS`), and it is part of the
row's key. A runs.csv or summary.csv written before the column existed reads as Drake's (the only
simulator then); its checksums still verify, being over the columns the file has.
"""

from __future__ import annotations

import csv
import math
import os
import re
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import write_text_atomic


#: The simulators a row can come from; Drake first, the default and the only one before the column existed.
SIMULATORS = ("drake", "mujoco")

#: The contact models each simulator has (MuJoCo's soft contacts are point contacts: no pressure fields).
SIMULATOR_CONTACT_MODELS = {"drake": ("point", "hydroelastic"), "mujoco": ("point",)}

#: What a row without a ``simulator`` field (written before the column existed) was simulated in.
LEGACY_SIMULATOR = "drake"

RUN_COLUMNS = (
    "object", "representation", "contact_model", "simulator", "task", "run", "ate_m", "ocae_m", "cpd_m_per_s",
    "cpd_force_weighted_m_per_s", "cpd_paper", "sim_time_s", "sim_duration_s", "real_time_factor", "error",
)


# Added after the first release: a runs.csv without them still reads (as NaN).
_OPTIONAL_RUN_COLUMNS = ("cpd_force_weighted_m_per_s", "cpd_paper", "simulator")


#: Last column of runs.csv: CRC-32 (8 hex digits) of the row's RUN_COLUMNS fields as written.
CHECK_COLUMN = "row_crc32"


KEY_COLUMNS = ("object", "representation", "contact_model", "simulator", "task", "run")


FLOAT_COLUMNS = ("ate_m", "ocae_m", "cpd_m_per_s", "cpd_force_weighted_m_per_s", "cpd_paper", "sim_time_s",
                 "sim_duration_s", "real_time_factor")


SUMMARY_COLUMNS = (
    "representation", "ocae_m", "ate_m", "cpd_m_per_s", "sim_time_s",  # the layout of the paper's Table I
    "cpd_force_weighted_m_per_s", "cpd_paper", "collision", "contact_model", "simulator", "sim_duration_s",
    "real_time_factor", "runs_ok", "runs_failed",
)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _csv_text(header: Sequence[str], records: Iterable[Sequence[str]]) -> str:
    import io

    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(header)
    writer.writerows(records)
    return buffer.getvalue()


def write_csv_atomic(path: Path, rows: Iterable[dict], columns: Sequence[str]) -> None:
    """Write ``rows`` to ``path`` whole or not at all (temporary file, fsync, rename)."""
    write_text_atomic(path, _csv_text(columns, ([_fmt(row.get(c, "")) for c in columns] for row in rows)))


def row_checksum(fields: Sequence[str]) -> str:
    """CRC-32 of a runs.csv row's RUN_COLUMNS fields (their text as written), 8 hex digits."""
    # The unit separator cannot occur in a field, so moving a character across a field
    # boundary changes the checksum too.
    return f"{zlib.crc32(chr(31).join(fields).encode('utf-8')) & 0xFFFFFFFF:08x}"


def write_runs_csv(path: Path, rows: Iterable[dict]) -> None:
    """Write runs.csv whole or not at all: RUN_COLUMNS, then each row's checksum (CHECK_COLUMN)."""
    def records():
        for row in rows:
            fields = [_fmt(row.get(c, "")) for c in RUN_COLUMNS]
            yield fields + [row_checksum(fields)]

    write_text_atomic(path, _csv_text(RUN_COLUMNS + (CHECK_COLUMN,), records()))


@dataclass(frozen=True)
class RunsTable:
    """What :func:`load_runs_csv` found: the complete rows, the line numbers of torn rows
    (set aside), and whether the file carries checksums (False: written before they existed)."""

    rows: list[dict]
    torn_lines: tuple[int, ...]
    verified: bool


def _parse_row(raw: dict[str, str]) -> dict[str, Any]:
    """One row from its text fields; ValueError when a key is empty or a number does not parse."""
    row: dict[str, Any] = {c: raw.get(c, "") for c in RUN_COLUMNS}
    row["simulator"] = row["simulator"] or LEGACY_SIMULATOR  # written before the column existed
    if any(not row[c] for c in KEY_COLUMNS):
        raise ValueError("empty key field")
    row["run"] = int(raw["run"])
    for c in FLOAT_COLUMNS:
        # An empty optional column (older files) is NaN; float() reads "nan", "inf" and numbers.
        row[c] = float(raw.get(c) or "nan")
    row["error"] = raw.get("error") or ""
    return row


def load_runs_csv(path: Path) -> RunsTable:
    """Read runs.csv; torn rows are set aside (see the module docstring), never guessed at.

    UserInputError when the file is not a runs.csv at all: not a readable text file,
    binary, or without the RUN_COLUMNS header.
    """
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"{path} is not a file")
    rows: list[dict] = []
    torn: list[int] = []
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header is None:
                raise UserInputError(f"{path} is empty, not a runs.csv")
            missing = set(RUN_COLUMNS) - set(header) - set(_OPTIONAL_RUN_COLUMNS)
            if missing:
                raise UserInputError(f"{path} is not a runs.csv (missing columns {', '.join(sorted(missing))})")
            verified = CHECK_COLUMN in header
            for record in reader:
                if not record:
                    continue  # a blank line
                line = reader.line_num
                if len(record) != len(header):
                    torn.append(line)
                    continue
                raw = dict(zip(header, record))
                # over the columns the file has: one written before an optional column existed verifies
                if verified and row_checksum([raw[c] for c in RUN_COLUMNS if c in raw]) != raw[CHECK_COLUMN]:
                    torn.append(line)
                    continue
                try:
                    rows.append(_parse_row(raw))
                except ValueError:
                    torn.append(line)
    except UnicodeDecodeError:
        raise UserInputError(f"{path} is not a runs.csv (not UTF-8 text)") from None
    except csv.Error as exc:
        raise UserInputError(f"{path} is not a runs.csv ({exc})") from None
    except OSError as exc:
        raise UserInputError(f"could not read {path}: {exc.strerror or exc}") from None
    return RunsTable(rows, tuple(torn), verified)


def read_runs_csv(path: Path) -> list[dict]:
    """The complete rows of runs.csv (floats parsed, ``run`` an int); torn rows left out."""
    return load_runs_csv(path).rows


def describe_torn(table: RunsTable, path: Path | str) -> str:
    """One line about the torn rows of ``table`` (empty when there are none)."""
    if not table.torn_lines:
        return ""
    lines = ", ".join(str(n) for n in table.torn_lines[:10]) + (" ..." if len(table.torn_lines) > 10 else "")
    return f"{len(table.torn_lines)} incomplete or corrupt row(s) in {Path(path).name} (line {lines})"


# An absolute path in a message: a '/' not preceded by a word character or a dot, then at
# least two components ("m/s" and "1/2" are not paths).
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~])/(?:[^\s/'\"(),;:]+/)+[^\s/'\"(),;:]*")


def relative_paths_in_text(text: str, base: Path | str) -> str:
    """``text`` with every absolute path in it rewritten relative to ``base`` (the results
    folder), so that results and reports do not record where the user's files live."""
    base = os.path.abspath(base)
    return _ABSOLUTE_PATH.sub(lambda m: os.path.relpath(m.group(0), base), text)


def row_key(row: dict) -> tuple:
    """The row's KEY_COLUMNS values; a row made before the simulator column is Drake's."""
    return tuple((row.get(c) or LEGACY_SIMULATOR) if c == "simulator" else row[c] for c in KEY_COLUMNS)


def summary_label(collision: str, contact_model: str, simulator: str = LEGACY_SIMULATOR) -> str:
    """summary.csv's ``representation`` label: ``<collision>_<contactmodel>`` for Drake (as the paper's
    Table I and every results folder before the simulator column), ``<collision>_<contactmodel>_<simulator>``
    for any other simulator (``coacd_point_mujoco``)."""
    return f"{collision}_{contact_model}" if simulator == LEGACY_SIMULATOR else f"{collision}_{contact_model}_{simulator}"


def _simulator_rank(simulator: str) -> int:
    return SIMULATORS.index(simulator) if simulator in SIMULATORS else len(SIMULATORS)


def summarize(rows: Sequence[dict]) -> list[dict]:
    """One row per ``<representation>_<contactmodel>`` and simulator (:func:`summary_label`): means over
    objects, tasks and runs; Drake's rows first, then each other simulator's.

    Only rows without an error enter the means (``runs_failed`` counts the others).
    ``sim_time_s`` is the mean wall-clock seconds per simulation, as the paper's ST;
    ``real_time_factor`` is total simulated time over total wall time. CPD ignores
    runs where it is undefined (no sustained contact).
    """
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["representation"], r["contact_model"], r.get("simulator") or LEGACY_SIMULATOR),
                          []).append(r)
    out = []
    for (rep, cm, sim), group in sorted(groups.items(), key=lambda kv: (_simulator_rank(kv[0][2]), kv[0])):
        ok = [r for r in group if not r["error"]]

        def mean(col: str, src=ok) -> float:
            vals = np.array([r.get(col, math.nan) for r in src], dtype=float)
            vals = vals[np.isfinite(vals)]
            return float(np.mean(vals)) if len(vals) else math.nan

        total_time = float(np.nansum([r["sim_time_s"] for r in ok])) if ok else math.nan
        total_duration = float(np.nansum([r["sim_duration_s"] for r in ok])) if ok else math.nan
        out.append({
            "representation": summary_label(rep, cm, sim),
            "ocae_m": mean("ocae_m"),
            "ate_m": mean("ate_m"),
            "cpd_m_per_s": mean("cpd_m_per_s"),
            "sim_time_s": mean("sim_time_s"),
            "cpd_force_weighted_m_per_s": mean("cpd_force_weighted_m_per_s"),
            "cpd_paper": mean("cpd_paper"),
            "collision": rep,
            "contact_model": cm,
            "simulator": sim,
            "sim_duration_s": mean("sim_duration_s"),
            "real_time_factor": total_duration / total_time if ok and total_time > 0 else math.nan,
            "runs_ok": len(ok),
            "runs_failed": len(group) - len(ok),
        })
    return out


def read_summary_csv(path: Path) -> list[dict]:
    rows = []
    with open(path, newline="") as fh:
        for raw in csv.DictReader(fh):
            row: dict[str, Any] = dict(raw)
            row["simulator"] = row.get("simulator") or LEGACY_SIMULATOR  # written before the column existed
            for c in FLOAT_COLUMNS:
                if c in row:
                    row[c] = float(row[c]) if row[c] not in ("", None) else math.nan
            for c in ("runs_ok", "runs_failed"):
                if c in row and row[c] not in ("", None):
                    row[c] = int(row[c])
            rows.append(row)
    return rows
