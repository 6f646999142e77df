"""Argument types shared by the commands: each rejects bad values with a message argparse prints as is."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = ["candidate_count", "integer_at_least", "non_negative_float", "positive_int"]


def integer_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type accepting integers >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {text}")
        return value

    parse.__name__ = f"integer_at_least_{minimum}"
    return parse


#: Positive integers (batch sizes, epochs, k of a search).
positive_int = integer_at_least(1)
#: Candidates per query for RS/SD/SU: the best match and at least one runner-up.
candidate_count = integer_at_least(2)


def non_negative_float(text: str) -> float:
    """An argparse type accepting finite numbers >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 <= value < math.inf:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value
