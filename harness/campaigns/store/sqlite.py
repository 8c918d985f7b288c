"""The campaign store: one SQLite file (WAL) per campaign; every evaluation committed as it finishes.

A killed campaign resumes by replaying its searches with the same seeds: every candidate the
search asks for again is found here by its exact vector and answered from the row, so nothing
finished is lost and nothing is flown twice.
"""

from __future__ import annotations

import json
import sqlite3
import time
from contextlib import closing
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Sequence

import numpy as np

from harness.campaigns.store.rows import StoredEvaluation, StoredRun, vector_key
from harness.campaigns.store.screen_tables import SCREEN_SCHEMA, ScreenTables
from harness.errors import InputError, Problem
from harness.flight.differential import Reveal
from harness.flight.fitness import Status

if TYPE_CHECKING:
    from harness.flight.results import EvaluationResult

SCHEMA = """
CREATE TABLE IF NOT EXISTS campaigns (
    id INTEGER PRIMARY KEY,
    created REAL NOT NULL,
    config TEXT NOT NULL UNIQUE,
    sources TEXT
);
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    scenario_file TEXT NOT NULL,
    scenario TEXT NOT NULL,
    algorithm TEXT NOT NULL,
    run_index INTEGER NOT NULL,
    seed INTEGER NOT NULL,
    finished REAL,
    scenario_key TEXT,
    UNIQUE (campaign_id, scenario_file, algorithm, run_index)
);
CREATE TABLE IF NOT EXISTS evaluations (
    id INTEGER PRIMARY KEY,
    run_id INTEGER NOT NULL REFERENCES runs(id),
    ordinal INTEGER NOT NULL,
    step INTEGER NOT NULL,
    optimizer TEXT NOT NULL,
    vector TEXT NOT NULL,
    vector_key TEXT NOT NULL,
    concrete TEXT,
    fitness REAL NOT NULL,
    status TEXT NOT NULL,
    why TEXT,
    min_clearance_m REAL,
    sim_time_s REAL,
    wall_time_s REAL,
    log_path TEXT,
    seed INTEGER NOT NULL,
    created REAL NOT NULL,
    attempts TEXT,
    confirmations TEXT,
    reveals TEXT,
    differential TEXT,
    failures_refused TEXT,
    properties TEXT,
    coverage TEXT,
    UNIQUE (run_id, vector_key),
    UNIQUE (run_id, ordinal)
);
CREATE TABLE IF NOT EXISTS evaluation_ids (
    last_given INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS checkpoints (
    run_id INTEGER NOT NULL REFERENCES runs(id),
    step INTEGER NOT NULL,
    state TEXT NOT NULL,
    created REAL NOT NULL,
    PRIMARY KEY (run_id, step)
);
"""


# An evaluation with its run's scenario, algorithm and index: what every reader of evaluations
# selects (the order of _evaluation's arguments), each with its own WHERE and ORDER BY.
_SELECT = (
    "SELECT e.id, e.run_id, e.ordinal, e.vector, e.vector_key, e.fitness, e.status, e.log_path, e.seed, e.why, e.min_clearance_m, e.sim_time_s,"
    " e.wall_time_s, e.created, {concrete}, e.confirmations, e.reveals, {differential}, e.properties, e.coverage, r.scenario, r.scenario_file,"
    " r.algorithm, r.run_index"
    " FROM evaluations e JOIN runs r ON r.id = e.run_id"
)
EVALUATIONS = _SELECT.format(concrete="e.concrete", differential="e.differential")
# What a resumed run answers from: the outcomes without the concrete scenarios and the pairs
# (about 30 KB an evaluation), which it never reads.
OUTCOMES = _SELECT.format(concrete="NULL", differential="NULL")


# What a run's search minimised, per evaluation: the least robustness of its safety properties
# where the campaign scored them (harness/campaigns/problem.py: objective_of), else its fitness.
SEARCHED = "COALESCE((SELECT MIN(json_extract(p.value, '$.robustness')) FROM json_each(e.properties) p), e.fitness)"


def _json(text: str | None) -> Any:
    return json.loads(text) if text is not None else None


def _evaluation(id, run_id, ordinal, vector, key, fitness, status, log_path, seed, why, min_clearance_m, sim_time_s, wall_time_s, created,
                concrete, confirmations, reveals, differential, properties, coverage, scenario, scenario_file, algorithm, run_index) -> StoredEvaluation:
    return StoredEvaluation(id, run_id, ordinal, np.array(json.loads(vector)), key, fitness, Status(status), log_path, seed, why, min_clearance_m,
                            sim_time_s, wall_time_s, created, _json(concrete), _json(confirmations), Reveal(reveals) if reveals else None,
                            _json(differential), scenario, scenario_file, algorithm, run_index, _json(properties) or {}, _json(coverage))


