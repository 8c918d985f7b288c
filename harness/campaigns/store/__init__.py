"""The campaign store, the only code that speaks SQL: one SQLite file (WAL) per campaign, its
rows handed out typed (rows.py), and the reference flights of differential campaigns."""

from harness.campaigns.store.reference_flights import ReferenceFlightTable
from harness.campaigns.store.rows import StoredEvaluation, StoredRun, evaluation_name, vector_key
from harness.campaigns.store.sqlite import Store

__all__ = ["ReferenceFlightTable", "Store", "StoredEvaluation", "StoredRun", "evaluation_name", "vector_key"]
