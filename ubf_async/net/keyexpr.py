"""Key expressions, in pure Python: zenoh's rules for the parts ubf_async uses — chunks
separated by ``/``, ``*`` is exactly one chunk, ``**`` any number of chunks (none included), a
chunk starting with ``@`` is verbatim (matched only by itself). :func:`intersects` is zenoh's
``KeyExpr.intersects``; ``tests/test_transport_keyexpr.py`` checks it against zenoh's own.
Used by the in-process transport to route and by the bus to find its own subscriptions of a
key."""

from __future__ import annotations

import functools

from ubf_async.errors import KeyExprError

__all__ = ["intersects", "key_chunks"]


@functools.lru_cache(maxsize=4096)
def key_chunks(key_expr: str) -> tuple[str, ...]:
    """The chunks of ``key_expr``; :class:`KeyExprError` for one zenoh would refuse or that
    uses what this module does not implement (``$*`` sub-chunk wildcards)."""
    if not key_expr or key_expr.startswith("/") or key_expr.endswith("/"):
        raise KeyExprError(f"invalid key expression {key_expr!r}: empty, or a leading or "
                           f"trailing '/'")
    chunks = tuple(key_expr.split("/"))
    for i, chunk in enumerate(chunks):
        if not chunk:
            raise KeyExprError(f"invalid key expression {key_expr!r}: empty chunk")
        if any(c in chunk for c in "#?$"):
            raise KeyExprError(f"invalid key expression {key_expr!r}: '#', '?' and '$' are "
                               f"not supported")
        if "*" in chunk and chunk not in ("*", "**"):
            raise KeyExprError(f"invalid key expression {key_expr!r}: '*' must be a whole "
                               f"chunk")
        if chunk == "**" and i > 0 and chunks[i - 1] == "**":
            raise KeyExprError(f"invalid key expression {key_expr!r}: '**/**' is not "
                               f"canonical (write '**')")
        if chunk == "*" and i > 0 and chunks[i - 1] == "**":
            raise KeyExprError(f"invalid key expression {key_expr!r}: '**/*' is not "
                               f"canonical (write '*/**')")
    return chunks


def _chunk_meets(a: str, b: str) -> bool:
    if a == b:
        return True
    if a.startswith("@") or b.startswith("@"):
        return False  # a verbatim chunk only meets itself
    return a == "*" or b == "*"


@functools.lru_cache(maxsize=16384)
def intersects(a: str, b: str) -> bool:
    """Whether some concrete key matches both key expressions ``a`` and ``b`` (zenoh's
    ``KeyExpr.intersects``)."""
    left, right = key_chunks(a), key_chunks(b)

    @functools.cache
    def meet(i: int, j: int) -> bool:
        if i == len(left) and j == len(right):
            return True
        if i < len(left) and left[i] == "**":
            if meet(i + 1, j):
                return True
            return j < len(right) and not right[j].startswith("@") and meet(i, j + 1)
        if j < len(right) and right[j] == "**":
            if meet(i, j + 1):
                return True
            return i < len(left) and not left[i].startswith("@") and meet(i + 1, j)
        if i == len(left) or j == len(right):
            return False
        return _chunk_meets(left[i], right[j]) and meet(i + 1, j + 1)

    return meet(0, 0)
