"""Sample quality codes.

Stored as a small integer, the severity of an OPC UA StatusCode:

====  ==========  ==================================================
code  name        meaning
====  ==========  ==================================================
0     GOOD        value can be used
1     UNCERTAIN   value kept, but flagged (e.g. sensor near limits)
2     BAD         value is not usable; aligned frames show NaN
====  ==========  ==================================================

:func:`from_opcua_status` maps a full 32-bit OPC UA StatusCode (severity in bits 31–30:
00 good, 01 uncertain, 10/11 bad) to these codes.
"""

from __future__ import annotations

GOOD = 0
UNCERTAIN = 1
BAD = 2

NAMES = {GOOD: "good", UNCERTAIN: "uncertain", BAD: "bad"}


def from_opcua_status(status: int) -> int:
    """OPC UA StatusCode (uint32) → quality code 0/1/2 from its severity bits."""
    sev = (int(status) >> 30) & 0b11
    return GOOD if sev == 0 else UNCERTAIN if sev == 1 else BAD
