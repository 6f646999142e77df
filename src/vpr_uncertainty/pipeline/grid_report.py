"""The result of a grid cell (:class:`Cell`) and the files a grid writes: results.json/csv, the report figures
and report.html.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import atomic_write, write_json
from vpr_uncertainty.evaluation import Evaluation
from vpr_uncertainty.pipeline.grid_config import GridConfig
from vpr_uncertainty.reports.figures import REPORT_FIGURES, parse_figure_spec, unmet_figure_needs
from vpr_uncertainty.reports.html import Section, averaged_over, settings_table, write_report
from vpr_uncertainty.reports.plots import cascades
from vpr_uncertainty.reports.style import figure_width, study_styles
from vpr_uncertainty.reports.tables import csv_cell

CSV_FIELDS = (
    "vpr_method",
    "dataset",
    "uncertainty_method",
    "auc_pr",
    "average_precision",
    "aurc",
    "time_per_query_ms",
    "recall_at_100_precision",
    "n_queries",
)
_UNCERTAINTY = "uncertainty/"
_OWN_CORRECT = "correct/"


def _float_key(value: float) -> str:
    """``f"{value:g}"`` (the key format of ``results.json``), or the exact ``repr`` when ``:g`` would round."""
    text = f"{value:g}"
    return text if float(text) == value else repr(float(value))


@dataclass
class Cell:
    """Everything the reports need from one (VPR method, dataset) cell.

    Attributes
    ----------
    vpr_method, dataset : str
        The cell's row and column.
    evaluation : Evaluation
        Every uncertainty method's numbers and uncertainties.
    scores, indices : ndarray of shape (Q, K)
        The retrieval's top-K similarities (float32) and database indices.
    ablation_alpha : dict of float to float or None
        AUC-PR of SU for each α (None when undefined).
    ablation_k : dict of str to dict of int to float or None
        AUC-PR of RS and SD for each k.
    hits : ndarray of shape (Q, H), bool, optional
        Whether each of the first H candidates is a positive.
    query_paths, database_paths : list of str, optional
        The images, when the cell has them.
    held_out : dict, optional
        The held-out evaluation of the grid's ``calibration`` option (every method's mean and std over the splits,
        CAL's calibration quality; :func:`~vpr_uncertainty.pipeline.grid.held_out_evaluation`); None without it.
    cached : bool
        Whether the cell was read from the cache.
    stage_seconds : dict of str to float, optional
        Seconds of each stage of the run that computed the cell (``input``: reading the results file, or the
        pipeline with its own stages as ``pipeline_<stage>``; ``uncertainty_and_evaluation``; ``ablations``).
    """

    vpr_method: str
    dataset: str
    evaluation: Evaluation
    scores: np.ndarray
    indices: np.ndarray
    ablation_alpha: dict[float, float | None]
    ablation_k: dict[str, dict[int, float | None]]
    hits: np.ndarray | None = None
    query_paths: list[str] | None = None
    database_paths: list[str] | None = None
    held_out: dict[str, Any] | None = None
    cached: bool = False
    stage_seconds: dict[str, float] | None = None

    def uncertainties(self) -> dict[str, np.ndarray]:
        """Each uncertainty method's stored uncertainties, shape (Q,), by method name."""
        return {name: method.uncertainty for name, method in self.evaluation.methods.items()}

    def rows(self) -> list[dict[str, Any]]:
        """Long-format rows (the fields of ``results.csv``), one per uncertainty method."""
        recalls = {f"recall@{n}": value for n, value in self.evaluation.recall_at_n.items()}
        return [
            {
                "vpr_method": self.vpr_method,
                "dataset": self.dataset,
                "uncertainty_method": name,
                **{key: metrics.get(key) for key in CSV_FIELDS[3:-1]},
                "n_queries": self.evaluation.n_queries,
                **recalls,
            }
            for name, metrics in ((name, method.to_dict()) for name, method in self.evaluation.methods.items())
        ]

    def to_dict(self) -> dict[str, Any]:
        """The cell's entry in ``results.json``: its names, ``Evaluation.to_dict()``, the ablations and, with the
        grid's calibration option, ``held_out``."""
        return {
            "vpr_method": self.vpr_method,
            "dataset": self.dataset,
            **self.evaluation.to_dict(),
            "ablation_alpha": {_float_key(a): v for a, v in self.ablation_alpha.items()},
            "ablation_k": {name: {str(k): v for k, v in c.items()} for name, c in self.ablation_k.items()},
            **({"held_out": self.held_out} if self.held_out is not None else {}),
            **({"stage_seconds": dict(self.stage_seconds)} if self.stage_seconds is not None else {}),
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """What :meth:`to_dict` leaves out, by name (``uncertainty/NAME`` per method; ``correct/NAME`` for a
        method judged by its own retrieval)."""
        arrays = {"correct": self.evaluation.correct, "scores": self.scores, "indices": self.indices}
        if self.hits is not None:
            arrays["hits"] = self.hits
        for name, method in self.evaluation.methods.items():
            arrays[_UNCERTAINTY + name] = method.uncertainty
            if method.correct is not None:
                arrays[_OWN_CORRECT + name] = method.correct
        return arrays

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        arrays: Mapping[str, np.ndarray],
        *,
        query_paths: list[str] | None = None,
        database_paths: list[str] | None = None,
        cached: bool = False,
    ) -> Cell:
        """The inverse of :meth:`to_dict` and :meth:`arrays`.

        Parameters
        ----------
        data : mapping
            What :meth:`to_dict` returned.
        arrays : mapping of str to ndarray
            What :meth:`arrays` returned.
        query_paths, database_paths : list of str, optional
            The cell's images.
        cached : bool, default=False
            Whether the cell comes from the cache.

        Returns
        -------
        Cell

        Raises
        ------
        KeyError
            When ``data`` or ``arrays`` lacks an entry.
        """
        evaluation = Evaluation.from_dict(
            data,
            correct=arrays["correct"],
            uncertainties={k[len(_UNCERTAINTY) :]: v for k, v in arrays.items() if k.startswith(_UNCERTAINTY)},
            own_correct={k[len(_OWN_CORRECT) :]: v for k, v in arrays.items() if k.startswith(_OWN_CORRECT)},
        )
        return cls(
            vpr_method=data["vpr_method"],
            dataset=data["dataset"],
            evaluation=evaluation,
            scores=arrays["scores"],
            indices=arrays["indices"],
            hits=arrays.get("hits"),
            ablation_alpha={float(a): v for a, v in data["ablation_alpha"].items()},
            ablation_k={name: {int(k): v for k, v in c.items()} for name, c in data["ablation_k"].items()},
            query_paths=query_paths,
            database_paths=database_paths,
            held_out=data.get("held_out"),
            cached=cached,
            stage_seconds=data.get("stage_seconds"),
        )


