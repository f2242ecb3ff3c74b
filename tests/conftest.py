import os
from pathlib import Path

import pytest

# The shared reference data sits beside the repository (../shared/data), as in CI.
SHARED = Path(os.environ.get("GPSINS_SHARED", Path(__file__).resolve().parents[2] / "shared"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip(f"reference data not found at {path} (set GPSINS_SHARED)")
    return path
