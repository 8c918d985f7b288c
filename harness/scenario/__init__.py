"""Logical scenarios, system profiles, search spaces, concrete scenarios and world specs."""
