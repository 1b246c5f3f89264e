"""Collision fits in a process of its own: ``python -m real2sim.asset.fit_worker THREADS`` fits each job
whose path it reads on stdin (see :func:`real2sim.asset.fits.fit_all`, which starts it, and
:func:`real2sim.asset.fits.work_on`)."""

import sys

from real2sim.asset.fits import work_on

if __name__ == "__main__":
    raise SystemExit(work_on(sys.stdin, int(sys.argv[1])))
