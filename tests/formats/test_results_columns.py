"""runs.csv files written before an optional column existed still read, and still verify."""

from __future__ import annotations

import csv
import math

from real2sim.formats.results import CHECK_COLUMN, RUN_COLUMNS, load_runs_csv, row_checksum, write_runs_csv


def _row(**over):
    row = {"object": "can", "representation": "spheres_8", "contact_model": "point", "task": "push", "run": 0,
           "ate_m": 0.01, "ocae_m": 0.02, "cpd_m_per_s": 0.3, "cpd_force_weighted_m_per_s": 0.2, "cpd_paper": 0.004,
           "sim_time_s": 1.5, "sim_duration_s": 2.0, "real_time_factor": 1.3, "error": ""}
    row.update(over)
    return row


def test_cpd_paper_round_trips(tmp_path):
    path = tmp_path / "runs.csv"
    write_runs_csv(path, [_row()])
    table = load_runs_csv(path)
    assert table.verified and not table.torn_lines
    assert table.rows[0]["cpd_paper"] == 0.004


def _old_runs_csv(tmp_path, old_columns: list[str]):
    """A runs.csv of one row with only ``old_columns``, checksummed as it was written then."""
    fields = [repr(v) if isinstance(v, float) else str(v) for v in (_row()[c] for c in old_columns)]
    path = tmp_path / "runs.csv"
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow([*old_columns, CHECK_COLUMN])
        writer.writerow([*fields, row_checksum(fields)])
    return path


def test_a_runs_csv_from_before_cpd_paper_verifies_and_reads_it_as_nan(tmp_path):
    old_columns = [c for c in RUN_COLUMNS if c not in ("cpd_paper", "simulator")]  # both came later
    path = _old_runs_csv(tmp_path, old_columns)
    table = load_runs_csv(path)
    assert table.verified and table.torn_lines == ()
    assert len(table.rows) == 1 and math.isnan(table.rows[0]["cpd_paper"])
    # a changed field is still caught
    text = path.read_text().replace("0.02,", "0.03,", 1)
    path.write_text(text)
    assert load_runs_csv(path).torn_lines == (2,)


def test_a_runs_csv_from_before_the_simulator_column_verifies_and_reads_as_drake(tmp_path):
    from real2sim.formats.results import row_key, summarize

    old_columns = [c for c in RUN_COLUMNS if c != "simulator"]
    path = _old_runs_csv(tmp_path, old_columns)
    table = load_runs_csv(path)
    assert table.verified and table.torn_lines == ()
    assert table.rows[0]["simulator"] == "drake"
    assert row_key(table.rows[0]) == ("can", "spheres_8", "point", "drake", "push", 0)
    assert summarize(table.rows)[0]["representation"] == "spheres_8_point"  # Drake's label, as before
    # rewritten, it carries the column, and a MuJoCo row beside it is a row of its own
    write_runs_csv(path, [*table.rows, dict(table.rows[0], simulator="mujoco")])
    rows = load_runs_csv(path).rows
    assert [r["simulator"] for r in rows] == ["drake", "mujoco"]
    assert [s["representation"] for s in summarize(rows)] == ["spheres_8_point", "spheres_8_point_mujoco"]
