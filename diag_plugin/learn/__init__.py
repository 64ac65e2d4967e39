"""Learning a unit's thresholds from a fault-free window: cross-fitted residuals held to a
false-alarm budget (``diag unit learn``)."""
