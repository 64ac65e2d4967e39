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


#: the most false alarms an hour a budget (``--far``) may ask for: one every 10 minutes, the
#: most an operator can handle (EEMUA 191, ISA-18.2); beyond it the thresholds fall to the
#: residuals' noise (``--far 1000`` at 15 s: limits of ±0.0001 % of span, every sample an alarm)
FAR_MAX = 6.0


def check_far(far: float) -> float:
    """``far`` (alarms per hour) when it is a budget: positive, finite, at most
    :data:`FAR_MAX`; otherwise a :class:`~historian.errors.UserError` saying so."""
    if not 0 < far <= FAR_MAX:
        raise UserError(
            f"--far {far:g}: the budget must be a positive rate per hour, at most {FAR_MAX:g} "
            "(an alarm every 10 minutes); e.g. 0.001, about one in six weeks"
        )
    return far
