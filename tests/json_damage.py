"""Damage to a JSON document for property tests of what users hand us in files (map documents,
world files): one place replaced by any JSON value, or one key dropped."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from hypothesis import strategies as st

#: Any JSON value, NaN and the infinities included (Python's json writes and reads them).
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(-1e6, 1e6) | st.floats(allow_nan=True)
    | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=4),
    max_leaves=8)


def places(node: Any, path: tuple = ()) -> Iterator[tuple[tuple, Any]]:
    """Every place in a JSON tree: (path of keys and indices, value); the root's path is ()."""
    yield path, node
    if isinstance(node, dict):
        for k, v in node.items():
            yield from places(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from places(v, (*path, i))


def damage(doc: Any, data: st.DataObject) -> tuple:
    """Damage ``doc`` in place at one place ``data`` draws: drop the key (half the time, when the
    place is a key) or replace the value by any JSON value. Returns the place's path."""
    path = data.draw(st.sampled_from([p for p, _ in places(doc) if p]))
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    if isinstance(parent, dict) and data.draw(st.booleans()):
        del parent[path[-1]]
    else:
        parent[path[-1]] = data.draw(JSON_VALUES)
    return path
