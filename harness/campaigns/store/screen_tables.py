"""A screened campaign's tables (harness/campaigns/screen.py): its cheap flights and the screen's
decisions on them, and the candidates flown both ways that it learned from other stores."""

from __future__ import annotations

import json
import sqlite3
import time
from typing import TYPE_CHECKING, Any, Mapping, Sequence

from harness.flight.fitness import COULD_NOT_FINISH, Status

if TYPE_CHECKING:
    from harness.flight.results import EvaluationResult

SCREEN_SCHEMA = """
CREATE TABLE IF NOT EXISTS screen_flights (
    run_id INTEGER NOT NULL REFERENCES runs(id),
    vector_key TEXT NOT NULL,
    fitness REAL NOT NULL,
    status TEXT NOT NULL,
    properties TEXT,
    log_path TEXT,
    chosen INTEGER,
    created REAL NOT NULL,
    predicted_mean REAL,
    predicted_sd REAL,
    ranked_by_cheap INTEGER,
    PRIMARY KEY (run_id, vector_key)
);
CREATE TABLE IF NOT EXISTS screen_imports (
    source TEXT NOT NULL,
    origin TEXT NOT NULL,
    scenario_key TEXT NOT NULL,
    vector_key TEXT NOT NULL,
    vector TEXT NOT NULL,
    cheap_fitness REAL NOT NULL,
    cheap_status TEXT NOT NULL,
    cheap_properties TEXT,
    fitness REAL NOT NULL,
    status TEXT NOT NULL,
    properties TEXT,
    PRIMARY KEY (origin, vector_key)
);
"""

# A candidate flown both ways, cheaply and for real to the end: what a correction learns from.
_FLOWN_BOTH_WAYS = (
    "SELECT r.id, s.vector_key, e.vector, s.fitness, s.status, s.properties, e.fitness, e.status, e.properties, r.scenario_key FROM runs r"
    " JOIN screen_flights s ON s.run_id = r.id JOIN evaluations e ON e.run_id = s.run_id AND e.vector_key = s.vector_key"
    f" WHERE e.status NOT IN ({', '.join(repr(str(status)) for status in sorted(COULD_NOT_FINISH | {Status.INFEASIBLE}))})"
)
_IMPORTED = ("SELECT origin, vector_key, vector, cheap_fitness, cheap_status, cheap_properties, fitness, status, properties, scenario_key"
             " FROM screen_imports")


def _json(text: str | None) -> Any:
    return json.loads(text) if text is not None else None


def _pair(origin, key, vector, cheap, cheap_status, cheap_properties, fitness, status, properties, scenario_key) -> dict[str, Any]:
    return {"origin": str(origin), "key": key, "vector": json.loads(vector), "cheap_fitness": cheap, "cheap_status": cheap_status,
            "cheap_properties": _json(cheap_properties) or {}, "fitness": fitness, "status": status, "properties": _json(properties) or {},
            "scenario_key": scenario_key}


class ScreenTables:
    """Mixed into Store: the queries of a screened campaign."""

    db: sqlite3.Connection

    def add_screen_flight(self, run_id: int, key: str, result: EvaluationResult) -> None:
        with self.db:
            self.db.execute("INSERT OR REPLACE INTO screen_flights (run_id, vector_key, fitness, status, properties, log_path, created) VALUES (?, ?, ?, ?, ?, ?, ?)",
                            (run_id, key, result.fitness, str(result.status), json.dumps(result.properties) if result.properties else None,
                             result.log_path, time.time()))

    def screen_decisions(self, run_id: int, chosen: Mapping[str, bool], predicted: Mapping[str, tuple[float, float]], ranked_by_cheap: bool = False) -> None:
        """Which cheaply flown candidates the screen chose for a real flight, what its correction
        predicted of them (mean and standard deviation, where one was trained) and whether it
        ranked them by the cheap flights all the same: kept, so that a resumed run decides as the
        first did and measures the correction alike."""
        with self.db:
            self.db.executemany("UPDATE screen_flights SET chosen = ?, predicted_mean = ?, predicted_sd = ?, ranked_by_cheap = ? WHERE run_id = ? AND vector_key = ?",
                                [(int(flag), *predicted.get(key, (None, None)), int(ranked_by_cheap), run_id, key) for key, flag in chosen.items()])

    def screen_flights(self, run_id: int) -> dict[str, dict[str, Any]]:
        """A run's cheap flights by their vector's key: fitness, status, properties, whether the
        screen chose it for a real flight (None: not decided yet) and what its correction
        predicted (mean and standard deviation; None: no correction trained)."""
        return {key: {"fitness": fitness, "status": status, "properties": _json(properties) or {}, "chosen": None if chosen is None else bool(chosen),
                      "predicted": None if mean is None else (mean, sd), "ranked_by_cheap": bool(by_cheap)}
                for key, fitness, status, properties, chosen, mean, sd, by_cheap in self.db.execute(
                    "SELECT vector_key, fitness, status, properties, chosen, predicted_mean, predicted_sd, ranked_by_cheap FROM screen_flights WHERE run_id = ?",
                    (run_id,))}

    def earlier_screen_pairs(self, run_id: int) -> list[dict[str, Any]]:
        """What the screen's correction of this run learns from before its own flights: the
        candidates flown both ways that were learned from other stores when the campaign began,
        and those of the store's runs of the same scenario before this one; each with its origin
        (the run's id, or for one learned, the other store and its run) and whether it was learned."""
        scenario = "(SELECT scenario_key FROM runs WHERE id = ?)"
        imported = self.db.execute(f"{_IMPORTED} WHERE scenario_key = {scenario} ORDER BY origin, vector_key", (run_id,))
        own = self.db.execute(f"{_FLOWN_BOTH_WAYS} AND r.scenario_key = {scenario} AND r.id < ? ORDER BY r.id, s.vector_key",
                              (run_id, run_id))
        return [{**_pair(*row), "learned": True} for row in imported] + [{**_pair(*row), "learned": False} for row in own]

    def flown_both_ways(self) -> list[dict[str, Any]]:
        """Every candidate the store's runs flew both ways, with its origin (the run's id) and its
        scenario's key: what another campaign's correction can learn from."""
        return [_pair(*row) for row in self.db.execute(f"{_FLOWN_BOTH_WAYS} ORDER BY r.id, s.vector_key")]

    def learn_screen_pairs(self, source: str, pairs: Sequence[Mapping[str, Any]]) -> None:
        """Keep another store's candidates flown both ways (flown_both_ways), as they are now, so
        that the campaign learns from the same pairs however often it is resumed and wherever the
        other store goes."""
        with self.db:
            self.db.executemany(
                "INSERT OR REPLACE INTO screen_imports (source, origin, scenario_key, vector_key, vector, cheap_fitness, cheap_status, cheap_properties,"
                " fitness, status, properties) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(source, f"{source}:{pair['origin']}", pair["scenario_key"], pair["key"], json.dumps(pair["vector"]), pair["cheap_fitness"],
                  pair["cheap_status"], json.dumps(pair["cheap_properties"]) if pair["cheap_properties"] else None, pair["fitness"], pair["status"],
                  json.dumps(pair["properties"]) if pair["properties"] else None) for pair in pairs])

    def screen_sources(self) -> dict[str, int]:
        """The stores learned from, each with how many candidates flown both ways it gave."""
        return dict(self.db.execute("SELECT source, COUNT(*) FROM screen_imports GROUP BY source ORDER BY source"))
