"""The live plug-in: the loop that polls, stores, diagnoses and publishes once per cycle
(``loop``), ``plant.toml`` (``config``) and ``diag run`` (``cli``)."""
