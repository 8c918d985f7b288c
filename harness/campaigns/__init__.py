"""Campaigns: searches over logical scenarios, their store, statistics, report, triage and
regression cases."""
