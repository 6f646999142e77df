"""Evaluation results as tables: one evaluation (:func:`format_table`, plain text or Markdown), Table 1 of a grid
(:func:`build_table1`: a metric per uncertainty method and VPR method, averaged over datasets, in Markdown, CSV,
LaTeX and HTML), and the ties table (:func:`build_ties_table`). How the best value is marked (paired tests, ``†``
for a method that ranks nothing): see docs/explanation/evaluation.md.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from html import escape
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation import Evaluation
from vpr_uncertainty.evaluation.bootstrap import (
    evaluation_distributions,
    leaders,
    percentile_interval,
    significance_notice,
)
from vpr_uncertainty.methods import METHODS
from vpr_uncertainty.reports.latex import latex_escape, latex_float

#: The columns of :func:`format_table` after ``method``: header, ``MethodEvaluation`` attribute, format.
_COLUMNS = (
    ("AUC-PR", "auc_pr", "{:.4f}"),
    ("AP", "average_precision", "{:.4f}"),
    ("AURC", "aurc", "{:.4f}"),
    ("R@100%P", "recall_at_full_precision", "{:.3f}"),
    ("values", "n_distinct", "{:d}"),
    ("tied", "tied_share", "{:.0%}"),
    ("ms/query", "time_per_query_ms", "{:.5f}"),
)
#: The metrics that have a bootstrap interval (``<metric>_ci``).
_WITH_CI = ("auc_pr", "average_precision", "aurc")


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
    trained = {m.name for m in evaluation.methods.values() if m.never_best}
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
    """The best AUC-PR among the informative methods not trained on the queries; None when fewer than two."""
    scored = [
        m.auc_pr for m in evaluation.methods.values() if m.informative and m.auc_pr is not None and not m.never_best
    ]
    return max(scored) if len(scored) >= 2 else None


def csv_cell(value: object) -> object:
    """``value`` as a CSV cell: text that a spreadsheet would run as a formula (it starts with = + - @, a tab or a
    carriage return, and is no signed number) gets a leading ``'`` (OWASP's advice on CSV injection); numbers stay."""
    if isinstance(value, str) and value.startswith(("=", "+", "-", "@", "\t", "\r")):
        try:
            float(value if value[0] in "+-" else "x")
        except ValueError:
            return "'" + value
    return value


def _csv_field(value: object) -> str:
    """A CSV field (RFC 4180): :func:`csv_cell`, quoted when it holds a comma, a quote or a line break (also a lone
    carriage return, which Python's ``csv`` writer leaves bare when lines end with ``\\n``)."""
    text = "" if value is None else str(csv_cell(value))
    return '"' + text.replace('"', '""') + '"' if any(char in text for char in ',"\r\n') else text


def _csv_text(rows: Iterable[Sequence[object]]) -> str:
    return "".join(",".join(map(_csv_field, row)) + "\n" for row in rows)


def per_query_csv(evaluation: Evaluation) -> str:
    """:meth:`Evaluation.per_query_columns` as CSV text (``evaluate --per-query FILE.csv``), without pandas."""
    columns = evaluation.per_query_columns()
    return _csv_text([list(columns), *zip(*columns.values(), strict=True)])


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

    ``†``: uninformative (constant uncertainty), ``‡``: evaluated on queries it was trained on (``‡?``: it cannot say it
    was not); none is starred.
    With a bootstrap, each metric shows its 95 % interval, the star marks the AUC-PR leaders and a column gives the
    difference in AUC-PR to the reference method with its Holm-adjusted p-value. The evaluation's notes follow.

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
        marker += "‡" if method.trained_on_queries else "‡?" if method.never_best else ""  # see the notes
        row = [method.name + marker, *(_fmt(template, getattr(method, key)) for _, key, template in _COLUMNS)]
        if reference is not None:
            row[1:4] = [_with_interval(getattr(method, key), getattr(method, f"{key}_ci")) for key in _WITH_CI]
            row.append(_vs_reference(method, reference))
        rows.append(row)
    header = ["method", *(name for name, _, _ in _COLUMNS)] + ([f"vs {reference}"] if reference is not None else [])
    recalls = "  ".join(f"R@{n} {_fmt('{:.3f}', value)}" for n, value in evaluation.recall_at_n.items())
    summary = f"{evaluation.n_queries} queries, {recalls}"
    lines = [title] if title else []
    if markdown:
        lines += [summary, "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(markdown_cell(cell) for cell in row) + " |" for row in rows]
    else:
        widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
        justify = [str.ljust] + [str.rjust] * (len(header) - 1)
        lines.append(summary)
        lines += ["  ".join(j(c, w) for j, c, w in zip(justify, row, widths, strict=True)) for row in [header, *rows]]
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
    lines += [f"note: {note}" for note in evaluation.notes]
    return "\n".join(lines)


# --- Table 1 of a grid ---

#: The metrics a Table 1 can hold: display name and whether higher is better.
METRIC_NAMES: dict[str, tuple[str, bool]] = {
    "auc_pr": ("AUC-PR", True),
    "average_precision": ("AP", True),
    "aurc": ("AURC", False),
}


@dataclass
class Table1:
    """rows: uncertainty methods; columns: VPR methods followed by ``Mean``; values[i][j] may be None.

    ``informative[i][j]`` is False for a cell whose every underlying result had a constant uncertainty (None:
    every cell is informative).
    """

    rows: list[str]
    columns: list[str]
    values: list[list[float | None]]
    time_ms: list[float | None]
    informative: list[list[bool]] | None = None
    metric: str = "auc_pr"
    higher_is_better: bool = True
    intervals: list[list[tuple[float, float] | None]] | None = None
    leaders: list[list[bool]] | None = None
    significant: list[bool] | None = None
    bootstrap: dict[str, Any] | None = None

    def is_informative(self, i: int, j: int) -> bool:
        return self.informative is None or self.informative[i][j]

    def best(self) -> list[float | None]:
        """The best informative value of each column (None where fewer than two informative values compete)."""
        best = []
        for j in range(len(self.columns)):
            column = [row[j] for i, row in enumerate(self.values) if row[j] is not None and self.is_informative(i, j)]
            best.append((max if self.higher_is_better else min)(column) if len(column) >= 2 else None)
        return best

    def marks(self) -> list[list[bool]]:
        """Per cell, whether it is marked: a bootstrap leader, or (no bootstrap) equal to the column's best."""
        if self.leaders is not None:
            return [list(row) for row in self.leaders]
        return [
            [
                v is not None and b is not None and bool(np.isclose(v, b, rtol=0, atol=5e-7))
                for v, b in zip(r, bs, strict=True)
            ]
            for r, bs in zip(self.values, self.cell_best(), strict=True)
        ]

    def cell_best(self) -> list[list[float | None]]:
        """Per cell: the column's best value where the cell is informative, else None (never marked)."""
        best = self.best()
        return [[b if self.is_informative(i, j) else None for j, b in enumerate(best)] for i in range(len(self.values))]


def _mean(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def build_table1(
    cells: Sequence, metric: str = "auc_pr", *, bootstrap: int = 0, seed: int = 0, level: float = 0.05
) -> Table1:
    """Average a metric of the grid's cells (``Cell``) over datasets.

    Each value is the metric averaged over the datasets on which it is defined; ``Mean`` averages a row over the
    VPR methods and ``ms/query`` is the row's mean time per query. With ``bootstrap``, a column's resamples follow
    the same averages, each cell resampled over its queries with the same seed (paired across methods).

    Parameters
    ----------
    cells : sequence of Cell
        The grid's results.
    metric : {"auc_pr", "average_precision", "aurc"}
        The metric of the table.
    bootstrap : int, default=0
        Paired bootstrap resamples for the intervals and the significance marks (0: none, the best value marked).
    seed : int, default=0
        Seed of the resamples.
    level : float, default=0.05
        Family-wise level of the tests of each column.
    """
    if metric not in METRIC_NAMES:
        raise ValueError(f"metric must be one of {', '.join(METRIC_NAMES)}, got {metric!r}")
    vpr_methods = list(dict.fromkeys(cell.vpr_method for cell in cells))
    methods = list(dict.fromkeys(name for cell in cells for name in cell.evaluation.methods))
    values, times, informative = [], [], []
    for method in methods:
        row, row_times, row_informative = [], [], []
        for vpr in vpr_methods:
            found = [
                c.evaluation.methods[method] for c in cells if c.vpr_method == vpr and method in c.evaluation.methods
            ]
            row.append(_mean([getattr(m, metric) for m in found]))
            row_times += [m.time_per_query_ms for m in found]
            row_informative.append(
                any(getattr(m, "informative", True) for m in found if getattr(m, metric) is not None)
            )
        row.append(_mean(row[: len(vpr_methods)]))
        row_informative.append(any(row_informative))
        values.append(row)
        times.append(_mean(row_times))
        informative.append(row_informative)
    table = Table1(
        rows=methods,
        columns=[*vpr_methods, "Mean"],
        values=values,
        time_ms=times,
        informative=informative,
        metric=metric,
        higher_is_better=METRIC_NAMES[metric][1],
    )
    if bootstrap and cells:
        distributions = column_distributions(cells, table.columns, bootstrap, seed)
        table_significance(table, distributions[metric], level)
        table.bootstrap = {"resamples": int(bootstrap), "seed": int(seed), "level": level}
    return table


def _rows(
    table: Table1, bold: tuple[str, str], dagger: str, around: tuple[str, str] = ("", ""), *, intervals: bool = True
) -> list[tuple[str, list[str], str]]:
    """(method, value texts, ms/query text) per row: marked values between ``bold``, ``dagger`` after an
    uninformative value, a bootstrap interval between ``around`` (when ``intervals``)."""
    marks = table.marks()
    rows = []
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        texts = []
        for j, value in enumerate(row):
            if value is None:
                texts.append("–")
                continue
            text = f"{bold[0]}{value:.3f}{bold[1]}" if marks[i][j] else f"{value:.3f}"
            text += "" if marks[i][j] or table.is_informative(i, j) else dagger
            interval = None if table.intervals is None or not intervals else table.intervals[i][j]
            if interval is not None:
                text += f" {around[0]}[{interval[0]:.2f}, {interval[1]:.2f}]{around[1]}"
            texts.append(text)
        rows.append((name, texts, "–" if time_ms is None else f"{time_ms:.4f}"))
    return rows


def marks_note(table: Table1) -> str:
    """What the marks mean: the best value, or (bootstrap) significant best vs tied leaders."""
    direction = "highest" if table.higher_is_better else "lowest"
    if table.bootstrap is None:
        return f"Bold: the best ({direction}) value of each column; no significance test (bootstrap = 0)."
    notice = significance_notice(table.bootstrap["resamples"], len(table.rows) - 1, table.bootstrap["level"])
    return (  # the notice before "[low", where the LaTeX caption ends
        f"Bold alone: the best ({direction}) of its column and significantly better than every other method; "
        "several in bold: tied leaders, none significantly worse than the best (paired bootstrap over queries, "
        f"{table.bootstrap['resamples']} resamples, seed {table.bootstrap['seed']}; significant: Holm-adjusted p <= "
        f"{table.bootstrap['level']:g}).{f' Note: {notice}.' if notice else ''} [low, high]: 95 % percentile interval."
    )


_FOOTNOTE = "† uninformative: the same uncertainty for every query on every dataset (AUC-PR at chance level)."
_LATEX_FOOTNOTE = r"\par\smallskip{\footnotesize $^\dagger$ uninformative: constant uncertainty (chance level).}"


def _end_latex(lines: list[str], uninformative: bool) -> str:
    """The float's ``lines``, the footnote on uninformative methods (when there are any) and ``\\end{table}``."""
    end = lines[0].replace("begin", "end").removesuffix("[t]")  # table or table*
    return "\n".join([*lines, *([_LATEX_FOOTNOTE] if uninformative else []), end]) + "\n"


def _any_uninformative(table: Table1) -> bool:
    return any(
        not table.is_informative(i, j) and table.values[i][j] is not None
        for i in range(len(table.rows))
        for j in range(len(table.columns))
    )


def table1_markdown(table: Table1) -> str:
    """GitHub Markdown; the marked values of each column in bold, then what the marks mean."""
    lines = [
        "| method | " + " | ".join(markdown_cell(c) for c in table.columns) + " | ms/query |",
        "|---|" + "---:|" * (len(table.columns) + 1),
    ]
    for name, texts, time_text in _rows(table, ("**", "**"), "†"):
        lines.append(f"| {markdown_cell(name)} | " + " | ".join(texts) + f" | {time_text} |")
    lines += ["", marks_note(table)]
    if _any_uninformative(table):
        lines += ["", _FOOTNOTE]
    entries = [METHODS.get(name) for name in table.rows if name in METHODS]  # a plugin's in place of a built-in:
    replaced = [f"{entry.name} is {entry.function.__module__}'s method" for entry in entries if entry.replaces]
    if replaced:
        lines += ["", f"{'; '.join(replaced)}: a plugin's, in place of the built-in method of that name."]
    return "\n".join(lines) + "\n"


def table1_csv(table: Table1) -> str:
    """CSV with numeric cells (empty where undefined) and ``best_for``: the columns where the row is marked.

    An uninformative cell keeps its number but never appears in ``best_for``. With a bootstrap, each column ``C``
    is followed by ``C_ci_low`` and ``C_ci_high``, and ``significant_best_for`` lists the columns where the row is
    the best alone, significantly better than every other method.
    """
    marks = table.marks()
    with_ci = table.intervals is not None
    columns = [part for c in table.columns for part in ((c, f"{c}_ci_low", f"{c}_ci_high") if with_ci else (c,))]
    extra = ["significant_best_for"] if with_ci else []
    csv_rows: list[list[object]] = [["method", *columns, "time_per_query_ms", "best_for", *extra]]
    for i, (name, row, time_ms) in enumerate(zip(table.rows, table.values, table.time_ms, strict=True)):
        best_for = [column for j, column in enumerate(table.columns) if marks[i][j]]
        numbers = []
        for j, v in enumerate(row):
            numbers.append("" if v is None else f"{v:.6f}")
            if with_ci:
                numbers += ["", ""] if table.intervals[i][j] is None else [f"{x:.6f}" for x in table.intervals[i][j]]
        numbers.append("" if time_ms is None else f"{time_ms:.6f}")
        sole = [c for j, c in enumerate(table.columns) if marks[i][j] and table.significant and table.significant[j]]
        csv_rows.append([name, *numbers, ";".join(best_for), *([";".join(sole)] if with_ci else [])])
    return _csv_text(csv_rows)


def table1_latex(
    table: Table1,
    *,
    caption: str | None = None,
    label: str | None = None,
    intervals: bool = False,
    width: str | None = r"\columnwidth",
) -> str:
    """A booktabs ``table`` float that fits a column of a two-column paper; the marked values per column in bold.

    Uncertainty methods are rows and VPR methods columns (plus Mean and ms/query), the layout of the published
    tables; since the grid sets how many columns there are, the tabular is shrunk to ``width`` when it is wider
    (never enlarged), rather than dropping columns. Needs :data:`LATEX_PACKAGES` in the preamble.

    Parameters
    ----------
    table : Table1
    caption : str, optional
        Default: the metric, and what the marks mean.
    label : str, optional
        The ``\\label``; default ``tab:<metric>`` (``tab:auc-pr``).
    intervals : bool, default=False
        Show each value's bootstrap interval (when the table has them); they double the width, so off by default.
    width : str or None, default=r"\\columnwidth"
        The most the table may take (``\\textwidth`` in a ``table*``); None: its natural width.
    """
    if caption is None:
        caption = f"{METRIC_NAMES[table.metric][0]} of each uncertainty method, averaged over datasets. "
        caption += marks_note(table) if intervals or table.bootstrap is None else marks_note(table).split(" [low")[0]
    label = label or f"tab:{METRIC_NAMES[table.metric][0].lower()}"
    header = ["Method", *(latex_escape(c) for c in table.columns), "ms/query"]
    rows = [
        [latex_escape(name), *(text.replace("–", "--") for text in [*texts, time_text])]
        for name, texts, time_text in _rows(
            table, (r"\textbf{", "}"), r"$^\dagger$", (r"{\scriptsize ", "}"), intervals=intervals
        )
    ]
    lines = latex_float(caption, label, "l" + "r" * (len(table.columns) + 1), header, rows, width)
    return _end_latex(lines, _any_uninformative(table))


#: Columns of :func:`evaluation_csv` and :func:`evaluation_latex`: key of ``MethodEvaluation.to_dict``, LaTeX header,
#: decimals.
_EVALUATION_COLUMNS = (
    ("auc_pr", "AUC-PR", 4),
    ("average_precision", "AP", 4),
    ("aurc", "AURC", 4),
    ("recall_at_100_precision", "R@100\\%P", 3),
    ("time_per_query_ms", "ms/query", 5),
)


def _exact(value: float | None) -> str:
    return "" if value is None else repr(float(value))


def _recall_levels(evaluation: Evaluation) -> list[float]:
    """The recall levels of the methods' precision at recall (:data:`~vpr_uncertainty.evaluation.RECALL_LEVELS`)."""
    return list(dict.fromkeys(level for method in evaluation.methods.values() for level in method.precision_at_recall))


def evaluation_csv(evaluation: Evaluation) -> str:
    """One row per uncertainty method, the numbers of ``evaluate --json`` at full precision (empty: undefined).

    Columns: ``method``, ``auc_pr``, ``average_precision``, ``aurc``, ``recall_at_100_precision``,
    ``time_per_query_ms``, ``precision_at_recall_<level>``, the retrieval's ``recall@N`` (the same in every row),
    ``informative``, ``best`` (marked as in :func:`format_table`), with a bootstrap ``<metric>_ci_low``/``_ci_high``
    of AUC-PR, AP and AURC.
    """
    marked, levels = _marked(evaluation), _recall_levels(evaluation)
    with_ci = evaluation.bootstrap is not None
    metrics = [key for key, _, _ in _EVALUATION_COLUMNS]
    intervals = [f"{key}_ci_{end}" for key in _WITH_CI for end in ("low", "high")]
    header = ["method", *metrics, *(f"precision_at_recall_{level:g}" for level in levels)]
    header += [*(f"recall@{n}" for n in evaluation.recall_at_n), "informative", "best", *(intervals if with_ci else [])]
    csv_rows: list[list[object]] = [header]
    for name, method in evaluation.methods.items():
        numbers = method.to_dict()
        row = [name, *(_exact(numbers[key]) for key in metrics)]
        row += [_exact(method.precision_at_recall.get(level)) for level in levels]
        row += [_exact(value) for value in evaluation.recall_at_n.values()]
        row += [str(method.informative).lower(), str(name in marked and method.informative).lower()]
        for interval in (getattr(method, f"{key}_ci") for key in _WITH_CI) if with_ci else ():
            row += ["", ""] if interval is None else [_exact(interval[0]), _exact(interval[1])]
        csv_rows.append(row)
    return _csv_text(csv_rows)


def evaluation_latex(
    evaluation: Evaluation,
    *,
    caption: str | None = None,
    label: str = "tab:uncertainty",
    intervals: bool = False,
    width: str | None = r"\columnwidth",
) -> str:
    """One evaluation as a booktabs ``table`` float for a paper: uncertainty methods as rows, the metrics of
    :func:`evaluation_csv` as columns (precision at each recall level included), the retrieval's recall@N in the
    caption. The tabular is shrunk to ``width`` (None: its natural width) if it is wider, never enlarged. The best
    AUC-PR is bold (as starred by :func:`format_table`); ``$^\\dagger$`` marks an uninformative method. The default
    ``caption`` gives the queries, recall@N and what the columns and marks mean; ``intervals`` shows the 95 %
    bootstrap intervals of AUC-PR, AP and AURC (when computed). Needs :data:`LATEX_PACKAGES`.
    """
    marked, levels = _marked(evaluation), _recall_levels(evaluation)
    if caption is None:
        recalls = {n: value for n, value in evaluation.recall_at_n.items() if value is not None}
        caption = f"Uncertainty methods on {evaluation.n_queries} queries"
        numbers = "/".join(f"{value:.3f}" for value in recalls.values())
        caption += f" (recall@{'/'.join(map(str, recalls))} {numbers})" if recalls else ""
        caption += ". AUC-PR, AP: higher is better; AURC: lower is better; P@R=r: precision of the answers accepted "
        caption += "down to recall r. Bold: "
        caption += "best AUC-PR." if evaluation.bootstrap is None else "AUC-PR leaders (none significantly worse)."
        if intervals and evaluation.bootstrap is not None:
            caption += f" [low, high]: {evaluation.bootstrap['confidence']:.0%} bootstrap interval."
    rows = []
    for name, method in evaluation.methods.items():
        numbers = method.to_dict()
        cells = [latex_escape(name) + ("" if method.informative else r"$^\dagger$")]
        for key, _, digits in _EVALUATION_COLUMNS:
            value = numbers[key]
            text = "--" if value is None else f"{value:.{digits}f}"
            if key == "auc_pr" and value is not None and name in marked and method.informative:
                text = rf"\textbf{{{text}}}"
            interval = getattr(method, f"{key}_ci", None) if intervals else None
            if interval is not None:
                text += rf" {{\scriptsize [{interval[0]:.3f}, {interval[1]:.3f}]}}"
            cells.append(text)
        precisions = (method.precision_at_recall.get(level) for level in levels)
        cells[-1:-1] = ["--" if value is None else f"{value:.3f}" for value in precisions]
        rows.append(cells)
    header = ["Method", *(title for _, title, _ in _EVALUATION_COLUMNS)]
    header[-1:-1] = [f"P@R={level:g}" for level in levels]
    lines = latex_float(caption, label, "l" + "r" * (len(header) - 1), header, rows, width)
    return _end_latex(lines, any(not m.informative for m in evaluation.methods.values()))


def table1_html(table: Table1) -> str:
    """An HTML ``<table>``; the marked values per column in bold."""
    head = "".join(f"<th>{escape(c)}</th>" for c in ["method", *table.columns, "ms/query"])
    body = []
    for name, texts, time_text in _rows(table, ("<b>", "</b>"), "†"):
        cells = "".join(f"<td>{text}</td>" for text in [*texts, time_text])
        body.append(f"<tr><th>{escape(name)}</th>{cells}</tr>")
    return f'<table class="table1"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'


def column_distributions(
    cells: Sequence[Any], columns: Sequence[str], n_resamples: int, seed: int
) -> dict[str, dict[tuple[str, str], np.ndarray]]:
    """``metric -> (method, column) -> (B,)``: each column's average over its cells (``Mean``: over the columns),
    per resample; a resample skipped in one cell (one class only) is skipped in the averages that include it."""
    per_cell = [(cell, evaluation_distributions(cell.evaluation, n_resamples, seed)) for cell in cells]
    result: dict[str, dict[tuple[str, str], np.ndarray]] = {}
    for metric in per_cell[0][1] if per_cell else ():
        by_key: dict[tuple[str, str], np.ndarray] = {}
        methods = list(dict.fromkeys(name for cell in cells for name in cell.evaluation.methods))
        for method in methods:
            for column in columns[:-1]:
                found = [
                    distributions[metric][method]
                    for cell, distributions in per_cell
                    if cell.vpr_method == column
                    and getattr(cell.evaluation.methods.get(method), metric, None) is not None
                ]
                if found:
                    by_key[method, column] = np.mean(found, axis=0)
            row = [by_key[method, column] for column in columns[:-1] if (method, column) in by_key]
            if row:
                by_key[method, columns[-1]] = np.mean(row, axis=0)
        result[metric] = by_key
    return result


def table_significance(table: Any, distributions: dict[tuple[str, str], np.ndarray], level: float = 0.05) -> None:
    """Set ``table.intervals`` (95 % percentile) and ``table.leaders`` / ``table.significant`` in place.

    Only informative cells with a value compete in a column; fewer than two: nothing is marked.
    """
    intervals = [
        [
            percentile_interval(distributions[method, column]) if (method, column) in distributions else None
            for column in table.columns
        ]
        for method in table.rows
    ]
    marked = [[False] * len(table.columns) for _ in table.rows]
    significant = []
    for j, column in enumerate(table.columns):
        values = {
            method: table.values[i][j]
            for i, method in enumerate(table.rows)
            if table.values[i][j] is not None and table.is_informative(i, j) and (method, column) in distributions
        }
        names, alone = leaders(
            {method: distributions[method, column] for method in values},
            values,
            higher_is_better=table.higher_is_better,
            level=level,
        )
        for name in names:
            marked[table.rows.index(name)][j] = True
        significant.append(alone)
    table.intervals, table.leaders, table.significant = intervals, marked, significant


# --- ties ---


@dataclass
class TiesTable:
    """rows: uncertainty methods; columns: VPR methods; ``tied_share``/``distinct`` may hold None (no cell)."""

    rows: list[str]
    columns: list[str]
    tied_share: list[list[float | None]]
    distinct: list[list[float | None]]
    n_queries: list[float | None]


def build_ties_table(cells: Sequence) -> TiesTable:
    """Average each method's tied share and distinct values over the datasets of each VPR method."""
    columns = list(dict.fromkeys(cell.vpr_method for cell in cells))
    rows = list(dict.fromkeys(name for cell in cells for name in cell.evaluation.methods))
    shares, distinct = [], []
    for method in rows:
        found = [
            [c.evaluation.methods[method] for c in cells if c.vpr_method == vpr and method in c.evaluation.methods]
            for vpr in columns
        ]
        shares.append([float(np.mean([m.tied_share for m in f])) if f else None for f in found])
        distinct.append([float(np.mean([m.n_distinct for m in f])) if f else None for f in found])
    n_queries = [float(np.mean([c.evaluation.n_queries for c in cells if c.vpr_method == vpr])) for vpr in columns]
    return TiesTable(rows=rows, columns=columns, tied_share=shares, distinct=distinct, n_queries=n_queries)


def ties_markdown(table: TiesTable) -> str:
    """GitHub Markdown: ``97 % (8)`` = 97 % of the queries tied, 8 distinct values."""
    lines = ["| method | " + " | ".join(table.columns) + " |", "|---|" + "---:|" * len(table.columns)]
    for name, shares, distinct in zip(table.rows, table.tied_share, table.distinct, strict=True):
        cells = ["–" if s is None else f"{s:.0%} ({d:.0f})" for s, d in zip(shares, distinct, strict=True)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    queries = ", ".join(f"{n:.0f}" for n in dict.fromkeys(q for q in table.n_queries if q is not None))
    lines += [
        "",
        f"Share of queries whose uncertainty equals another query's (distinct values in brackets; {queries} queries "
        "per cell). The trapezoid AUC-PR interpolates linearly between tied groups: compare it with AP and AURC for "
        "methods with few distinct values.",
    ]
    return "\n".join(lines) + "\n"


def ties_csv(table: TiesTable) -> str:
    """CSV: ``C_tied_share`` and ``C_distinct_values`` for each VPR method ``C`` (empty where undefined)."""
    header = ["method", *(f"{c}_{part}" for c in table.columns for part in ("tied_share", "distinct_values"))]
    csv_rows: list[list[object]] = [header]
    for name, shares, distinct in zip(table.rows, table.tied_share, table.distinct, strict=True):
        pairs = [["", ""] if s is None else [f"{s:.6f}", f"{d:g}"] for s, d in zip(shares, distinct, strict=True)]
        csv_rows.append([name, *(text for pair in pairs for text in pair)])
    return _csv_text(csv_rows)


# --- Table 1 from held-out means (the grid's calibration option) ---


@dataclass
class HeldOutMethod:
    """One method's held-out numbers in the shape Table 1 reads (``auc_pr``, ``time_per_query_ms``, ...)."""

    name: str
    auc_pr: float | None
    auc_pr_std: float | None
    time_per_query_ms: float | None
    informative: bool = True


@dataclass
class HeldOutEvaluationView:
    """The ``methods`` of a cell's held-out evaluation, by name."""

    methods: dict[str, HeldOutMethod] = field(default_factory=dict)


@dataclass
class HeldOutCell:
    """A cell as Table 1 sees it with the calibration option: its names and its held-out numbers."""

    vpr_method: str
    dataset: str
    evaluation: HeldOutEvaluationView


def _held_out_cell(cell: Any) -> HeldOutCell:
    methods = {
        name: HeldOutMethod(
            name,
            *(numbers.get(key) for key in ("auc_pr", "auc_pr_std", "time_per_query_ms")),
            informative=getattr(cell.evaluation.methods.get(name), "informative", True),  # CAL: none on all queries
        )
        for name, numbers in cell.held_out["methods"].items()
    }
    return HeldOutCell(cell.vpr_method, cell.dataset, HeldOutEvaluationView(methods))


def table1_cells(cells: Sequence[Any]) -> list[Any]:
    """The cells Table 1 is built from: ``cells`` themselves, or a :class:`HeldOutCell` of each when they hold a
    held-out evaluation (the calibration option: CAL has no number on all queries, its gate is fitted per split)."""
    if not any(cell.held_out is not None for cell in cells):
        return list(cells)
    missing = [f"{cell.vpr_method} / {cell.dataset}" for cell in cells if cell.held_out is None]
    if missing:
        raise ValueError(f"cells without a held-out evaluation among cells with one: {', '.join(missing)}")
    return [_held_out_cell(cell) for cell in cells]


def table1_note(cells: Sequence[Any]) -> str | None:
    """One sentence saying that Table 1 holds held-out means, with the option's values; None without it."""
    found = next((cell.held_out for cell in cells if cell.held_out is not None), None)
    if found is None:
        return None
    option = found["calibration"]
    return (
        f"AUC-PR on held-out queries: mean over {option['repeats']} random splits (seed {option['seed']}), each "
        f"fitting CAL on {option['fraction']:.0%} of the queries; every method is measured on the same held-out "
        "queries (standard deviations in results.json)."
    )
