"""Stage 4, ``report``: an evaluation -> ``results.md``, ``pr_curves.png`` and, last, ``results.json``; each written
atomically and at most once, nothing redrawn whose inputs are unchanged (see docs/explanation/caches.md).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from vpr_uncertainty import cache

__all__ = ["format_reranking", "main"]


def format_reranking(reranking: Mapping[str, Any]) -> str:
    """recall@N of the global retrieval and after re-ranking its top-k by inliers, in one line."""
    pairs = ", ".join(
        f"R@{n} {reranking['global'][n]:.3f} → {reranking['reranked'][n]:.3f}" for n in reranking["reranked"]
    )
    return f"re-ranking the top {reranking['top_k']} by {reranking['method']} inliers: {pairs}"


def main(
    evaluation: Any,
    out: str | Path,
    *,
    dataset: str,
    model: str,
    document: Mapping[str, Any],
    stage_seconds: dict[str, float],
    reranking: Mapping[str, Any] | None = None,
    width: str = "page",
) -> dict[str, Path]:
    """Write the table, the precision-recall plot and ``results.json`` into the folder ``out``.

    Parameters
    ----------
    evaluation : Evaluation
    out : str or Path
        The run directory.
    dataset, model : str
        The names in the titles of the table and the plot.
    document : mapping
        Entries of ``results.json`` beside :meth:`Evaluation.to_dict` (``config``, ``dataset``).
    stage_seconds : dict
        Seconds of the earlier stages; this stage adds ``"reports"`` (in place).
    reranking : mapping, optional
        The re-ranking summary, reported in the table and in ``results.json``.
    width : {"page", "column"}, default="page"
        The width of the plot (7.16 or 3.5 in, ``--figure-width``).

    Returns
    -------
    dict of str to Path
        ``results`` (results.json), ``table`` (results.md) and ``plot`` (pr_curves.png).
    """
    from vpr_uncertainty.reports import format_table, plot_rejection_curves

    start = time.perf_counter()
    out = Path(out)
    text = f"# {dataset} with {model}\n\n" + format_table(evaluation, markdown=True) + "\n"
    if reranking:
        text += "\n" + format_reranking(reranking) + "\n"
    table = cache.write_text(out / "results.md", text, keep_unchanged=True)
    plot = plot_rejection_curves(
        evaluation, out / "pr_curves.png", title=f"{dataset} · {model}", reuse=True, width=width
    )
    stage_seconds["reports"] = time.perf_counter() - start
    content = {
        **evaluation.to_dict(),
        **document,
        "stage_seconds": stage_seconds,
        **({"reranking": dict(reranking)} if reranking else {}),
    }
    results = cache.write_json(out / "results.json", content)
    return {"results": results, "table": table, "plot": plot}
