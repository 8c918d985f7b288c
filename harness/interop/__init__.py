"""Other tools' formats: the UAV Testing Competition's tests and score, QGroundControl and
CSV parameter files."""
