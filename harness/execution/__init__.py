"""Where evaluations run: executors (in this process, a local pool, Docker containers, a Dask
cluster) behind one contract, and the worker that flies one try."""
