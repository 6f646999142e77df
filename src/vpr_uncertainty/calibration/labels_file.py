"""The labels file: ``query,correct`` rows of a pool's queries, headed by the fingerprint of the pool they belong to.

Its first line names the pool: ``# vpr-uncertainty labels of pool 1a2b3c4d5e6f7a8b (POOL.npy: 111 queries, k=10)``,
where the 16 hex digits are :func:`pool_fingerprint` (the BLAKE2b of the pool's top-k scores as read, and k): a
file of another pool is refused, naming both. A file without that line (started by hand) is adopted: the line is
written on top of it. Then a ``query,correct`` header (optional), and one row per label: a pool index and 1/0,
true/false or yes/no (cells quoted or not). Blank lines and other ``#`` lines are skipped; columns after the second
are not read. The file is read as UTF-8, with or without a byte-order mark (as spreadsheets save it); a write keeps
every line the file held and appends, atomically (:func:`~vpr_uncertainty.cache.write_text`).
"""

from __future__ import annotations

import csv
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from vpr_uncertainty._files import is_regular_file, open_regular
from vpr_uncertainty.cache import array_digest, write_text

__all__ = [
    "LabelsFile",
    "MachineLabels",
    "pool_fingerprint",
    "read_labels",
    "read_machine_labels",
    "write_labels",
    "write_machine_labels",
]

_POOL = re.compile(r'^"?#\s*vpr-uncertainty labels of pool ([0-9a-f]{16})\b(.*)$')
_MACHINE = re.compile(r'^"?#\s*vpr-uncertainty machine labels of pool ([0-9a-f]{16})\b(.*)$')
_TRUTH = {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False}


class LabelsFile(NamedTuple):
    """A labels file as read: ``labels`` (query, correct) in file order, each query once; ``pool`` the fingerprint
    it carries (None: a new file, or one started by hand); ``text`` all it holds ("" when it does not exist)."""

    labels: list[tuple[int, bool]]
    pool: str | None
    text: str


def pool_fingerprint(scores: np.ndarray, k: int) -> str:
    """16 hex digits of the pool's top-k scores of shape (N, K) (their values as read, as float64) and of k."""
    top = np.ascontiguousarray(np.asarray(scores)[:, :k], dtype="<f8")
    return array_digest(np.asarray(k, dtype="<i8"), top)[:16]


def read_labels(path: str | os.PathLike, *, n_queries: int, pool: str, about: str = "") -> LabelsFile:
    """The labels of ``path`` (none when it does not exist), refused (a ValueError naming the file, and the line)
    when it is not text, a row is malformed, a query is labelled both ways, or it carries another pool than
    ``pool`` (``about``: what that pool is, for the message)."""
    path = Path(path)
    if not is_regular_file(path, "a labels file"):  # a folder fails at the write, naming it
        return LabelsFile([], None, "")
    with open_regular(path) as handle:
        data = handle.read()
    try:
        text = data.decode("utf-8-sig")
        if "\0" in text:
            raise UnicodeError("it holds NUL bytes")
    except UnicodeError as error:
        raise ValueError(f"{path}: not a labels file ({error}): expected UTF-8 text of query,correct rows") from None
    found: str | None = None
    labels: dict[int, bool] = {}
    lines: dict[int, int] = {}
    for line, content in enumerate(text.splitlines(), start=1):
        if content.strip().strip('"').startswith("#"):
            if _MACHINE.match(content.strip()):
                raise ValueError(
                    f"{path} holds machine labels (written by `label`): they may choose the cut, but only labels a "
                    "person gave certify it; pass it as --machine-labels, and label the queries asked for elsewhere"
                )
            if (match := _POOL.match(content.strip())) and match[1] != pool:
                described = match[2].strip().rstrip(',"').strip()
                raise ValueError(
                    f"{path} holds the labels of pool {match[1]} {described}, not of this pool {pool} ({about}): "
                    "label this pool in another file, or pass the pool these labels belong to"
                )
            found = match[1] if match else found
            continue
        cells = [cell.strip().strip('"').strip() for cell in content.split(",")]  # quoted by a spreadsheet or not
        query, correct = [*cells, "", ""][:2]
        if not any(cells) or (not labels and query.lower() == "query"):
            continue
        if not (query.isascii() and query.isdigit()) or len(query) > 18 or int(query) >= n_queries:
            raise ValueError(f"{path}, line {line}: query must be a pool index in [0, {n_queries}), got {query!r}")
        if correct.lower() not in _TRUTH:
            raise ValueError(f"{path}, line {line}: correct must be 1/0, true/false or yes/no, got {correct!r}")
        if labels.setdefault(int(query), _TRUTH[correct.lower()]) != _TRUTH[correct.lower()]:
            raise ValueError(f"{path}, line {line}: query {query} is labelled otherwise on line {lines[int(query)]}")
        lines.setdefault(int(query), line)
    return LabelsFile(list(labels.items()), found, text)


