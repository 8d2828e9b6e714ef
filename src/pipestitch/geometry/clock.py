"""Clock positions of wall angles: 12 = crown, 3 = right, 6 = invert, 9 = left.

Clockwise as seen looking in the direction of survey (+z). In a pipe frame whose +y
points down (gravity), theta = atan2(y, x) grows from 3 o'clock (+x) towards 6 o'clock
(+y), i.e. clockwise for that viewer, and the crown is at theta = 270 deg. Where the
crown lies on a mosaic (its roll reference) is :mod:`pipestitch.standards.roll_reference`'s
business; these functions take it as a number.
"""

from __future__ import annotations

__all__ = ["CROWN_THETA_GRAVITY_DEG", "clock_hhmm", "clock_hour"]

CROWN_THETA_GRAVITY_DEG = 270.0   # crown in a pipe frame with +y down


def _clock_minutes(theta_deg: float, crown_theta_deg: float) -> float:
    return ((theta_deg - crown_theta_deg) % 360.0) / 360.0 * 720.0


def clock_hour(theta_deg: float, crown_theta_deg: float = CROWN_THETA_GRAVITY_DEG) -> int:
    """Clock position to the nearest hour, 1..12 (12 at ``crown_theta_deg``)."""
    hour = round(_clock_minutes(theta_deg, crown_theta_deg) / 60.0) % 12
    return hour or 12


def clock_hhmm(theta_deg: float, crown_theta_deg: float = CROWN_THETA_GRAVITY_DEG) -> str:
    """Clock position "H:MM" to 5 minutes (12 at ``crown_theta_deg``)."""
    minutes = round(_clock_minutes(theta_deg, crown_theta_deg) / 5) * 5 % 720
    hour, minute = divmod(int(minutes), 60)
    return f"{hour or 12}:{minute:02d}"
