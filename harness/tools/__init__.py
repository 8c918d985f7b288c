"""What users run: the command line, the campaign page, the pytest plugin, the benchmarks,
the log inspector and the SUT check."""
