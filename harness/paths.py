"""Where the project's data lives (`scenarios/` beside the packages, or STELLA_SCENARIOS), and
how a file the project writes is replaced whole."""

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


def write_atomically(path: Path, data: bytes) -> None:
    """path holds data, or what it held before: never a part (a killed run, a full disk). Its
    permissions stay (a source file put back in a user's tree)."""
    temporary = path.with_name(f".{path.name}.stella-tmp")
    temporary.write_bytes(data)
    os.chmod(temporary, path.stat().st_mode if path.exists() else 0o644)
    temporary.replace(path)
