"""ASSETDIR/asset_config.json: the full configuration an asset was built with.

The evaluation reads the contact material back from it, so that the reference is
simulated with the same friction and dissipation as the asset's representations
(rows then compare geometry, not material). An asset without the file (built
before it existed) evaluates with :class:`ContactProperties`' defaults, as before.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from real2sim.formats.contact import ContactProperties
from real2sim.plumbing.errors import UserInputError

ASSET_CONFIG_NAME = "asset_config.json"


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)  # paths, SPEC objects: their text


def write_asset_config(record: dict, path: Path) -> None:
    """Write ``record`` (dataclasses become dicts, paths and SPECs their text) as JSON."""
    Path(path).write_text(json.dumps(_plain(record), indent=1))


def read_asset_contact(asset_dir: Path | str) -> ContactProperties | None:
    """The contact material an asset was built with; None when it has no asset_config.json."""
    path = Path(asset_dir) / ASSET_CONFIG_NAME
    if not path.is_file():
        return None
    try:
        contact = json.loads(path.read_text())["contact"]
        # Written before the field existed, when every piece got the whole stiffness.
        contact.setdefault("point_stiffness_per_piece", False)
        return ContactProperties(**contact)
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise UserInputError(f"{path} has no readable contact properties: {exc}") from None
