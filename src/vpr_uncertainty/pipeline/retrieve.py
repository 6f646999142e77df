"""Stage 2, ``retrieve``: descriptors and ground truth -> ``retrieval.npz`` (top-k candidates with their ground truth),
reused only when the fingerprint of the options and of every input's content is equal (see docs/explanation/caches.md).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache
from vpr_uncertainty._repr import compact_repr
from vpr_uncertainty.pipeline.options import (
    add_options,
    add_progress_options,
    conf_from_args,
    non_negative_float,
    option,
    output_file,
    positive_int,
)

STAGE = "retrieval"


@dataclass(frozen=True)
class RetrieveConf:
    """How the candidates are found; each field is also the command-line option of the same name."""

    top_k: int = option(20, "candidates kept per query", type=positive_int)
    index: str = option("Flat", 'Faiss index-factory string: "Flat" (exact), "IVF4096,PQ64", "HNSW32", ...')
    search_params: str | None = option(
        None, 'search parameters of an approximate index, e.g. "nprobe=32"', metavar="PARAMS"
    )
    device: str = option("cpu", "cuda needs GPU Faiss", choices=("cpu", "cuda"))
    batch_size: int = option(4096, "queries searched at once", type=positive_int)
    database_block: int | None = option(
        None,
        "exact search: read the database in blocks of ROWS rows, never whole (default: a database file larger than "
        "64 MiB is read in blocks of 64 MiB; approximate indexes and cuda read it whole); not part of the "
        "fingerprint, since it changes the memory used, not the result",
        type=positive_int,
        metavar="ROWS",
    )
    progress: bool | None = field(default=None)


#: The configuration of the stage when none is given (hloc's ``default_conf``).
default_conf = RetrieveConf()


@dataclass
class Retrieved:
    """What :func:`compute` produced: the file, the retrieval in memory, its fingerprint, whether it was reused."""

    __repr__ = compact_repr

    path: Path
    retrieval: Any
    fingerprint: str
    reused: bool = False


def ground_truth_key(fields: Mapping[str, Any]) -> str:
    """A digest of the content of ground-truth fields (:func:`vpr_uncertainty.data.dataset.ground_truth_fields`)."""
    positives = fields.get("positives")
    parts: list[Any] = []
    if positives is None:
        parts += [None, None, None]
    else:
        from scipy import sparse

        matrix = sparse.csr_array(positives, dtype=bool)
        matrix.sort_indices()
        parts += [np.asarray(matrix.shape, dtype=np.int64), matrix.indptr.astype(np.int64), matrix.indices]
    for name in ("query_names", "database_names", "query_positions", "database_positions"):
        value = fields.get(name)
        parts.append(None if value is None else np.asarray(value, dtype=str if name.endswith("_names") else np.float64))
    return cache.fingerprint("ground_truth", dict(fields.get("config") or {}), {"arrays": cache.array_digest(*parts)})


def compute(
    conf: RetrieveConf,
    database: tuple[Any, np.ndarray],
    queries: tuple[Any, np.ndarray],
    ground_truth: Mapping[str, Any] | None,
    path: str | Path,
    *,
    describe: Mapping[str, Any] | None = None,
    copy: bool = True,
) -> Retrieved:
    """Top-``conf.top_k`` database candidates of each query, with the ground truth attached, cached in ``path``.

    Parameters
    ----------
    conf : RetrieveConf
    database, queries : tuple of (names or None, ndarray of shape (N, D))
        Descriptors and their image names. The database may be a
        :class:`~vpr_uncertainty.retrieval.DescriptorRows` (from :func:`~vpr_uncertainty.retrieval.open_descriptors`):
        it is then hashed and searched one block of rows at a time, never read whole (exact search).
    ground_truth : mapping, optional
        Fields made by :func:`vpr_uncertainty.data.dataset.ground_truth_fields` (None: no ground truth).
    path : str or Path
        The retrieval file (``.npz``).
    describe : mapping, optional
        Further entries of the file's ``config`` (the model, the dataset); they are part of the fingerprint.
    copy : bool
        Leave the descriptor arrays untouched (False normalises them in place).
    """
    from vpr_uncertainty.retrieval import load_retrieval, retrieve, save_retrieval
    from vpr_uncertainty.retrieval.ground_truth import attach_ground_truth

    path = Path(path)
    (database_names, database_array), (query_names, query_array) = database, queries
    describe = dict(describe or {})
    options = {"k": conf.top_k, "index": conf.index, "search_params": conf.search_params}
    inputs = {
        "database": cache.array_digest(_names(database_names), database_array),
        "queries": cache.array_digest(_names(query_names), query_array),
        "ground_truth": None if ground_truth is None else ground_truth_key(ground_truth),
    }
    fingerprint = cache.fingerprint(STAGE, {**options, **describe}, inputs)
    cached = cache.read_if_fresh(path, fingerprint, load_retrieval, lambda found: found.config.get("fingerprint"))
    if cached is not None:
        return Retrieved(path=path, retrieval=cached, fingerprint=fingerprint, reused=True)
    retrieval = retrieve(
        database_array,
        query_array,
        conf.top_k,
        index=conf.index,
        device=conf.device,
        batch_size=conf.batch_size,
        search_params=conf.search_params,
        config={**describe, "fingerprint": fingerprint},
        copy=copy,
        progress=conf.progress,
        database_block=conf.database_block,
    )
    if ground_truth is not None:
        retrieval = attach_ground_truth(retrieval, ground_truth)
    save_retrieval(retrieval, path)
    return Retrieved(path=path, retrieval=retrieval, fingerprint=fingerprint)


def main(
    conf: RetrieveConf,
    database: str | Path,
    queries: str | Path,
    out: str | Path,
    *,
    ground_truth: Mapping[str, Any] | None = None,
) -> Path:
    """Search the descriptor file ``database`` (.npy or .h5) for each row of ``queries`` and write ``out``."""
    from vpr_uncertainty.data import load_descriptors, open_descriptors

    rows = open_descriptors(database, "database"), load_descriptors(queries, "queries")
    describe = {"database": str(database), "queries": str(queries)}
    return compute(conf, *rows, ground_truth, out, describe=describe).path


def search_device(device: str) -> tuple[str, str | None]:
    """The Faiss device for descriptors computed on ``device``, and a note when it differs (no GPU Faiss).

    Examples
    --------
    >>> search_device("cpu")
    ('cpu', None)
    """
    from vpr_uncertainty.retrieval import faiss_gpu_available

    kind = device.split(":")[0]
    if kind == "cuda" and faiss_gpu_available():
        return "cuda", None
    if kind == "cpu":
        return "cpu", None
    return "cpu", f"Faiss has no GPU support here; searching on the CPU (descriptors came from {device})"


def _names(names: Any) -> np.ndarray | None:
    return None if names is None else np.asarray(names, dtype=str)


# --- command line --------------------------------------------------------------------------------------------


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """The ``retrieve`` command."""
    parser = subparsers.add_parser(
        "retrieve",
        help="search database descriptors for each query and write a retrieval file",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "L2-normalise the descriptors, find the k most similar database images of each query by inner\n"
            "product (cosine similarity) with Faiss, and write a retrieval file (.npz) with the scores, indices\n"
            "and squared L2 distances. With positions, the file also holds the positives (database images within\n"
            "--radius of each query) and the database positions that SUE needs, so that\n"
            "`vpr-uncertainty evaluate retrieval.npz` runs with no other argument.\n\n"
            "DB and Q are .npy arrays (one descriptor per row) or the HDF5 descriptor cache (.h5) of the feature\n"
            "extraction. Candidates with equal scores are ordered by lower database index; with k larger than the\n"
            "database, the missing candidates have index -1."
        ),
        epilog=(
            "examples:\n"
            "  vpr-uncertainty retrieve --database db.npy --queries q.npy --out runs/retrieval.npz \\\n"
            "      --database-positions db_utm.npy --query-positions q_utm.npy --radius 25\n"
            "  vpr-uncertainty retrieve --database descriptors.h5 --queries descriptors.h5 --out r.npz \\\n"
            '      --index "IVF4096,PQ64" --search-params nprobe=32'
        ),
    )
    parser.add_argument("--database", type=Path, required=True, metavar="DB", help="database descriptors (.npy, .h5)")
    parser.add_argument("--queries", type=Path, required=True, metavar="Q", help="query descriptors (.npy, .h5)")
    parser.add_argument("--out", type=output_file, required=True, metavar="FILE", help="retrieval file to write (.npz)")
    add_options(parser, RetrieveConf, help={"top_k": "candidates kept per query (default 10)"})
    parser.set_defaults(top_k=10)
    parser.add_argument("--database-positions", type=Path, metavar="P.npy", help="database positions (D x 2, metres)")
    parser.add_argument("--query-positions", type=Path, metavar="P.npy", help="query positions (Q x 2, metres)")
    parser.add_argument(
        "--radius",
        type=non_negative_float,
        default=25.0,
        help="positives: database images within this distance of the query, inclusive (default 25)",
    )
    parser.add_argument(
        "--position-kind",
        choices=("metres", "frames", "placeholder"),
        help="what the positions are (default: detected; frame indices and placeholder ids make SUE warn)",
    )
    parser.add_argument(
        "--gt", type=Path, help="explicit ground truth instead of the radius (any format that `evaluate --gt` reads)"
    )
    add_progress_options(parser)
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.data import load_descriptors, open_descriptors
    from vpr_uncertainty.evaluation import recall_at_n
    from vpr_uncertainty.formats.ground_truth import load_ground_truth, read_positions
    from vpr_uncertainty.retrieval.ground_truth import ground_truth_fields

    if args.out.suffix.lower() != ".npz":
        raise ValueError(f"--out must name a .npz file, got {args.out}")
    # The database stays on disk: exact search reads it block by block (approximate indexes read it whole).
    database_names, database = open_descriptors(args.database, "database")
    query_names, queries = load_descriptors(args.queries, "queries")
    positives = None
    if args.gt is not None:
        positives = load_ground_truth(args.gt, n_queries=len(queries), n_database=len(database))
    ground_truth = ground_truth_fields(  # checked before the search, the slow part
        len(queries),
        len(database),
        database_positions=read_positions(args.database_positions, expected=len(database), name="database positions"),
        query_positions=read_positions(args.query_positions, expected=len(queries), name="query positions"),
        radius=args.radius,
        positives=positives,
        database_names=database_names,
        query_names=query_names,
        position_kind=args.position_kind,
    )
    describe = {"database": str(args.database), "queries": str(args.queries)}
    if args.gt is not None:
        describe["ground_truth"] = str(args.gt)
    conf = conf_from_args(RetrieveConf, args, progress=getattr(args, "progress", None))
    start = time.perf_counter()
    found = compute(
        conf, (database_names, database), (query_names, queries), ground_truth, args.out, describe=describe, copy=False
    )
    seconds = time.perf_counter() - start
    result = found.retrieval
    done = "kept" if found.reused else "wrote"
    why = " (same descriptors, ground truth and options)" if found.reused else f" ({args.index}, {args.device}"
    print(
        f"{done} {args.out}: {result.n_queries} queries x {result.k} candidates among {len(database)} database "
        f"images{why}" + ("" if found.reused else f", {seconds:.1f} s)")
    )
    if result.positives is not None:
        answerable = int((result.positives.sum(axis=1) > 0).sum())
        if answerable:
            recalls = recall_at_n(result.indices, result.positives, ns=[n for n in (1, 5, 10) if n <= result.k])
            shown = ", ".join(f"recall@{n} {value:.3f}" for n, value in recalls.items())
            print(f"{shown} ({result.n_queries - answerable} queries without a positive)")
        else:
            print("no query has a positive in the database: check the positions and --radius")
    return 0
