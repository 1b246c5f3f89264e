"""Shared fixtures: small real meshes the project makes itself."""

from __future__ import annotations

import os

# Torch's default OpenMP spin-wait stalls small ops on 2-core machines (DESIGN.md).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# Several test workers (make test: pytest-xdist) share the cores: each one's torch, and the command
# lines its tests start, get their share instead of every core each.
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
if _WORKERS > 1:
    os.environ.setdefault("OMP_NUM_THREADS", str(max(1, (os.cpu_count() or 1) // _WORKERS)))

import pytest


@pytest.fixture(scope="session")
def bottle_mesh():
    from real2sim.geometry.objects import make_object

    return make_object("bottle")


@pytest.fixture(scope="session")
def can_mesh():
    from real2sim.geometry.objects import make_object

    return make_object("can")


@pytest.fixture(scope="session")
def mug_mesh():
    from real2sim.geometry.objects import make_object

    return make_object("mug")


# With the suite spread over workers one file at a time (make test), a long file that starts last
# keeps one worker busy alone at the end: the longest files (a minute or more each on 2 cores) go first,
# by the seconds their tests took in the suite (`pytest --durations`, 2 workers, 2026-12-07).
_LONGEST_FIRST = ("tests/pipeline/test_robot_frame.py", "tests/multiview/test_dense_run.py",
                  "tests/reconstruct/test_parallax_masks.py", "tests/cli/test_extras.py", "tests/test_pipeline.py",
                  "tests/pipeline/test_parallax_run.py", "tests/cli/test_demo.py", "tests/pipeline/test_batch_signals.py",
                  "tests/reconstruct/test_table_plate.py", "tests/test_behaviour_unchanged.py",
                  "tests/reconstruct/test_photo_carving.py", "tests/pipeline/test_batch.py",
                  "tests/evaluate/test_reliability.py", "tests/pipeline/test_phone.py")


def pytest_collection_modifyitems(session, config, items):
    rank = {path: i for i, path in enumerate(_LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))  # stable: the rest keep their order
