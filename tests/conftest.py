import pytest

from lmap_drake.scenario import LoadDefaultScenario


@pytest.fixture
def scenario():
    """The built-in default scenario (a fresh copy per test)."""
    return LoadDefaultScenario()
