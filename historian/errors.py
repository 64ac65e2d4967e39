"""User-facing errors shared by every package (``historian`` sits below ``diag_plugin``)."""

from __future__ import annotations


class UserError(Exception):
    """An error caused by input the user can fix; the CLI prints it without a traceback."""
