from __future__ import annotations

from pathlib import Path

import pytest

from harness.scenario.profile import Profile, load_profile

ROOT = Path(__file__).resolve().parent.parent
TABLE3 = sorted((ROOT / "scenarios" / "table3").glob("*.json"))


@pytest.fixture(scope="session")
def profile() -> Profile:
    return load_profile("default")
