"""report.html and its animations opened in a real headless browser: every image loads and no
request leaves the machine (the report and the animations must work offline and stay private).

Uses Debian's `chromium` (`make test` installs it where apt-get runs as root); skipped with the
reason otherwise.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (make test installs Debian's chromium "
                                                         "where apt-get runs as root)")

# Loads the page in an iframe, then writes what it found into its own DOM, which --dump-dom prints.
PROBE = """<!DOCTYPE html><html><body><iframe id="f" src="{page}" style="width:1200px;height:900px"></iframe>
<pre id="out">pending</pre>
<script>
document.getElementById('f').addEventListener('load', function () {{
  setTimeout(function () {{
    var doc = document.getElementById('f').contentDocument;
    var imgs = Array.prototype.slice.call(doc.images);
    var broken = imgs.filter(function (im) {{ return !(im.complete && im.naturalWidth > 0); }})
                     .map(function (im) {{ return im.alt || im.src.slice(0, 60); }});
    document.getElementById('out').textContent = 'RESULT ' + JSON.stringify(
      {{images: imgs.length, broken: broken, canvases: doc.getElementsByTagName('canvas').length,
        links: Array.prototype.map.call(doc.links, function (a) {{ return a.getAttribute('href'); }})}});
  }}, 1500);
}});
</script></body></html>"""


def _open(page: Path, work: Path) -> tuple[dict, list[str]]:
    """What the probe found in ``page``, and every URL the pages (not the browser itself) requested."""
    probe = page.parent / f".probe_{page.stem}.html"
    probe.write_text(PROBE.format(page=page.name))
    netlog = work / f"netlog_{page.stem}.json"
    try:
        done = subprocess.run(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--allow-file-access-from-files", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             # Nothing resolves: a request that would leave the machine is logged, never sent.
             "--host-resolver-rules=MAP * ~NOTFOUND",
             f"--log-net-log={netlog}", "--virtual-time-budget=15000", "--dump-dom", probe.as_uri()],
            capture_output=True, text=True, timeout=180)
    finally:
        probe.unlink(missing_ok=True)
    found = re.search(r"RESULT (\{.*?\})\s*</pre>", done.stdout.replace("&quot;", '"'))
    assert found, f"the probe did not report (exit {done.returncode}): {done.stderr[-800:]}"
    return json.loads(found.group(1)), _page_requests(netlog)


def _page_requests(netlog: Path) -> list[str]:
    """URLs of requests a page made (the browser's own, e.g. its clock sync, have no origin)."""
    events = json.loads(netlog.read_text()).get("events", []) if netlog.exists() else []
    urls = {e["params"]["url"] for e in events
            if isinstance(e.get("params"), dict) and "url" in e["params"] and "initiator" in e["params"]
            and e["params"]["initiator"] != "not an origin"}
    return sorted(urls)


def _remote(urls: list[str]) -> list[str]:
    return [u for u in urls if not u.startswith(("file:", "data:", "blob:", "about:", "chrome:", "devtools:"))]


def test_the_probe_sees_a_request_that_would_leave_the_machine(tmp_path):
    """A control: a page with one remote image is caught (so an empty list below means something)."""
    page = tmp_path / "leaky.html"
    page.write_text("<html><body><img alt='remote' src='http://example.invalid/x.png'></body></html>")
    found, urls = _open(page, tmp_path)
    assert found["broken"] == ["remote"]
    assert _remote(urls) == ["http://example.invalid/x.png"]


def test_report_images_load_and_nothing_leaves_the_machine(tmp_path):
    from real2sim.evaluate.scene.scene_config import SceneConfig
    from real2sim.evaluate.sweep import EvaluationConfig, evaluate
    from tests.evaluate.test_sweep import make_box_asset

    import numpy as np

    from real2sim.formats.collision import CollisionGeometry, CollisionShape, write_collision_json

    box = make_box_asset(tmp_path / "box", reps=("boxes_1", "mesh"))
    extents = tuple(float(v) for v in np.ptp(np.loadtxt(
        [line[2:] for line in (box / "visual" / "model.obj").read_text().splitlines() if line.startswith("v ")]),
        axis=0))
    write_collision_json(CollisionGeometry("boxes_1", "boxes:1", (CollisionShape("box", extents),)),
                         box / "boxes_1" / "collision.json")
    write_collision_json(CollisionGeometry("mesh", "mesh", (CollisionShape("mesh", (), mesh_file="mesh.obj"),)),
                         box / "mesh" / "collision.json")
    scene = SceneConfig(settle_s=0.05, push_duration_s=0.25, pusher_start_distance_m=0.11,
                        pusher_speed_m_per_s=0.3, hold_s=0.05, tilt_time_s=0.3, total_duration_s=0.4)
    config = EvaluationConfig(tasks=("push", "ramp"), contact_models=("point",), runs=1, jobs=1, scene=scene)
    result = evaluate([box], tmp_path / "results", config, animations=True)

    report, urls = _open(result.report_path, tmp_path)
    assert report["images"] >= 4 + 3  # the four Pareto plots, the visual mesh and two representations
    assert report["broken"] == []
    assert sorted(link for link in report["links"] if link.startswith("animations/")) == \
        ["animations/push.html", "animations/ramp.html"]
    assert _remote(urls) == []

    animation, urls = _open(result.out_dir / "animations" / "push.html", tmp_path)
    assert animation["canvases"] >= 1  # Meshcat's WebGL view came up from the inlined viewer
    assert _remote(urls) == []
