"""The golden comparison's own rules (tests/golden/record.py), on small files written here: float rounding
that moves the last digits passes, a changed word or a number beyond the tolerance fails."""

from __future__ import annotations

import json

from tests.golden.record import MAX_TEXT_NUMBERS, compare_outputs, summarise

URDF = '<robot name="r"><inertial><mass value="0.35"/><inertia ixx="{ixx}" iyy="3.5e-04"/></inertial></robot>\n'


def recorded(root, rel):
    return {"files": {rel: summarise(root / rel, True)}}


def test_rounding_in_the_last_digits_passes_but_text_and_real_changes_fail(tmp_path):
    urdf = tmp_path / "model.urdf"
    urdf.write_text(URDF.format(ixx="0.00037188606257027517"))
    golden = recorded(tmp_path, "model.urdf")
    assert "layout_sha256" in golden["files"]["model.urdf"]

    urdf.write_text(URDF.format(ixx="0.00037188606257021"))  # 1.7e-13 relative: a reordered sum
    assert compare_outputs(golden, tmp_path) == []

    urdf.write_text(URDF.format(ixx="0.00037188606257027517").replace('name="r"', 'name="s"'))
    problems = compare_outputs(golden, tmp_path)
    assert len(problems) == 1 and "text around them changed" in problems[0]

    urdf.write_text(URDF.format(ixx="0.000372"))  # 3e-4 relative: a result moved
    problems = compare_outputs(golden, tmp_path)
    assert any("bytes changed" in p for p in problems) and any("number #1" in p for p in problems)


def test_json_and_long_texts_follow_the_same_rule(tmp_path):
    report = tmp_path / "report.json"
    report.write_text(json.dumps({"mass_kg": 0.35, "com_m": [1.4929455901845595e-05, 0.1]}, indent=1))
    long_text = tmp_path / "model.usda"
    values = [0.001 * (i % 97) + 1e-3 for i in range(MAX_TEXT_NUMBERS + 10)]
    long_text.write_text("points = [" + ", ".join(repr(v) for v in values) + "]\n")
    golden = {"files": {**recorded(tmp_path, "report.json")["files"], **recorded(tmp_path, "model.usda")["files"]}}
    kept = golden["files"]["model.usda"]["values"]
    assert "#1" not in kept and "#0" in kept and "sum_sq" in kept  # too many to keep: a sample stands for them

    report.write_text(json.dumps({"mass_kg": 0.35, "com_m": [1.49294559018456e-05, 0.1]}, indent=1))
    long_text.write_text("points = [" + ", ".join(repr(v * (1 + 1e-13)) for v in values) + "]\n")
    assert compare_outputs(golden, tmp_path) == []

    values[0] += 1e-5  # one kept number moved
    long_text.write_text("points = [" + ", ".join(repr(v) for v in values) + "]\n")
    assert any(p.startswith("model.usda: number #0") for p in compare_outputs(golden, tmp_path))
    values[0] -= 1e-5
    long_text.write_text("points = [" + ", ".join(repr(v + 1e-5) for v in values) + "]\n")  # all of them moved
    assert any(p.startswith("model.usda:") for p in compare_outputs(golden, tmp_path))

    report.write_text(json.dumps({"mass_kg": 0.35, "com_m": [1.4929455901845595e-05, 0.1], "new": 1}, indent=1))
    assert any(p.startswith("report.json:") for p in compare_outputs(golden, tmp_path))


def test_a_json_layout_leaves_out_hashes_and_versions(tmp_path):
    config = tmp_path / "asset_config.json"

    def write(digest: str, numpy_version: str, mode: str = "compliant") -> None:
        config.write_text(json.dumps({"mass_kg": 0.6, "contact": {"hydroelastic": mode},
                                      "software": {"numpy": numpy_version},
                                      "input_mesh_sha256": digest}, indent=1))

    write("4dcade6b95ca7942", "2.4.6")
    golden = recorded(tmp_path, "asset_config.json")
    write("b6e8717a129f8564", "2.5")  # another input's hash (digits elsewhere), a version of two parts
    assert compare_outputs(golden, tmp_path) == []
    write("4dcade6b95ca7942", "2.4.6", mode="rigid")  # a setting's word is behaviour
    problems = compare_outputs(golden, tmp_path)
    assert len(problems) == 1 and "text around them changed" in problems[0]