class Store(ScreenTables):
    @classmethod
    def existing(cls, path: Path) -> "Store":
        """A campaign's store as it is (to compare, report, export, judge again): the file must
        be a campaign store, and is never turned into one."""
        return cls(cls._a_store(path))

    @classmethod
    def read_only(cls, path: Path) -> "Store":
        """A campaign's store to read and never write (another campaign's, perhaps on a read-only
        mount or another user's): as it is, without the tables and columns of later versions."""
        store = cls.__new__(cls)
        store.path = cls._a_store(path)
        store.db = sqlite3.connect(f"file:{store.path}?mode=ro", uri=True, timeout=30.0)
        return store

    @classmethod
    def _a_store(cls, path: Path) -> Path:
        path = Path(path)
        if not path.is_file():
            raise InputError([Problem(str(path), "", "no such campaign store: give the --store file of a `stella campaign`")])
        cls._check_is_a_store(path)
        return path

    @classmethod
    def for_campaign(cls, path: Path) -> "Store":
        """A store to write: a new file, or a campaign store to resume. Any other file is refused
        rather than turned into a store."""
        path = Path(path)
        if path.exists() and not path.is_file():
            raise InputError([Problem(str(path), "", "is not a file: give --store a file name such as runs/campaign.db")])
        if path.is_file() and path.stat().st_size > 0:
            cls._check_is_a_store(path)
        try:
            return cls(path)
        except (OSError, sqlite3.OperationalError) as error:
            raise InputError([Problem(str(path), "", f"cannot create a campaign store here ({error}): give --store a path in a writable folder")]) from None

    @staticmethod
    def _check_is_a_store(path: Path) -> None:
        try:
            with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as probe:
                tables = {row[0] for row in probe.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        except sqlite3.DatabaseError as error:
            raise InputError([Problem(str(path), "", f"not a campaign store ({error}): give the --store file of a `stella campaign`")]) from None
        if not {"campaigns", "runs", "evaluations"} <= tables:
            raise InputError([Problem(str(path), "", "an SQLite file, but not a campaign store (no campaigns, runs and evaluations tables)")])

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(self.path, timeout=30.0)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.executescript(SCHEMA + SCREEN_SCHEMA)
        columns = {row[1] for row in self.db.execute("PRAGMA table_info(evaluations)")}
        if "attempts" not in columns:  # a store written before tries were recorded
            self.db.execute("ALTER TABLE evaluations ADD COLUMN attempts TEXT")
        if "confirmations" not in columns:  # ... or before violations were re-flown (--confirm)
            self.db.execute("ALTER TABLE evaluations ADD COLUMN confirmations TEXT")
        if "differential" not in columns:  # ... or before flights were paired with a reference
            self.db.execute("ALTER TABLE evaluations ADD COLUMN reveals TEXT")
            self.db.execute("ALTER TABLE evaluations ADD COLUMN differential TEXT")
        if "failures_refused" not in columns:  # ... or before failure injections the SUT refused were kept
            self.db.execute("ALTER TABLE evaluations ADD COLUMN failures_refused TEXT")
        if "properties" not in columns:  # ... or before safety properties were scored
            self.db.execute("ALTER TABLE evaluations ADD COLUMN properties TEXT")
        if "coverage" not in columns:  # ... or before coverage builds recorded their flights' coverage
            self.db.execute("ALTER TABLE evaluations ADD COLUMN coverage TEXT")
        # Stores from before campaigns and runs were known by the content of their documents.
        if "sources" not in {row[1] for row in self.db.execute("PRAGMA table_info(campaigns)")}:
            self.db.execute("ALTER TABLE campaigns ADD COLUMN sources TEXT")
        if "scenario_key" not in {row[1] for row in self.db.execute("PRAGMA table_info(runs)")}:
            self.db.execute("ALTER TABLE runs ADD COLUMN scenario_key TEXT")
        if "predicted_mean" not in {row[1] for row in self.db.execute("PRAGMA table_info(screen_flights)")}:  # screened before the correction
            self.db.execute("ALTER TABLE screen_flights ADD COLUMN predicted_mean REAL")
            self.db.execute("ALTER TABLE screen_flights ADD COLUMN predicted_sd REAL")
        if "ranked_by_cheap" not in {row[1] for row in self.db.execute("PRAGMA table_info(screen_flights)")}:  # ... or before it chose between the two
            self.db.execute("ALTER TABLE screen_flights ADD COLUMN ranked_by_cheap INTEGER")
        self.db.commit()

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # -- campaigns and runs --------------------------------------------------------------------

    def campaign(self, config: Mapping[str, Any], *, legacy: Sequence[Mapping[str, Any]] = (), sources: Mapping[str, Any] | None = None) -> int:
        """The campaign with exactly this configuration; a store holds one campaign. A store made
        with one of its `legacy` configurations (as identities were made before) is that
        campaign: it is re-keyed by `config` from now on, so a copy of it resumes anywhere.
        `sources` (where its files lie) is kept as information."""
        text = json.dumps(config, sort_keys=True)
        row = self.db.execute("SELECT id FROM campaigns WHERE config = ?", (text,)).fetchone()
        if row:
            return row[0]
        for old in legacy:
            row = self.db.execute("SELECT id FROM campaigns WHERE config = ?", (json.dumps(old, sort_keys=True),)).fetchone()
            if row:
                with self.db:
                    self.db.execute("UPDATE campaigns SET config = ?, sources = ? WHERE id = ?", (text, json.dumps(sources), row[0]))
                return row[0]
        other = self.db.execute("SELECT config FROM campaigns").fetchone()
        if other:
            raise InputError([Problem(str(self.path), "", "this store holds a different campaign (other scenarios, algorithms, budget, runs, seed or SUT build); "
                                      "resume it with the same arguments or use a new --store")])
        with self.db:
            return self.db.execute("INSERT INTO campaigns (created, config, sources) VALUES (?, ?, ?)",
                                   (time.time(), text, json.dumps(sources) if sources is not None else None)).lastrowid

    def run(self, campaign_id: int, scenario_file: str, scenario: str, algorithm: str, run_index: int, seed: int, *,
            scenario_key: str | None = None) -> tuple[int, bool]:
        """(run id, already finished). A run is found by its scenario's content (`scenario_key`)
        where given, the file it was read from (`scenario_file`) being information; a run made
        before runs were keyed so is found by its file and keyed from now on."""
        select = "SELECT id, finished FROM runs WHERE campaign_id = ? AND algorithm = ? AND run_index = ?"
        row = None
        if scenario_key is not None:
            row = self.db.execute(f"{select} AND scenario_key = ?", (campaign_id, algorithm, run_index, scenario_key)).fetchone()
        if row is None:
            row = self.db.execute(f"{select} AND scenario_file = ? AND scenario_key IS NULL", (campaign_id, algorithm, run_index, scenario_file)).fetchone()
            if row is not None and scenario_key is not None:
                with self.db:
                    self.db.execute("UPDATE runs SET scenario_key = ? WHERE id = ?", (scenario_key, row[0]))
        if row:
            return row[0], row[1] is not None
        with self.db:
            cursor = self.db.execute(
                "INSERT INTO runs (campaign_id, scenario_file, scenario, algorithm, run_index, seed, scenario_key) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (campaign_id, scenario_file, scenario, algorithm, run_index, seed, scenario_key),
            )
        return cursor.lastrowid, False

    def finish_run(self, run_id: int) -> None:
        with self.db:
            self.db.execute("UPDATE runs SET finished = ? WHERE id = ?", (time.time(), run_id))

    # -- evaluations ---------------------------------------------------------------------------

    def evaluations(self, run_id: int) -> dict[str, StoredEvaluation]:
        """A run's evaluations by their vector's key, what a resumed run answers from: their
        outcomes, without concrete scenarios and pairs (None). A resumed campaign that kept them
        grew by 93 MB for 3,135 evaluations."""
        return {row.vector_key: row for row in (_evaluation(*r) for r in self.db.execute(f"{OUTCOMES} WHERE e.run_id = ?", (run_id,)))}

    def new_evaluation_id(self) -> int:
        """The id an evaluation about to fly will be stored under, so that its log can be named by
        it (`evaluation_name`). Given out once per store, in a transaction of the file: never
        again after a campaign killed in flight (whose log of that name may lie on disk), nor
        to another writer of the same file."""
        self.db.execute("BEGIN IMMEDIATE")
        try:
            given = self.db.execute("SELECT MAX(COALESCE((SELECT MAX(id) FROM evaluations), 0), COALESCE((SELECT MAX(last_given) FROM evaluation_ids), 0)) + 1").fetchone()[0]
            self.db.execute("DELETE FROM evaluation_ids")
            self.db.execute("INSERT INTO evaluation_ids (last_given) VALUES (?)", (given,))
            self.db.commit()
        except BaseException:
            self.db.rollback()
            raise
        return given

    def add_evaluation(self, run_id: int, *, ordinal: int, step: int, optimizer: str, vector: np.ndarray, result: EvaluationResult,
                       concrete: Mapping[str, Any] | None, evaluation_id: int | None = None) -> None:
        """Store an evaluation under `evaluation_id` (from new_evaluation_id), or the next free id."""
        with self.db:
            self.db.execute(
                "INSERT INTO evaluations (id, run_id, ordinal, step, optimizer, vector, vector_key, concrete, fitness, status, why, min_clearance_m, sim_time_s, wall_time_s, log_path, seed, created, attempts, confirmations,"
                " reveals, differential, failures_refused, properties, coverage) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    evaluation_id, run_id, ordinal, step, optimizer, json.dumps(np.asarray(vector).tolist()), vector_key(vector),
                    json.dumps(concrete) if concrete is not None else None, result.fitness, str(result.status), result.why,
                    result.min_clearance_m, result.sim_time_s, result.wall_time_s, result.log_path, result.seed, time.time(),
                    json.dumps(result.attempts) if result.attempts else None,
                    json.dumps(result.confirmations) if result.confirmations else None,
                    result.differential["reveals"] if result.differential else None,
                    json.dumps(result.differential) if result.differential else None,
                    json.dumps(result.failures_refused) if result.failures_refused else None,
                    json.dumps(result.properties) if result.properties else None,
                    json.dumps(result.coverage) if result.coverage else None,
                ),
            )

    def rejudge(self, evaluation_id: int, differential: Mapping[str, Any]) -> None:
        """Replace a pair's verdict and flights (harness/campaigns/rejudge.py)."""
        with self.db:
            self.db.execute("UPDATE evaluations SET reveals = ?, differential = ? WHERE id = ?",
                            (differential["reveals"], json.dumps(differential), evaluation_id))

    def checkpoint(self, run_id: int, step: int, state: Mapping[str, Any]) -> None:
        with self.db:
            self.db.execute("INSERT OR REPLACE INTO checkpoints (run_id, step, state, created) VALUES (?, ?, ?, ?)", (run_id, step, json.dumps(state), time.time()))

    # -- reading -------------------------------------------------------------------------------

    def _evaluations(self, where: str, parameters: Iterable[Any] = ()) -> list[StoredEvaluation]:
        return [_evaluation(*row) for row in self.db.execute(f"{EVALUATIONS} {where}", tuple(parameters))]

    def all_evaluations(self) -> list[StoredEvaluation]:
        return self._evaluations("ORDER BY r.id, e.ordinal")

    def evaluations_with(self, status: Status) -> list[StoredEvaluation]:
        """Every evaluation that ended so, by run and ordinal."""
        return self._evaluations("WHERE e.status = ? ORDER BY r.id, e.ordinal", (str(status),))

    def lowest(self, count: int, *, logged: bool = False) -> list[StoredEvaluation]:
        """The count lowest-fitness evaluations (logged: of those whose log was kept)."""
        return self._evaluations(f"{'WHERE e.log_path IS NOT NULL' if logged else ''} ORDER BY e.fitness LIMIT ?", (count,))

    def evaluation_logged_as(self, file_name: str) -> StoredEvaluation | None:
        """The evaluation whose log has this file name, wherever its folder now lies."""
        for evaluation_id, log_path in self.db.execute("SELECT id, log_path FROM evaluations WHERE log_path IS NOT NULL"):
            if Path(log_path).name == file_name:
                return self.evaluation(evaluation_id)
        return None

    def evaluation(self, evaluation_id: int) -> StoredEvaluation | None:
        found = self._evaluations("WHERE e.id = ?", (evaluation_id,))
        return found[0] if found else None

    def runs(self) -> list[StoredRun]:
        query = (
            "SELECT r.id, r.scenario_file, r.scenario, r.algorithm, r.run_index, r.seed, r.finished,"
            f" MIN({SEARCHED}), COUNT(e.id), COALESCE(SUM(e.status = :violation), 0), COALESCE(SUM(e.status = :violation AND e.min_clearance_m <= 0), 0),"
            " COALESCE(SUM(e.status = :violation AND json_extract(e.confirmations, '$.violations') < json_extract(e.confirmations, '$.repeats')), 0),"
            " COALESCE(SUM(e.failures_refused IS NOT NULL), 0), COALESCE(SUM(e.reveals IS NOT NULL), 0), COALESCE(SUM(e.reveals = :unsafe), 0),"
            " MIN(CASE WHEN e.reveals IS NOT NULL THEN e.ordinal END), MIN(e.created), MAX(e.created),"
            " COALESCE(SUM(e.status != :infeasible), 0), (SELECT COUNT(*) FROM screen_flights s WHERE s.run_id = r.id)"
            " FROM runs r LEFT JOIN evaluations e ON e.run_id = r.id GROUP BY r.id ORDER BY r.id"
        )
        return [StoredRun(*row) for row in self.db.execute(query, {"violation": str(Status.VIOLATION), "unsafe": str(Reveal.UNSAFE),
                                                                   "infeasible": str(Status.INFEASIBLE)})]

    def campaign_sut(self) -> dict[str, Any]:
        """The SUT the store's campaign flew (stores from before it was recorded flew the bundled one)."""
        row = self.db.execute("SELECT config FROM campaigns").fetchone()
        config = json.loads(row[0]) if row else {}
        return {"name": config.get("sut", "bundled"), "params": config.get("sut_params", {}),
                **({"fault": config["sut_fault"]} if config.get("sut_fault") else {})}

    def campaign_config(self) -> dict[str, Any]:
        """The campaign's identity as stored: scenarios, algorithms, budget, SUT, reference, ..."""
        row = self.db.execute("SELECT config FROM campaigns").fetchone()
        return json.loads(row[0]) if row else {}

    def campaign_sources(self) -> dict[str, Any]:
        """Where the campaign's documents and SUT build lay when it began (information, not identity)."""
        row = self.db.execute("SELECT sources FROM campaigns").fetchone()
        return json.loads(row[0]) if row and row[0] else {}

    def is_differential(self) -> bool:
        """Whether the campaign flew every candidate against a reference SUT too."""
        row = self.db.execute("SELECT config FROM campaigns").fetchone()
        return bool(row) and "reference" in json.loads(row[0])

    def worst_cases(self, threshold: float, worst_per_run: int) -> list[StoredEvaluation]:
        """Flown evaluations with fitness below threshold, plus each run's worst_per_run lowest, lowest first."""
        ranked = (
            "SELECT id, fitness, ROW_NUMBER() OVER (PARTITION BY run_id ORDER BY fitness, ordinal) AS rank FROM evaluations WHERE status != ?"
        )
        return self._evaluations(f"JOIN ({ranked}) ranked ON ranked.id = e.id WHERE ranked.fitness < ? OR ranked.rank <= ?"
                                 " ORDER BY e.fitness, r.scenario_file, r.algorithm, r.run_index, e.ordinal",
                                 (str(Status.INFEASIBLE), threshold, worst_per_run))

    def first_reveals(self) -> dict[str, Any]:
        """A differential campaign's single run: the evaluations (1-based) to its first revealing
        candidate and to its first unsafe one, that first one's level, and the evaluations spent."""
        first = self.db.execute("SELECT ordinal, reveals FROM evaluations WHERE reveals IS NOT NULL ORDER BY ordinal LIMIT 1").fetchone()
        unsafe = self.db.execute("SELECT MIN(ordinal) FROM evaluations WHERE reveals = ?", (str(Reveal.UNSAFE),)).fetchone()[0]
        spent = self.db.execute("SELECT COUNT(*) FROM evaluations").fetchone()[0]
        return {"evaluation": first[0] + 1 if first else None, "level": first[1] if first else None,
                "first_unsafe": unsafe + 1 if unsafe is not None else None, "budget": spent}

    def pairs(self) -> list[StoredEvaluation]:
        """Every evaluation flown against a reference, by run and ordinal."""
        return self._evaluations("WHERE e.differential IS NOT NULL ORDER BY r.id, e.ordinal")

    def revealing_cases(self) -> list[StoredEvaluation]:
        """Every revealing evaluation, unsafe ones first, then by fitness."""
        return self._evaluations("WHERE e.reveals IS NOT NULL ORDER BY e.reveals != ?, e.fitness, r.id, e.ordinal", (str(Reveal.UNSAFE),))

    def failures_refused(self, run_id: int) -> int:
        """How many of a run's flights the SUT refused a failure injection in."""
        return self.db.execute("SELECT COUNT(*) FROM evaluations WHERE run_id = ? AND failures_refused IS NOT NULL", (run_id,)).fetchone()[0]

    def best_so_far(self, run_id: int) -> list[tuple[int, float]]:
        """(ordinal, best fitness up to it) for a convergence curve."""
        best, curve = float("inf"), []
        for ordinal, fitness in self.db.execute("SELECT ordinal, fitness FROM evaluations WHERE run_id = ? ORDER BY ordinal", (run_id,)):
            best = min(best, fitness)
            curve.append((ordinal, best))
        return curve
