"""The last few values made for a key: what a gridded decomposition keeps
between calls on the same grid (layouts, outlines, stencil codes, the
critical points' geometry), so that the frames of a run with a fixed mask
pay for it once."""
from __future__ import annotations

__all__ = ["Recent"]


class Recent:
    """A dict of at most ``limit`` entries, the least recently used dropped
    first (:meth:`get` and :meth:`put` make an entry the most recent).  Safe
    against another thread trimming at the same time (it trims too)."""

    def __init__(self, limit: int):
        self.limit = int(limit)
        self._entries: dict = {}

    def get(self, key):
        """The value kept for ``key`` (now the most recent), or None."""
        value = self._entries.pop(key, None)
        if value is not None:
            self._entries[key] = value
        return value

    def put(self, key, value) -> None:
        """Keep ``value`` for ``key`` as the most recent entry."""
        self._entries.pop(key, None)
        self._entries[key] = value
        while len(self._entries) > self.limit:
            try:
                self._entries.pop(next(iter(self._entries)), None)
            except (RuntimeError, StopIteration):
                break

    def clear(self) -> None:
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)
