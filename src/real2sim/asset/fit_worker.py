"""One collision fit in a process of its own: ``python -m real2sim.asset.fit_worker JOB`` (see
:func:`real2sim.asset.fits.fit_all`, which starts it, and :func:`real2sim.asset.fits.work_on`)."""

import sys
from pathlib import Path

from real2sim.asset.fits import work_on

if __name__ == "__main__":
    raise SystemExit(work_on(Path(sys.argv[1])))
