"""Method specs as text: ``"SU, SUE:clip=one-sided,slope=300"`` split into specs, option values typed.

Used by :func:`vpr_uncertainty.methods.parse_method_spec`; no registry here.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["split_method_list", "typed_option"]

_TRUE, _FALSE = {"true", "yes", "1", "on"}, {"false", "no", "0", "off"}


def typed_option(text: str, default: Any, where: str) -> Any:
    """``text`` converted to the type of ``default`` (str when the default is None or a string)."""
    try:
        if isinstance(default, bool):
            if text.lower() not in _TRUE | _FALSE:
                raise ValueError
            return text.lower() in _TRUE
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float):
            value = float(text)
            if not math.isfinite(value):
                raise ValueError
            return value
    except ValueError:
        kind = {bool: "true or false", int: "an integer", float: "a finite number"}[type(default)]
        raise ValueError(f"{where} must be {kind}, got {text!r}") from None
    return text


def split_method_list(text: str) -> list[str]:
    """Split a comma-separated list of method specs; ``option=value`` items belong to the spec before them.

    Examples
    --------
    >>> split_method_list("SU, SUE:clip=one-sided,slope=300, BM")
    ['SU', 'SUE:clip=one-sided,slope=300', 'BM']
    """
    specs: list[str] = []
    for item in (part.strip() for part in text.split(",")):
        if not item:
            continue
        if "=" in item and ":" not in item.split("=", 1)[0]:
            if not specs or ":" not in specs[-1]:
                raise ValueError(f"option {item!r} follows no method spec (write NAME:{item})")
            specs[-1] += f",{item}"
        else:
            specs.append(item)
    return specs
