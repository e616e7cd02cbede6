"""Shared helpers of the MPM tests."""

from __future__ import annotations


def set_at(scene: dict, path, value) -> dict:
    """``scene`` changed in place at ``path`` (table keys and array indices, outermost first):
    the entry set to ``value``, or removed when ``value`` is ``KeyError``; returns ``scene``."""
    *head, last = path
    holder = scene
    for part in head:
        holder = holder[part]
    if value is KeyError:
        del holder[last]
    else:
        holder[last] = value
    return scene
