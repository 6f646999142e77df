"""The bootstrap part of a grid configuration: ``bootstrap`` (resamples, 0 = none), ``seed`` and ``reference``
(the method of the paired tests). :func:`bootstrap_settings` appends its problems to ``problems`` (all reported
together by :func:`vpr_uncertainty.study.load_config`)."""

from __future__ import annotations

from typing import Any

__all__ = ["bootstrap_settings"]


def _count(data: dict[str, Any], key: str, problems: list[str]) -> int:
    value = data.get(key, 0)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        problems.append(f"{key} must be an integer >= 0, got {value!r}")
        return 0
    return value


def bootstrap_settings(data: dict[str, Any], methods: list[str], problems: list[str]) -> tuple[int, int, str | None]:
    """``(bootstrap, seed, reference)`` of the config; a reference must be one of the grid's methods."""
    bootstrap, seed = _count(data, "bootstrap", problems), _count(data, "seed", problems)
    reference = data.get("reference")
    if reference is not None:
        if not isinstance(reference, str):
            problems.append(f"reference must be a method name, got {reference!r}")
            reference = None
        elif methods and reference not in methods:
            problems.append(
                f"reference {reference!r} (the method of the paired tests) is not among methods ({', '.join(methods)})"
            )
    return bootstrap, seed, reference
