"""Where the project's data lives: `scenarios/` beside the packages, or STELLA_SCENARIOS."""

from __future__ import annotations

import os
from pathlib import Path


def project_root() -> Path:
    """The checkout the packages run from (an editable install, as make setup makes)."""
    return Path(__file__).resolve().parent.parent


def scenarios_dir() -> Path:
    override = os.environ.get("STELLA_SCENARIOS")
    if override:
        return Path(override)
    return project_root() / "scenarios"


def schema_path(name: str) -> Path:
    return scenarios_dir() / "schema" / f"{name}.schema.json"


def profile_path(name_or_path: str) -> Path:
    """A profile given by name (`default`) or by path to a JSON file."""
    candidate = Path(name_or_path)
    if candidate.suffix == ".json" or candidate.exists():
        return candidate
    return scenarios_dir() / "profiles" / f"{name_or_path}.json"
