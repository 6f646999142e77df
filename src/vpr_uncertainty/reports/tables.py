"""Evaluation results as text tables (plain for the terminal, or Markdown).

Without a bootstrap the best AUC-PR is starred. With one (``Evaluation.bootstrap``), each metric shows its 95 %
interval in brackets, the star marks the leaders of AUC-PR (the best alone when it is significantly better than
every other method; otherwise every method not significantly worse than it) and a column gives the difference in
AUC-PR to the reference method with its Holm-adjusted p-value. ``values`` and ``tied`` count the distinct
uncertainty values and the share of queries that share theirs with another query.
"""

from __future__ import annotations

from vpr_uncertainty.evaluation import Evaluation

__all__ = ["best_auc_pr", "format_table", "markdown_cell"]

_COLUMNS = (
    ("method", "{}"),
    ("AUC-PR", "{:.4f}"),
    ("AP", "{:.4f}"),
    ("AURC", "{:.4f}"),
    ("R@100%P", "{:.3f}"),
    ("values", "{:d}"),
    ("tied", "{:.0%}"),
    ("ms/query", "{:.5f}"),
)


def _fmt(template: str, value: object) -> str:
    return "n/a" if value is None else template.format(value)


def _with_interval(value: float | None, interval: tuple[float, float] | None) -> str:
    text = _fmt("{:.4f}", value)
    return text if value is None or interval is None else f"{text} [{interval[0]:.3f}, {interval[1]:.3f}]"


def _vs_reference(method, reference: str) -> str:
    if method.name == reference:
        return "reference"
    test = method.vs_reference
    if test is None:
        return "n/a"
    return f"{test['delta_auc_pr']:+.3f} (p {test['p_value_holm']:.3f}){'s' if test['significant'] else ''}"


def _marked(evaluation: Evaluation) -> set[str]:
    """The methods starred: the bootstrap's AUC-PR leaders, or (no bootstrap) those with the best AUC-PR."""
    trained = {m.name for m in evaluation.methods.values() if m.trained_on_queries}
    if evaluation.bootstrap is not None:
        return set(evaluation.bootstrap["best"]["auc_pr"]["methods"]) - trained
    best = best_auc_pr(evaluation)
    return {
        m.name
        for m in evaluation.methods.values()
        if best is not None and m.informative and m.auc_pr == best and m.name not in trained
    }


def _legend(evaluation: Evaluation, compared: int) -> str:
    if compared < 2:
        return "no best AUC-PR (fewer than two informative methods)"
    if evaluation.bootstrap is None:
        return "* best AUC-PR"
    settings = evaluation.bootstrap
    how = (
        f"paired bootstrap over queries, {settings['resamples']} resamples, seed {settings['seed']}, "
        f"Holm-corrected at {settings['level']:g}"
    )
    if settings["best"]["auc_pr"]["significant"]:
        return f"* best AUC-PR, significantly better than every other method ({how})"
    return f"* tied leaders by AUC-PR: the best and every method not significantly worse than it ({how})"


def best_auc_pr(evaluation: Evaluation) -> float | None:
    """The best AUC-PR among the informative methods, or None when fewer than two can be compared.

    A method whose uncertainty is the same for every query ranks nothing: its AUC-PR is chance level and it is
    never best. With a single informative method there is nothing to compare it with, so nothing is marked.
    """
    scored = [
        m.auc_pr
        for m in evaluation.methods.values()
        if m.informative and m.auc_pr is not None and not m.trained_on_queries
    ]
    return max(scored) if len(scored) >= 2 else None


def markdown_cell(text: str) -> str:
    """``text`` safe inside a Markdown table cell: ``|`` escaped, line breaks as spaces.

    Examples
    --------
    >>> markdown_cell("SU|GV")
    'SU\\\\|GV'
    """
    return text.replace("|", "\\|").replace("\n", " ")


def format_table(evaluation: Evaluation, *, markdown: bool = False, title: str | None = None) -> str:
    """One row per uncertainty method, the best AUC-PR marked with ``*``; a header line with recall@N.

    Methods whose uncertainty is constant are marked ``†`` (uninformative) and never starred; see
    :func:`best_auc_pr`. A method evaluated on queries it was trained on is marked ``‡`` and never starred. The
    evaluation's notes follow the table, one line each.

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
    marked = _marked(evaluation)
    tied = [m.name for m in evaluation.methods.values() if not m.informative]
    reference = evaluation.bootstrap["reference"] if evaluation.bootstrap is not None else None
    for method in evaluation.methods.values():
        marker = "*" if method.name in marked and method.informative else ""
        marker += "" if method.informative else "†"
        marker += "‡" if method.trained_on_queries else ""  # trained on these queries (see the notes)
        values = (
            method.name + marker,
            method.auc_pr,
            method.average_precision,
            method.aurc,
            method.recall_at_full_precision,
            method.n_distinct,
            method.tied_share,
            method.time_per_query_ms,
        )
        row = [
            _fmt(template, value) if index else str(value)
            for index, ((_, template), value) in enumerate(zip(_COLUMNS, values, strict=True))
        ]
        if reference is not None:
            row[1] = _with_interval(method.auc_pr, method.auc_pr_ci)
            row[2] = _with_interval(method.average_precision, method.average_precision_ci)
            row[3] = _with_interval(method.aurc, method.aurc_ci)
            row.append(_vs_reference(method, reference))
        rows.append(row)
    header = [name for name, _ in _COLUMNS] + ([f"vs {reference}"] if reference is not None else [])
    recalls = "  ".join(f"R@{n} {value:.3f}" for n, value in evaluation.recall_at_n.items())
    summary = f"{evaluation.n_queries} queries, {recalls}"
    lines = [title] if title else []
    if markdown:
        lines += [summary, "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(markdown_cell(cell) for cell in row) + " |" for row in rows]
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
    lines.append(
        f"{_legend(evaluation, compared)}. AUC-PR, AP: higher is better; AURC: lower is better; R@100%P: recall with "
        "no wrong answer accepted; values: distinct uncertainty values; tied: share of queries tied with another."
    )
    if reference is not None:
        confidence = evaluation.bootstrap["confidence"]
        lines.append(
            f"[low, high]: {confidence:.0%} percentile bootstrap interval; vs {reference}: AUC-PR difference "
            f"(Holm-adjusted p; s = significant)."
        )
    if tied:
        lines.append("† uninformative: the same uncertainty for every query (no ranking, chance-level AUC-PR).")
    for note in evaluation.notes:
        lines.append(f"note: {note}")
    return "\n".join(lines)
