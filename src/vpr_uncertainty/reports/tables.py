"""Evaluation results as text tables (plain for the terminal, or Markdown)."""

from __future__ import annotations

from vpr_uncertainty.evaluation import Evaluation

__all__ = ["best_auc_pr", "format_table"]

_COLUMNS = (
    ("method", "{}"),
    ("AUC-PR", "{:.4f}"),
    ("AP", "{:.4f}"),
    ("AURC", "{:.4f}"),
    ("R@100%P", "{:.3f}"),
    ("ms/query", "{:.5f}"),
)


def _fmt(template: str, value: object) -> str:
    return "n/a" if value is None else template.format(value)


def best_auc_pr(evaluation: Evaluation) -> float | None:
    """The best AUC-PR among the informative methods, or None when fewer than two can be compared.

    A method whose uncertainty is the same for every query ranks nothing: its AUC-PR is chance level and it is
    never best. With a single informative method there is nothing to compare it with, so nothing is marked.
    """
    scored = [m.auc_pr for m in evaluation.methods.values() if m.informative and m.auc_pr is not None]
    return max(scored) if len(scored) >= 2 else None


def format_table(evaluation: Evaluation, *, markdown: bool = False, title: str | None = None) -> str:
    """One row per uncertainty method, the best AUC-PR marked with ``*``; a header line with recall@N.

    Methods whose uncertainty is constant are marked ``†`` (uninformative) and never starred; see
    :func:`best_auc_pr`. The evaluation's notes follow the table, one line each.

    Parameters
    ----------
    evaluation : Evaluation
        The result of :func:`vpr_uncertainty.evaluate`.
    markdown : bool
        Write a Markdown table instead of aligned plain text.
    title : str, optional
        A first line naming what was evaluated.
    """
    rows = []
    best = best_auc_pr(evaluation)
    tied = [m.name for m in evaluation.methods.values() if not m.informative]
    for method in evaluation.methods.values():
        marker = "*" if best is not None and method.informative and method.auc_pr == best else ""
        marker += "" if method.informative else "†"
        values = (
            method.name + marker,
            method.auc_pr,
            method.average_precision,
            method.aurc,
            method.recall_at_full_precision,
            method.time_per_query_ms,
        )
        rows.append(
            [
                _fmt(template, value) if index else str(value)
                for index, ((_, template), value) in enumerate(zip(_COLUMNS, values, strict=True))
            ]
        )
    header = [name for name, _ in _COLUMNS]
    recalls = "  ".join(f"R@{n} {value:.3f}" for n, value in evaluation.recall_at_n.items())
    summary = f"{evaluation.n_queries} queries, {recalls}"
    lines = [title] if title else []
    if markdown:
        lines += [summary, "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(row) + " |" for row in rows]
    else:
        widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
        lines.append(summary)
        lines.append(
            "  ".join(h.ljust(w) if i == 0 else h.rjust(w) for i, (h, w) in enumerate(zip(header, widths, strict=True)))
        )
        for row in rows:
            lines.append(
                "  ".join(
                    c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths, strict=True))
                )
            )
    compared = sum(1 for m in evaluation.methods.values() if m.informative and m.auc_pr is not None)
    star = "* best AUC-PR" if compared >= 2 else "no best AUC-PR (fewer than two informative methods)"
    lines.append(
        f"{star}. AUC-PR, AP: higher is better; AURC: lower is better; R@100%P: recall with no wrong answer accepted."
    )
    if tied:
        lines.append("† uninformative: the same uncertainty for every query (no ranking, chance-level AUC-PR).")
    for note in evaluation.notes:
        lines.append(f"note: {note}")
    return "\n".join(lines)
