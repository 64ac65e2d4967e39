"""Rule-base files the plant expert edits: the TOML document with its byte-exact round trip,
locks and ``file:line`` checks (``document``), IEC 61131-7 FCL export (``fcl``) and
``diag rules`` (``cli``)."""
