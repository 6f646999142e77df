"""Stage ``verify``: a retrieval and its images -> ``verification.npz`` (RANSAC inliers of the top candidates: the GV
uncertainty of the top match, or the candidates re-ranked by inliers; see docs/explanation/geometric-verification.md).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache
from vpr_uncertainty._repr import compact_repr
from vpr_uncertainty.pipeline.options import (
    add_executor_options,
    add_image_options,
    add_options,
    command_wording,
    conf_from_args,
    device_name,
    executor_from_args,
    executor_options,
    option,
    output_file,
    positive_int,
)
from vpr_uncertainty.pipeline.report import format_reranking


@dataclass(frozen=True)
class VerifyConf:
    """How the candidates are verified; each field is also the command-line option of the same name."""

    method: str = option("GV-SIFT", "geometric verification preset: GV-SIFT, GV-DISK-LG, GV-XFEAT, GV-SP-SG, GV-SP-LG")
    top_k: int = option(
        1, "candidates verified per query (1: the top match, its GV uncertainty; more: re-ranking)", type=positive_int
    )
    device: str = option("cpu", "cpu, cuda, cuda:N or mps (local features and matching)", type=device_name)


#: The configuration of the stage when none is given (hloc's ``default_conf``).
default_conf = VerifyConf()


@dataclass
class Verified:
    """What :func:`compute` produced: the file and the re-ranking (inliers, re-ranked indices, recall@N)."""

    __repr__ = compact_repr

    path: Path
    reranking: Any


def compute(
    conf: VerifyConf,
    retrieval: Any,
    query_paths: list[str],
    database_paths: list[str],
    path: str | Path,
    *,
    cache_dir: str | Path | None = None,
    executor: Any = None,
) -> Verified:
    """Verify the first ``conf.top_k`` candidates of every query and write ``path``.

    Parameters
    ----------
    conf : VerifyConf
    retrieval : Retrieval
        With or without ground truth (without, no recall@N).
    query_paths, database_paths : list of str
        Image files indexed like the retrieval.
    path : str or Path
        ``verification.npz``: ``inliers`` and ``matches`` of shape (Q, top_k) in the retrieval's order,
        ``indices`` (Q, K) re-ranked by inliers, ``uncertainty`` (Q,) = −inliers of the re-ranked top match (higher =
        less trustworthy) and ``fingerprint`` (the method, top_k and the retrieval's fingerprint).
    cache_dir : str or Path, optional
        Where each image's local features are cached (default: ``local_features`` beside ``path``).
    executor : LocalExecutor or RayExecutor, optional
        Where the pairs are verified (default: this process).
    """
    from vpr_uncertainty.geometric import rerank

    path = Path(path)
    options = {"executor": executor} if executor is not None else {}
    reranking = rerank(
        retrieval,
        conf.method,
        top_k=conf.top_k,
        query_paths=query_paths,
        database_paths=database_paths,
        cache_dir=Path(cache_dir) if cache_dir is not None else path.parent / "local_features",
        device=conf.device,
        **options,
    )
    from vpr_uncertainty.methods import get_method

    described = {"method": get_method(conf.method).identity(), "top_k": conf.top_k}
    fingerprint = cache.fingerprint("verify", described, {"retrieval": retrieval.config.get("fingerprint")})
    with cache.atomic_write(path, "wb") as handle:
        np.savez_compressed(
            handle,
            inliers=reranking.inliers,
            matches=reranking.verification.matches,
            indices=reranking.indices,
            uncertainty=reranking.uncertainty,
            fingerprint=np.array(fingerprint),
        )
    return Verified(path=path, reranking=reranking)


def main(conf: VerifyConf, retrieval_file: str | Path, images: str | Path, out: str | Path) -> Path:
    """Verify the retrieval file's candidates against the images of the dataset folder ``images``; ``out``."""
    from vpr_uncertainty.data.images import retrieval_image_paths
    from vpr_uncertainty.retrieval import load_retrieval

    retrieval = load_retrieval(retrieval_file)
    query_paths, database_paths = retrieval_image_paths(retrieval, images=images)
    return compute(conf, retrieval, [str(p) for p in query_paths], [str(p) for p in database_paths], out).path


# --- command line --------------------------------------------------------------------------------------------


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """The ``verify`` command."""
    parser = subparsers.add_parser(
        "verify",
        help="geometric verification of the top candidates of a retrieval file (inliers, re-ranking)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Match local features between each query and its first --top-k candidates, count the RANSAC inliers\n"
            "and write them, with the candidates re-ranked by inliers and the GV uncertainty of the top match\n"
            "(−inliers), to a .npz file. Each image's local features are cached (in local_features/ beside OUT),\n"
            "so a rerun, or `evaluate --methods GV-...` with the same cache, extracts nothing again."
        ),
        epilog=(
            "example:\n  vpr-uncertainty verify runs/corridor/retrieval.npz --images corridor/ --top-k 10 "
            "--out runs/corridor/verification.npz"
        ),
    )
    parser.add_argument("retrieval", type=Path, metavar="RETRIEVAL", help="retrieval file (.npz, from retrieve or run)")
    add_image_options(parser)
    parser.add_argument("--out", type=output_file, required=True, metavar="FILE", help="file to write (.npz)")
    add_options(parser, VerifyConf)
    add_executor_options(parser, ray_workers="the verification tasks in flight (default: the cluster's CPUs)")
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.data.images import retrieval_image_paths
    from vpr_uncertainty.methods import get_method
    from vpr_uncertainty.retrieval import load_retrieval

    if args.out.suffix.lower() != ".npz":
        raise ValueError(f"--out must name a .npz file, got {args.out}")
    if get_method(args.method).kind != "geometric":
        raise ValueError(
            f"--method must be a geometric verification method (GV-SIFT, GV-DISK-LG, ...), got {args.method}"
        )
    executor_options(args)  # bad executor options fail before any work
    retrieval = load_retrieval(args.retrieval)
    wording = {"images": "--images", "query_images": "--query-images", "database_images": "--database-images"}
    with command_wording(**wording):
        query_paths, database_paths = retrieval_image_paths(
            retrieval, images=args.images, query_images=args.query_images, database_images=args.database_images
        )
    conf = conf_from_args(VerifyConf, args)
    with executor_from_args(args) as executor:
        verified = compute(
            conf,
            retrieval,
            [str(p) for p in query_paths],
            [str(p) for p in database_paths],
            args.out,
            executor=None if executor.name == "local" else executor,
        )
    reranking = verified.reranking
    inliers = reranking.inliers[:, 0]
    print(
        f"{retrieval.n_queries} queries x {reranking.inliers.shape[1]} candidates verified with {conf.method}: "
        f"median {np.median(inliers):.0f} inliers with the top match"
    )
    if reranking.recall:
        print(format_reranking({"method": conf.method, "top_k": conf.top_k, **reranking.recall}))
    print(f"wrote {args.out}")
    return 0
