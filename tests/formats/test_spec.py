import pytest

from real2sim.plumbing.errors import UserInputError
from real2sim.formats.spec import MAX_PRIMITIVES, parse_spec


@pytest.mark.parametrize(
    "text, name, parts, baseline",
    [
        ("spheres:128", "spheres_128", (("spheres", 128),), None),
        ("rotated_boxes:50", "rotated_boxes_50", (("rotated_boxes", 50),), None),
        ("boxes:20+cylinders:20", "boxes_20_cylinders_20", (("boxes", 20), ("cylinders", 20)), None),
        ("coacd", "coacd", (), "coacd"),
        ("mesh", "mesh", (), "mesh"),
    ],
)
def test_parse_valid(text, name, parts, baseline):
    spec = parse_spec(text)
    assert spec.name == name
    assert spec.parts == parts
    assert spec.baseline == baseline
    assert spec.is_primitive_fit == (baseline is None)


@pytest.mark.parametrize(
    "text",
    ["", "pyramids:3", "spheres:0", f"boxes:{MAX_PRIMITIVES + 1}", "boxes:1500+spheres:600", "boxes:", "boxes:3+",
     "boxes:3++spheres:2", "boxes:2+boxes:3", "coacd+boxes:3", "Boxes:3", "boxes:-1", "boxes:1.5"],
)
def test_parse_invalid(text):
    with pytest.raises(UserInputError) as err:
        parse_spec(text)
    assert "\n" not in str(err.value)
