"""A short ``repr`` for result dataclasses: arrays as their shape and dtype, numbers rounded, long values elided."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np


def describe_value(value: Any) -> str:
    """One short text for one field: an array as ``<(Q, K) float32>``, a float to 4 significant digits, a mapping or
    sequence by its size when it is long or holds arrays (else as is), a path or string as is (cut at 60 characters).

    Examples
    --------
    >>> describe_value(np.zeros((3, 2), np.float32)), describe_value(0.123456), describe_value({"a": np.zeros(2)})
    ('<(3, 2) float32>', '0.1235', '{1 entries}')
    >>> describe_value({"a": 1, "b": 2}), describe_value(list(range(9)))
    ("{'a': 1, 'b': 2}", '[9 items]')
    """
    shape = getattr(value, "shape", None)
    if shape is not None and not np.isscalar(value) and hasattr(value, "dtype"):
        kind = "sparse " if not isinstance(value, np.ndarray) else ""
        return f"<{kind}{tuple(shape)} {value.dtype}>"
    if isinstance(value, (bool, np.bool_)) or value is None:
        return repr(value)
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    if isinstance(value, (dict, list, tuple)) and len(value) > 4:
        return f"{{{len(value)} entries}}" if isinstance(value, dict) else f"[{len(value)} items]"
    if isinstance(value, dict):
        return f"{{{len(value)} entries}}" if any(hasattr(v, "shape") for v in value.values()) else _cut(repr(value))
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return f"{type(value).__name__}(...)"
    return _cut(repr(value) if not hasattr(value, "__fspath__") else repr(str(value)))


def _cut(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def compact_repr(self: Any) -> str:
    """``Name(field=value, ...)`` of a dataclass, each value by :func:`describe_value` (no array printed whole)."""
    parts = [
        f"{field.name}={describe_value(getattr(self, field.name))}"
        for field in dataclasses.fields(self)
        if field.repr and getattr(self, field.name) is not None
    ]
    return f"{type(self).__name__}({', '.join(parts)})"
