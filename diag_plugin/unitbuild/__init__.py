"""A unit from the plant's history: tests, inputs chosen on held-out error, models and
thresholds from a fault-free window (``diag unit build``)."""
