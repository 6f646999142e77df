"""Progress bars on stderr, shown when the call says so (``enabled``), else when the process default says so
(:func:`progress_default`: ``--progress`` / ``--no-progress``), else when stderr is a terminal.

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

    ``iterable`` None: a bar updated by hand. ``enabled`` None: decided by :func:`progress_enabled`. ``initial``:
    items already done (a resumed stage). ``leave``: keep the finished bar on screen.
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
