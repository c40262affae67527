"""Per-layout caches of values derived from a layout alone, keyed by the layout object's identity and dropped with it.

By identity because hashing a Layout (a frozen dataclass of tuples) costs more than most of what is cached; the
entry holds a weak reference, so a layout that dies takes its entry with it and a later object given the same id
never reads a stale value.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import TypeVar

from neatskin.layout import Layout

T = TypeVar("T")

LayoutCache = dict[int, tuple["weakref.ref[Layout]", T]]


def per_layout(cache: LayoutCache[T], layout: Layout, build: Callable[[Layout], T]) -> T:
    """cache's value for this layout object, built by build(layout) on first use."""
    entry = cache.get(id(layout))
    if entry is not None and entry[0]() is layout:
        return entry[1]
    value = build(layout)
    key = id(layout)

    def forget(_ref: weakref.ref[Layout], key: int = key) -> None:
        cache.pop(key, None)

    cache[key] = (weakref.ref(layout, forget), value)
    return value
