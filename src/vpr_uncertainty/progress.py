"""Progress bars: one helper for every stage that can take more than a few seconds.

Bars go to stderr. Whether they are shown is decided once per call, in this order:

1. the ``enabled`` argument of the call, when it is True or False;
2. the process-wide default set with :func:`progress_default` (the command line's ``--progress`` /
   ``--no-progress``);
3. whether stderr is a terminal: a log file or a pipe gets no bar unless it is asked for.

Examples
--------
>>> from vpr_uncertainty.progress import progress_bar
>>> sum(progress_bar(range(3), desc="adding", enabled=False))
3
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = ["progress_bar", "progress_default", "progress_enabled", "progress_requested", "progress_status"]

T = TypeVar("T")

_DEFAULT: list[bool | None] = [None]


def progress_enabled(enabled: bool | None = None) -> bool:
    """Whether a bar is shown: ``enabled`` when given, else the process default, else whether stderr is a TTY."""
    if enabled is not None:
        return bool(enabled)
    if _DEFAULT[0] is not None:
        return bool(_DEFAULT[0])
    stream = sys.stderr
    try:
        return bool(stream is not None and stream.isatty())
    except (AttributeError, ValueError):  # a closed or replaced stream
        return False


def progress_requested() -> bool | None:
    """The process-wide default set by :func:`progress_default` (None: not set, the TTY test decides)."""
    return _DEFAULT[0]


@contextmanager
def progress_default(enabled: bool | None) -> Iterator[None]:
    """Within the block, bars whose call does not decide are shown (True), hidden (False) or left to the TTY test
    (None)."""
    previous = _DEFAULT[0]
    _DEFAULT[0] = None if enabled is None else bool(enabled)
    try:
        yield
    finally:
        _DEFAULT[0] = previous


def progress_bar(
    iterable: Iterable[T] | None = None,
    *,
    total: int | None = None,
    desc: str | None = None,
    unit: str = "it",
    enabled: bool | None = None,
    initial: int = 0,
    leave: bool = False,
) -> Any:
    """A tqdm bar on stderr (usable as an iterable wrapper or as a context manager with ``update``).

    Parameters
    ----------
    iterable : iterable, optional
        What to iterate over; None for a bar updated by hand.
    total : int, optional
        Number of items (default ``len(iterable)`` when it has one).
    desc, unit : str
        Label and unit of the bar.
    enabled : bool, optional
        Show the bar (True), hide it (False), or decide as :func:`progress_enabled` does (None).
    initial : int
        Items already done (a resumed stage).
    leave : bool
        Keep the finished bar on screen.
    """
    from tqdm import tqdm

    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        initial=initial,
        leave=leave,
        disable=not progress_enabled(enabled),
        file=sys.stderr,
        dynamic_ncols=True,
    )


@contextmanager
def progress_status(desc: str, *, enabled: bool | None = None, interval: float = 0.5) -> Iterator[None]:
    """A bar with no count for one long call (e.g. training a Faiss index): its elapsed time ticks every
    ``interval`` seconds until the block ends."""
    bar = progress_bar(total=None, desc=desc, unit="step", enabled=enabled)
    if bar.disable:
        with bar:
            yield
        return
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(interval):
            bar.refresh()

    ticker = threading.Thread(target=tick, name="progress-status", daemon=True)
    ticker.start()
    try:
        yield
        bar.update(1)
    finally:
        stop.set()
        ticker.join()
        bar.close()
