"""Test-wide settings: the derivation cache lives in a temporary folder, never in ~/.cache."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True, scope="session")
def _isolated_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("PERTURB_CACHE_DIR", str(tmp_path_factory.mktemp("perturb-cache")))
    mp.setenv("PERTURB_PROGRESS", "0")
    yield
    mp.undo()
