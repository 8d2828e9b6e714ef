"""Reviewed generated observations: an inspector's edit or deletion of an ``auto:`` row
supersedes that row on every later re-coding.

A generated row is named by its key (:func:`auto_key`): its ref, plus `` [A1]`` when it
is one row of a start/finish pair (both rows of a pair share one ref). An edited
generated row is stored with the ref ``reviewed:`` + its key without ``auto:``
(:func:`reviewed_ref`); a deleted one is listed by key under ``deleted_auto`` in
standards.json. Re-coding leaves out the generated rows so named
(:func:`without_superseded`); rows not starting ``auto:`` are still kept as written,
byte for byte.
"""

from __future__ import annotations

from collections.abc import Iterable

from pipestitch.standards.observations import AUTO_PREFIX, Observation

__all__ = ["DELETED_KEY", "REVIEWED_PREFIX", "auto_key", "deleted_keys", "replaced_key",
           "reviewed_ref", "without_superseded"]

REVIEWED_PREFIX = "reviewed:"
DELETED_KEY = "deleted_auto"      # standards.json: keys of generated rows deleted in review


def auto_key(o: Observation) -> str:
    """The key of a generated row: its ref, and its continuous marker when it has one."""
    return o.ref + (f" [{o.continuous}]" if o.continuous else "")


def reviewed_ref(o: Observation) -> str:
    """The ref the reviewed edit of the generated row ``o`` is stored with."""
    return REVIEWED_PREFIX + auto_key(o)[len(AUTO_PREFIX):]


def replaced_key(o: Observation) -> str | None:
    """The key of the generated row the reviewed row ``o`` replaces (None: not reviewed)."""
    if not o.ref.startswith(REVIEWED_PREFIX):
        return None
    return AUTO_PREFIX + o.ref[len(REVIEWED_PREFIX):]


def deleted_keys(state: dict) -> list[str]:
    """The keys of generated rows deleted in review, as standards.json (``state``) lists
    them; anything else there is ignored."""
    keys = state.get(DELETED_KEY)
    return sorted({k for k in keys if isinstance(k, str)}) if isinstance(keys, list) else []


def without_superseded(auto: Iterable[Observation], kept: Iterable[Observation],
                       deleted: Iterable[str] = ()) -> list[Observation]:
    """The generated rows ``auto`` less those a kept row replaces or ``deleted`` names.

    Parameters
    ----------
    auto : iterable of Observation
        The rows re-coding generated.
    kept : iterable of Observation
        The user's rows kept from the earlier observations.csv.
    deleted : iterable of str
        Keys (:func:`auto_key`) of generated rows deleted in review.
    """
    gone = {replaced_key(o) for o in kept} | set(deleted)
    return [o for o in auto if auto_key(o) not in gone]
