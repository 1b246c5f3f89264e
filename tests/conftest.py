"""Shared fixtures: small real meshes the project makes itself."""

from __future__ import annotations

import os

# Torch's default OpenMP spin-wait stalls small ops on 2-core machines (DESIGN.md).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

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
