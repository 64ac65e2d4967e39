"""Training a model file from the historian: chunked fits and time-ordered validation
(``chunked``), the jobs behind ``diag train`` and ``diag experiments`` (``jobs``), the Dask
scale-out (``dask_engine``) and the commands (``cli``)."""
