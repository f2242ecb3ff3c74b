import os
from pathlib import Path

import pytest

# Small public reference files live in the repository (tests/data, see its README).
TEST_DATA = Path(__file__).resolve().parent / "data"
# Large data sets stay outside: ../shared/data beside the clone, or GPSINS_SHARED.
SHARED = Path(os.environ.get("GPSINS_SHARED", Path(__file__).resolve().parents[2] / "shared"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The reference files every clone has."""
    return TEST_DATA


@pytest.fixture(scope="session")
def external_data() -> Path:
    """Large reference data sets outside the repository (skipped when absent)."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip(f"large reference data not found at {path} (set GPSINS_SHARED); see tests/data/README.md")
    return path
