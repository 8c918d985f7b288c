"""Safety properties beyond clearance: STL specifications over a flight's signals (issue 58)."""