def write_labels(
    path: str | os.PathLike, read: LabelsFile, new: Sequence[tuple[int, bool]], *, pool: str, about: str = ""
) -> Path:
    """Write what ``read`` held (every line, the pool line on top when it had none) and the ``new`` labels after it,
    atomically; a file that would not change is left as it is."""
    text = (
        read.text if read.pool else f"# vpr-uncertainty labels of pool {pool} ({' '.join(about.split())})\n{read.text}"
    )
    if not read.text.strip():
        text += "query,correct\n"
    text += "\n" if not text.endswith("\n") else ""
    return write_text(path, text + "".join(f"{query},{int(correct)}\n" for query, correct in new), keep_unchanged=True)


class MachineLabels(NamedTuple):
    """The labels a machine gave every query of a pool: ``correct`` (N,) bool, ``confidence`` (N,) float64 (NaN
    where the labeler gives none) and ``sources`` (N,), the labeler and its options for each row."""

    correct: np.ndarray
    confidence: np.ndarray
    sources: list[str]


def write_machine_labels(path: str | os.PathLike, labels: MachineLabels, *, pool: str, about: str = "") -> Path:
    """Write ``labels`` as ``query,correct,confidence,source`` rows under the line ``# vpr-uncertainty machine labels
    of pool …``, atomically; :func:`read_labels` refuses such a file (machine labels never certify)."""
    rows = [
        f"{query},{int(correct)},{'' if np.isnan(confidence) else repr(float(confidence))},{_csv_cell(source)}\n"
        for query, (correct, confidence, source) in enumerate(zip(*labels, strict=True))
    ]
    header = f"# vpr-uncertainty machine labels of pool {pool} ({' '.join(about.split())})\n"
    header += "query,correct,confidence,source\n"
    return write_text(path, header + "".join(rows))


def read_machine_labels(path: str | os.PathLike, *, n_queries: int, pool: str, about: str = "") -> MachineLabels:
    """The machine labels of ``path``, one row per query of the pool ``pool`` (``about``: what it is); refused,
    naming the file and line, when it is of another pool, carries no pool line, or misses or repeats a query."""
    path = Path(path)
    with open_regular(path) as handle:
        text = handle.read().decode("utf-8-sig", errors="replace")
    lines = text.splitlines()
    match = _MACHINE.match(lines[0].strip()) if lines else None
    if match is None or match[1] != pool:
        found = f"the machine labels of pool {match[1]} {match[2].strip()}" if match else "no machine labels line"
        raise ValueError(f"{path} holds {found}, not the machine labels of this pool {pool} ({about}): run `label`")
    correct, confidence, sources = np.zeros(n_queries, bool), np.full(n_queries, np.nan), [""] * n_queries
    seen = np.zeros(n_queries, bool)
    for line, cells in enumerate(csv.reader(lines[2:]), start=3):
        query, flag, value, source = [*cells, "", "", "", ""][:4]
        good = query.isascii() and query.isdigit() and len(query) < 19 and int(query) < n_queries and flag in "01"
        try:
            number = float(value) if value else np.nan
        except ValueError:
            good = False
        if not good or not flag or seen[int(query)]:
            got = ",".join(cells[:3])
            raise ValueError(
                f"{path}, line {line}: expected a new query in [0, {n_queries}), 0/1 and a number, got {got!r}"
            )
        q = int(query)
        seen[q], correct[q], confidence[q], sources[q] = True, flag == "1", number, source
    if not seen.all():
        raise ValueError(f"{path}: no machine label for {int((~seen).sum())} queries, first {int(np.argmin(seen))}")
    return MachineLabels(correct, confidence, sources)


def _csv_cell(text: str) -> str:
    return f'"{text.replace(chr(34), chr(34) * 2)}"' if any(c in text for c in ',"\n') else text
