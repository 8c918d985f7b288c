"""One evaluation: a concrete scenario flown end to end and scored from its recording (the
port block, the bridge's control channel, the MAVSDK session, the API tap, the log merge)."""
