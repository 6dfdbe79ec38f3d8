# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""What is computed from an immutable record, computed once per record.

The engine's state is immutable: a registration, once accepted, is the same object in every
later state until it is undone, moved to another frame or replaced. Whatever is drawn or said of
it -- its status entry, its markers, its TF frames -- is therefore the same every time the state
is published, and a session with many registrations would otherwise rebuild all of it for every
click. :class:`PerRecord` keeps one value per record, found by the record's identity (records
hold numpy arrays and are not hashable) and checked against the record itself, so a new record
that reuses a freed object's ``id`` is never given the old one's value.

:func:`per_object` is the other way round: values derived from a live object (a click's
context: its scene descriptors, its grids) that several callers ask for, kept while the object
lives and dropped with it.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Hashable, Iterable

__all__ = ["PerRecord", "per_object"]


class PerRecord:
    """``compute(record, *context)`` memoised per record and ``context`` (hashable: the frame,
    say): :meth:`values` returns one value per record and keeps only the values of the records
    it was last given, so what it holds is bounded by the current state. Thread-safe."""

    def __init__(self, compute: Callable):
        self._compute = compute
        self._held: dict[int, tuple] = {}  # id(record) -> (record, context, value)
        self._lock = threading.Lock()

    def values(self, records: Iterable, *context: Hashable) -> list:
        """``compute(record, *context)`` of each of ``records``, in order (computed for the
        records, or the context, not seen in the last call)."""
        records = list(records)
        with self._lock:
            held, kept = self._held, {}
            out = []
            for record in records:
                entry = held.get(id(record))
                if entry is None or entry[0] is not record or entry[1] != context:
                    entry = (record, context, self._compute(record, *context))
                kept[id(record)] = entry
                out.append(entry[2])
            self._held = kept
            return out


_object_lock = threading.Lock()
#: id(object) -> {what: value}, while the object lives (see :func:`per_object`)
_per_object: dict = {}


def per_object(obj, what: Hashable, compute: Callable):
    """``compute()`` once per live ``obj`` (weak-referenceable; it need not be hashable) and
    ``what``: later calls get the same value. The values go with the object (before its id can
    be reused); two threads may compute one twice, never see a half-built one."""
    key = id(obj)
    with _object_lock:
        memo = _per_object.get(key)
        if memo is None:
            memo = _per_object[key] = {}
            weakref.finalize(obj, _per_object.pop, key, None)
        hit = memo.get(what)
    if hit is not None:
        return hit
    value = compute()
    with _object_lock:
        return memo.setdefault(what, value)
