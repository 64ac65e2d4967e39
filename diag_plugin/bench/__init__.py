"""Detection benchmarks: the DAMADICS faults against a unit, and a unit built on a simulated
plant scored beside PCA and dynamic PCA at the same false-alarm budget (``diag benchmark``)."""
