"""The per-query table of ``evaluate --per-query`` read back: one row per query (``.csv``; ``.parquet`` with the pandas
extra), as a retrieval with the top-1 of each query and placeholders for the other candidates, so the score methods
give the original numbers and recall@N is known for N = 1 only. Columns and why: see docs/reference/file-formats.md.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.plugins import load_target
from vpr_uncertainty.retrieval.result import Retrieval, positives_from_lists

#: The first columns of a per-query table, before ``s_1``.
COLUMNS: tuple[str, ...] = ("query_index", "query", "top1_index", "top1", "answerable", "correct")
_SUFFIXES = (".csv", ".parquet")


def _header(path: Path) -> list[str]:
    if path.suffix.lower() == ".parquet":
        import pyarrow.parquet

        return list(pyarrow.parquet.read_schema(path).names)
    with path.open(encoding="utf-8-sig", newline="") as handle:
        return next(csv.reader([handle.readline()]), [])


def sniff(path: Path) -> bool:
    """Whether ``path`` is a ``.csv``/``.parquet`` file whose header starts with :data:`COLUMNS` and ``s_1``."""
    path = Path(path)
    if path.suffix.lower() not in _SUFFIXES or not is_regular_file(path, "a per-query table"):
        return False
    try:
        return tuple(_header(path)[: len(COLUMNS) + 1]) == (*COLUMNS, "s_1")
    except ImportError:  # no pyarrow to read the schema: the reader names what to install
        return True
    except (OSError, UnicodeDecodeError, ValueError):
        return False


def _unquoted(cell: Any) -> str:
    """A cell as written, less the quote a CSV writer puts before ``= + - @`` against formula injection."""
    text = str(cell).strip()
    return text[1:] if text[:1] == "'" and text[1:2] in ("=", "+", "-", "@", "\t", "\r") else text


def _table(path: Path) -> tuple[list[str], list[list[str]]]:
    if path.suffix.lower() == ".parquet":
        frame = load_target("pandas:read_parquet", what="a per-query .parquet table", extra="pandas")(path)
        return [str(name) for name in frame.columns], frame.astype(str).values.tolist()
    with path.open(encoding="utf-8-sig", newline="") as handle:
        rows = [row for row in csv.reader(handle) if row]
    return rows[0], rows[1:]


def read(path: Path, *, ground_truth: str | Path | None = None, **_: Any) -> Retrieval:
    """The retrieval a per-query table holds (docs/reference/file-formats.md); its ground truth is the table's own."""
    path = Path(path)
    if not is_regular_file(path, "a per-query table"):
        raise FileNotFoundError(f"per-query table not found: {path}")
    if ground_truth is not None:
        raise ValueError(f"{path} is a per-query table: its ground truth is its correct and answerable columns")
    header, rows = _table(path)
    if tuple(header[: len(COLUMNS)]) != COLUMNS or not rows:
        raise ValueError(f"{path}: expected a header {', '.join(COLUMNS)}, s_1, ..., s_K and one row per query")
    k = next((i for i, name in enumerate(header[len(COLUMNS) :]) if name != f"s_{i + 1}"), len(header) - len(COLUMNS))
    values = [[_unquoted(cell) for cell in row] for row in rows]
    try:
        scores = np.array([[float(cell) for cell in row[len(COLUMNS) : len(COLUMNS) + k]] for row in values])
        top1 = np.array([int(row[2]) for row in values], dtype=np.int64)
        flags = np.array([[row[i].lower() in ("true", "1", "1.0") for i in (4, 5)] for row in values])
    except (ValueError, IndexError) as error:
        raise ValueError(f"{path}: a row does not hold the columns of its header ({error})") from None
    placeholders = int(top1.max()) + 1 + np.arange(k)  # past every top-1: images the table does not name
    indices = np.concatenate([top1[:, None], np.broadcast_to(placeholders[: k - 1], (len(top1), k - 1))], axis=1)
    indices[scores == -np.inf] = -1
    answerable, correct = flags[:, 0], flags[:, 1]
    rows_of = zip(top1, answerable, correct, strict=True)
    lists = [[int(t)] if c else [int(placeholders[-1])] if a else [] for t, a, c in rows_of]
    positives = positives_from_lists(lists, n_database=int(placeholders[-1]) + 1, source=path)
    config = {"source": str(path), "format": "per-query", "ranked_candidates": 1, "top_k": k}
    return Retrieval(scores, indices, positives, query_names=np.array([row[1] for row in values]), config=config)
