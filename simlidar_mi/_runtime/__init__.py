"""How a run runs, not what it computes: libLLVM and Mitsuba loading, signals, progress, forked
writers and Dask clusters.  Private: the workflows use these; users never need to."""
