"""The bundled autopilot's seeded faults put to use: witnesses flown both ways, and the
benchmark of how often a search reveals them."""
