"""Machine labels: labelers say, for every query of a retrieval, whether its top-1 answer is correct.

A labeler (:class:`Labeler`, in :data:`LABELERS`: ``agreement``, ``gv-sift``, ``gv-disk-lg``, ``gv-xfeat``,
``back-end``) turns a
retrieval and what it needs (:data:`NEEDS`) into :class:`~vpr_uncertainty.calibration.labels_file.MachineLabels`:
``correct`` (Q,) bool, ``confidence`` (Q,), higher = surer the top-1 is correct (NaN: none), and each label's source.
Machine labels may choose a gate's cut; only a person's labels certify it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from vpr_uncertainty.calibration.labels_file import MachineLabels
from vpr_uncertainty.methods import get_method, spec_options
from vpr_uncertainty.plugins import Registry, load_target, merge_options
from vpr_uncertainty.retrieval import Retrieval
from vpr_uncertainty.retrieval.ground_truth import DEFAULT_RADIUS
from vpr_uncertainty.retrieval.result import check_positive_int

#: Needs a labeler may declare by name (any other is the name of an input): the inputs that give it, and in words.
NEEDS: dict[str, tuple[tuple[str, ...], str]] = {
    "retrievals": (("others",), "other VPR methods' retrievals of the same queries (argument others)"),
    "images": (("query_paths", "database_paths"), "the images (arguments query_paths and database_paths)"),
    "graph": (("graph",), "a pose graph (argument graph)"),
}


@dataclass(frozen=True)
class Labeler:
    """A labeler: ``target`` is ``function(retrieval, **inputs, **options) -> MachineLabels`` or ``"module:function"``;
    ``requires``: names of :data:`NEEDS`; ``options``: its options and defaults (whose types type a spec's values)."""

    name: str
    description: str
    target: Callable[..., MachineLabels] | str
    requires: tuple[str, ...] = ()
    extra: str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)


#: The registered labelers (names are case-insensitive).
LABELERS: Registry[Labeler] = Registry("labeler", normalise=str.lower)


def label(retrieval: Retrieval, by: str, *, options: Mapping[str, Any] | None = None, **inputs: Any) -> MachineLabels:
    """The labels of the queries of ``retrieval`` (scores, indices (Q, K)) by ``by``, a name or a spec with options
    (``"agreement:min_agree=2"``); ``options`` go over the spec's, those over the defaults (an unknown one is a
    ValueError); ``inputs``: what it needs (:data:`NEEDS`) and takes (gv-*: ``cache_dir``, ``device``, ``workers``).

    Examples
    --------
    >>> mine = Retrieval(np.array([[0.9, 0.5], [0.8, 0.7]]), np.array([[3, 1], [2, 0]]))
    >>> others = [Retrieval(np.array([[0.6, 0.2], [0.9, 0.1]]), np.array([[3, 0], [1, 2]]))] * 3
    >>> label(mine, "agreement:min_agree=2", others=others)[:2]
    (array([ True, False]), array([1., 0.]))
    """
    entry = LABELERS.get(by.partition(":")[0].strip())
    what = f"labeler {entry.name!r}"
    given = spec_options(by, entry.options, "labeler spec") if ":" in by else {}
    merged = merge_options(entry.options, {**given, **(options or {})}, what=what)
    needs = [NEEDS.get(need, ((need,), f"argument {need}")) for need in entry.requires]  # else: an input's name
    if missing := [words for keys, words in needs if any(inputs.get(key) is None for key in keys)]:
        raise ValueError(f"{what} needs {' and '.join(missing)}")
    labels = load_target(entry.target, what=what, extra=entry.extra)(retrieval, **inputs, **merged)
    correct, confidence = np.asarray(labels.correct), np.asarray(labels.confidence, np.float64)
    if correct.dtype != bool or {correct.shape, confidence.shape, (len(labels.sources),)} != {(retrieval.n_queries,)}:
        raise RuntimeError(f"{what} returned labels of shape {correct.shape}, expected ({retrieval.n_queries},) bool")
    return MachineLabels(correct, confidence, list(labels.sources))


def agreement(
    retrieval: Retrieval, *, others: Sequence[Retrieval] | Mapping[str, Retrieval], min_agree: int = 3
) -> MachineLabels:
    """Correct when at least ``min_agree`` of the ``others`` (retrievals of the same queries and database, or names to
    them) return the top-1 or, when ``retrieval`` holds database positions, one within its ``config["radius"]`` (else
    25); a best score tied among m candidates gives each 1/m of a vote; confidence = the votes' share of the others."""
    named = dict(others) if isinstance(others, Mapping) else {f"others[{i}]": r for i, r in enumerate(others)}
    if check_positive_int(min_agree, "min_agree") > len(named):
        raise ValueError(f"min_agree={min_agree} needs at least {min_agree} other retrievals, got {len(named)}")
    top, positions, votes = retrieval.indices[:, 0], retrieval.database_positions, np.zeros(retrieval.n_queries)
    size = retrieval.n_database or retrieval.config.get("n_database")
    for name, other in named.items():
        theirs = other.n_database or other.config.get("n_database")
        pairs = [(getattr(retrieval, n), getattr(other, n)) for n in ("query_names", "database_names")]
        if (other.n_queries, theirs or size) != (retrieval.n_queries, size or theirs) or any(
            a is not None and b is not None and not np.array_equal(a, b) for a, b in pairs
        ):
            raise ValueError(
                f"{name} holds {other.n_queries} queries against {theirs or '?'} images, not this pool's "
                f"{retrieval.n_queries} against {size or '?'} (or other names): it is no retrieval of the same queries"
            )
        tied = (other.scores == other.scores[:, :1]) & (other.indices >= 0)
        width = max(1, int(tied.sum(1).max(initial=0)))  # sorted descending: the ties of the best come first
        tied, indices = tied[:, :width], other.indices[:, :width]
        same = indices == top[:, None]
        if positions is not None:
            radius = float(retrieval.config.get("radius", DEFAULT_RADIUS))
            same |= np.linalg.norm(positions[indices] - positions[top][:, None], axis=-1) <= radius
        votes += (tied & same).sum(1) / np.maximum(tied.sum(1), 1)
    votes[top < 0] = 0.0
    source = f"agreement:min_agree={min_agree},others={len(named)}"
    return MachineLabels(votes >= min_agree - 1e-9, votes / len(named), [source] * retrieval.n_queries)


