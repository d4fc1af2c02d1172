"""Shared fixtures. Fakes, where any are allowed, live here too."""

from __future__ import annotations

from pathlib import Path

import pytest

# ../shared/data beside the checkout (CI has it there; a user's clone may not).
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real test data folder; the test skips, naming the path, when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real test data not found at {SHARED_DATA}")
    return SHARED_DATA
