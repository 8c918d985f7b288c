"""Search: the problem adapter the optimizers see, the optimizer adapters, termination objects."""

# Candidates BO and random search ask for at once (NSGA-II and SMPSO ask for a generation). A
# campaign setting, not the executor's worker count, so that a seed flies the same candidates on
# every executor and machine.
DEFAULT_BATCH = 4
