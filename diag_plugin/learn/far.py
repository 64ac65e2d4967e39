"""The false-alarm budget a user asks for (``--far``, alarms per hour): what may be asked."""

from __future__ import annotations

from historian.errors import UserError

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
