"""Shared fixtures: the real probes in ../shared (skipped cleanly when absent)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

PROBE_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "probes"


def pytest_configure(config):
    """Fits recorded by commands under test go to a private catalogue, never the user's library."""
    os.environ["BRDFRIG_LIBRARY"] = str(Path(tempfile.mkdtemp(prefix="brdfrig-test-library-")) / "library.sqlite")


def probe_paths() -> list[Path]:
    """Real measured light probes (lat-long Radiance .hdr), or [] when ../shared is absent."""
    return sorted(PROBE_DIR.glob("*.hdr")) if PROBE_DIR.is_dir() else []


@pytest.fixture
def real_probes() -> list[Path]:
    paths = probe_paths()
    if not paths:
        pytest.skip("../shared/data/probes is absent")
    return paths
