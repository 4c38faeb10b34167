"""Shared fixtures. Real data lives in ../shared/data (or $IBR_SHARED_DATA); tests that use it
skip with a reason when it is absent (a user's fresh clone has no ../shared)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data() -> Path:
    return Path(os.environ.get("IBR_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def data_dir():
    d = shared_data()
    if not d.is_dir():
        pytest.skip(f"real test data not found at {d} (set IBR_SHARED_DATA)")
    return d


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
