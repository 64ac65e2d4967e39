"""User-facing errors shared by every package (``historian`` sits below ``diag_plugin``)."""

from __future__ import annotations


class UserError(Exception):
    """An error caused by input the user can fix; the CLI prints it without a traceback."""


class ProblemsError(UserError):
    """A :class:`UserError` listing every problem found (``problems``, one a line), as a file's
    reader reports each ``file:line: what`` at once."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        super().__init__("\n".join(problems))
