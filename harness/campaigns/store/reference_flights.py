"""Reference flights of differential campaigns by key (concrete scenario, seed, reference build):
a table in an SQLite file (a campaign's store, or one file shared by a mutation run's campaigns),
each flight list committed as it is flown."""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path
from typing import Any, Mapping, Sequence


class ReferenceFlightTable:
    def __init__(self, path: Path):
        self.db = sqlite3.connect(Path(path), timeout=30.0)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("CREATE TABLE IF NOT EXISTS reference_flights (key TEXT PRIMARY KEY, outcomes TEXT NOT NULL, created REAL NOT NULL)")
        self.db.commit()

    def get(self, key: str) -> list[dict[str, Any]]:
        """The flights kept under key, as their documents; none if not flown yet."""
        row = self.db.execute("SELECT outcomes FROM reference_flights WHERE key = ?", (key,)).fetchone()
        return json.loads(row[0]) if row else []

    def items(self) -> list[tuple[str, list[dict[str, Any]]]]:
        """Every key with its flights' documents."""
        return [(key, json.loads(outcomes)) for key, outcomes in self.db.execute("SELECT key, outcomes FROM reference_flights ORDER BY key")]

    def put(self, key: str, outcomes: Sequence[Mapping[str, Any]]) -> None:
        with self.db:
            self.db.execute("INSERT OR REPLACE INTO reference_flights (key, outcomes, created) VALUES (?, ?, ?)",
                            (key, json.dumps(list(outcomes)), time.time()))

    def close(self) -> None:
        self.db.close()
