"""Search: the problem adapter the optimizers see, the optimizer adapters, termination objects."""
