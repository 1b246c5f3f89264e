"""Report: summary, Pareto plots and report.html of a results folder, from its CSVs only.

A sub-stage of :mod:`real2sim.evaluate` (the sweep writes the report at its end); it reads
:mod:`real2sim.formats.results` and never imports the evaluation.
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "build_outputs": "html",
    "write_report": "html",
    "render_html": "page",
    "recommend": "pareto",
    "pareto_front": "pareto",
    "write_pareto_plots": "pareto",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
