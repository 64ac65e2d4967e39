"""The seed-000 engine experiment (Laukonen et al., 1995): the whole FDI run (``fdi``), every
method on one model file's data (``method_compare``), the residual figures (``svgplot``) and
``diag engine-fdi`` / ``diag compare-methods`` (``cli``)."""
