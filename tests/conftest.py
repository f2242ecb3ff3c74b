from pathlib import Path

import pytest

# Public reference files live in the repository (tests/data, see its README), so a clone
# alone runs every test.
TEST_DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The reference files every clone has."""
    return TEST_DATA