def _geometric(preset: str) -> Callable[..., MachineLabels]:
    """Correct at ``min_inliers`` or more with the top-1 by the method ``preset`` (its cache too); confidence = inliers.
    4, 15, 9: the fewest wrong labels on the corridor's 160×120 images (benchmarks/machine_labels.py); measure yours."""

    def geometric(retrieval: Retrieval, *, min_inliers: int, **inputs: Any) -> MachineLabels:
        import vpr_uncertainty.geometric  # noqa: F401  (registers the GV-* methods)

        check_positive_int(min_inliers, "min_inliers")
        inliers, source = -np.asarray(get_method(preset)(retrieval, **inputs), float), f"{preset.lower()}:min_inliers"
        return MachineLabels(inliers >= min_inliers, inliers, [f"{source}={min_inliers}"] * len(inliers))

    return geometric


def back_end(retrieval: Retrieval, *, graph: Any, robust: str, odometry: str) -> MachineLabels:
    """A SLAM back end's own decisions as labels of a loop-closure score file's rows (the pool ``retrieval`` read
    from it, its closures in ``config["edges"]``): every scored closure enters ``graph`` (closures without a row
    too), GNC (or the kernel ``robust``) optimises it, and a closure whose final weight is above 0.5 is labelled
    correct; confidence = the weight."""
    from vpr_uncertainty.slam.graph_file import read_graph_file
    from vpr_uncertainty.slam.pose_graph import closure_mask, factor_graph, odometry_mask, optimize

    if "edges" not in retrieval.config:
        raise ValueError("the back-end labeler labels the rows of a loop-closure score file (edges, scores)")
    graph_file, edges = read_graph_file(graph), np.asarray(retrieval.config["edges"], np.int64).reshape(-1, 2)
    is_odometry = odometry_mask(graph_file, odometry)
    every = SimpleNamespace(accept=lambda rows: np.ones(len(rows), bool))
    keep = closure_mask(graph_file.edges, edges, retrieval.scores, every, odometry=is_odometry, unscored="keep")
    factors, initial = factor_graph(graph_file, keep, odometry)
    closures = np.flatnonzero(~is_odometry[keep])
    weight = np.full(len(keep), np.nan)
    weight[keep] = optimize(factors, initial, robust=robust, closures=closures, weights=True)[1]
    first = {
        pair: index for index, pair in reversed(list(enumerate(map(tuple, np.sort(graph_file.edges, 1).tolist()))))
    }
    row_weight = weight[[first[pair] for pair in map(tuple, np.sort(edges, axis=1).tolist())]]
    return MachineLabels(row_weight > 0.5, row_weight, [f"back-end:robust={robust},odometry={odometry}"] * len(edges))


def label_quality(correct: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Labels ``correct`` against the ground truth ``truth``, both (Q,) bool: ``precision`` of the labels "correct",
    ``recall`` of the truly correct (NaN where there is none) and ``wrong``, the share of labels that differ."""
    correct, truth = np.asarray(correct, bool), np.asarray(truth, bool)
    hits, nan = int((correct & truth).sum()), float("nan")
    precision, recall = (hits / int(n) if n else nan for n in (correct.sum(), truth.sum()))
    return {"precision": precision, "recall": recall, "wrong": float(np.mean(correct != truth)) if len(truth) else nan}


_AGREEMENT = "at least min_agree others return the top-1; confidence: their share"
_BACK_END = "a loop closure kept by the back end (GNC weight > 0.5) on the graph; confidence: the weight"
LABELERS.register(Labeler("back-end", _BACK_END, back_end, ("graph",), "slam", {"robust": "gnc", "odometry": "ids"}))
LABELERS.register(Labeler("agreement", _AGREEMENT, agreement, ("retrievals",), options={"min_agree": 3}))
for _preset, (_extra, _inliers, *_aliases) in {
    "GV-SIFT": ("opencv", 4), "GV-DISK-LG": ("gv", 15, "gv-disk-lightglue"), "GV-XFEAT": ("gv", 9)
}.items():  # fmt: skip
    _description = f"{_preset} inliers with the top-1 >= min_inliers; confidence: inliers"
    _entry = Labeler(_preset.lower(), _description, _geometric(_preset), ("images",), _extra, {"min_inliers": _inliers})
    LABELERS.register(_entry, aliases=tuple(_aliases))