def write_results(cells: Sequence[Cell], config: GridConfig) -> dict[str, Path]:
    """Write ``results.json`` (every cell's evaluation and ablations) and the long-format ``results.csv``.

    With the grid's calibration option, ``results.json`` records it (``"calibration": {fraction, repeats, seed}``)
    and each cell's held-out means and standard deviations (``"held_out"``).

    Parameters
    ----------
    cells : sequence of Cell
        The grid's results (see :func:`~vpr_uncertainty.pipeline.grid.run_grid`).
    config : GridConfig
        The grid's settings and output folder.

    Returns
    -------
    dict of str to Path
        ``results_json`` and ``results_csv``.
    """
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    document: dict[str, Any] = {"settings": config.settings()}
    if config.calibration is not None:  # the held-out option: each cell then holds "held_out"
        document["calibration"] = dict(config.calibration)
    document["cells"] = [cell.to_dict() for cell in cells]
    json_path = write_json(out / "results.json", document)
    rows = [row for cell in cells for row in cell.rows()]
    recall_fields = sorted({key for row in rows for key in row if key.startswith("recall@")}, key=lambda s: int(s[7:]))
    csv_path = out / "results.csv"
    with atomic_write(csv_path, newline="") as file:
        writer = csv.DictWriter(file, fieldnames=[*CSV_FIELDS, *recall_fields])
        writer.writeheader()
        writer.writerows({key: csv_cell(value) for key, value in row.items()} for row in rows)
    return {"results_json": json_path, "results_csv": csv_path}


