"""The shipped examples: how the rule bases and the example unit in ``rulebases/`` are made
(``build``), the real DAMADICS hour (``damadics``) and ``diag demo`` (``demo``)."""
