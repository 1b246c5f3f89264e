"""The CPU cores this process may run on: what parallel work is sized to."""

from __future__ import annotations

import os


def usable_cores() -> int:
    """The CPUs this process may be scheduled on (its affinity mask where the OS has one), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)