def write_reports(
    cells: Sequence[Cell],
    config: GridConfig,
    *,
    html: bool = True,
    figures: Sequence[str] | None = None,
    width: str | None = None,
) -> dict[str, Any]:
    """Every selected report figure (:data:`~vpr_uncertainty.reports.figures.REPORT_FIGURES`), then ``report.html``.

    The built-in figures are Table 1 (md, csv, tex), the ΔAUC-PR heatmaps, the ablations, the PR curves and the
    qualitative figures; a registered figure (:func:`~vpr_uncertainty.reports.register_report_figure`) is written
    after them and gets its own section of ``report.html``. A figure whose needs the cells do not meet (no
    images, no ablation) is not written; its section says why.

    Parameters
    ----------
    cells : sequence of Cell
        The grid's results; the figures receive them with their stored uncertainties.
    config : GridConfig
        The grid's settings and output folder; ``config.report`` selects the figures (default: every registered
        one) and ``config.qualitative`` the VPR methods with a qualitative figure.
    html : bool, default=True
        Also write ``report.html``.
    figures : sequence of str, optional
        Figure names or specs (``"qualitative:rank_by=RS"``) to write instead of ``config.report``.
    width : {"page", "column"}, optional
        The width of every figure that has a ``width`` option and whose spec sets none (``reproduce
        --figure-width``); by default each figure's own (page: 7.16 in).

    Returns
    -------
    dict of str to list of Path or Path
        The files each figure wrote, by figure name; each file other than a figure (PNG, PDF, SVG) also under
        ``<name>_<suffix>`` when it is the figure's only file of that suffix (``table1_md``, ``table1_csv``,
        ``table1_tex``); and ``report_html``.

    Raises
    ------
    KeyError
        For an unknown figure name (naming the closest one and listing the available ones).
    ValueError
        For an unknown option of a figure, or a bad value.
    """
    if width is not None:
        figure_width(width)  # a bad width fails before any figure is drawn

    specs = figures if figures is not None else config.report
    selected = [parse_figure_spec(spec) for spec in (REPORT_FIGURES.names() if specs is None else specs)]
    out = Path(config.out)
    available = _available_needs(cells)
    paths: dict[str, Any] = {}
    sections = []
    with study_styles([name for cell in cells for name in cell.evaluation.methods], [c.vpr_method for c in cells]):
        for name, options in selected:
            entry = REPORT_FIGURES.get(name)
            if width is not None and "width" in entry.options and "width" not in options:
                options = {**options, "width": width}
            note = unmet_figure_needs(entry, available)
            written = [] if note else entry.write(cells, config, out, **options)
            paths[name] = written
            suffixes = [path.suffix for path in written]
            for path in written:
                if path.suffix not in (".png", ".pdf", ".svg") and suffixes.count(path.suffix) == 1:
                    paths[f"{name}_{path.suffix.lstrip('.')}"] = path
            body = "" if note else entry.section_html(cells, config, written, **options)
            if entry.title and entry.description:
                body = f'<p class="note">{escape(entry.description)}</p>' + body
            if note:
                body += f'<p class="note">Not written: {escape(note)}.</p>'
            pngs = [
                (entry.caption_of(cells, config, path, **options), path)
                for path in written
                if path.suffix.lower() == ".png"
            ]
            heading = entry.heading.replace("{where}", averaged_over(cells) if cells else "")  # "on corridor", ...
            sections.append(Section(heading, body, figures=pngs))
    if html:
        intro = settings_table(cells, config)
        paths["report_html"] = write_report(
            out / "report.html", "vpr-uncertainty: reproduction report", sections, intro=intro
        )
    return paths


def _available_needs(cells: Sequence[Cell]) -> set[str]:
    """The needs of report figures (:data:`~vpr_uncertainty.reports.figures.FIGURE_NEEDS`) the cells meet."""
    available = {"evaluation", "uncertainties"}
    if any(cell.query_paths and cell.database_paths for cell in cells):
        available.add("images")
    if any(cell.ablation_alpha for cell in cells) or any(curve for c in cells for curve in c.ablation_k.values()):
        available.add("ablations")
    if any("CAL" in (cell.held_out or {}).get("calibration_quality", {}) for cell in cells):
        available.add("calibration")
    if cascades(cells):
        available.add("cascade")
    return available
