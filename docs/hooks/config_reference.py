"""MkDocs hook: the `reproduce` config reference, generated at build time from the one config schema.

The keys, their types and defaults come from the code (``GridConfig``'s dataclass fields, the top-level and input
keys that ``load_config`` accepts, ``CALIBRATION_DEFAULTS``); only the one-line descriptions are written here. A key
without a description, or a description of a key the code no longer has, fails the build (``mkdocs build --strict``
and ``tests/test_docs.py``), so the page cannot drift from the schema.

The page ``docs/reference/reproduce-config.md`` holds the marker below; this hook replaces it with the tables.
"""

from __future__ import annotations

import dataclasses
import sys
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

MARKER = "<!-- generated: reproduce config reference -->"

#: Top-level keys (``GridConfig`` fields, plus the bootstrap keys read into them).
TOP_LEVEL = {
    "out": "Output folder; relative paths are relative to the config file. `--out` overrides it.",
    "inputs": "The cells of the grid: one `[[inputs]]` table per input (keys below); required.",
    "methods": 'Uncertainty methods, each optionally with options after a colon (`"SUE:clip=one-sided"`); a list '
    "or one comma-separated string.",
    "k": "Number of top-k scores the methods read (an integer >= 2).",
    "alpha": "SU's weight between RS (α = 1) and SD (α = 0), in [0, 1].",
    "alphas": "The α values of the α ablation (`figures/ablation_alpha.png`); `[]` skips it.",
    "ks": "The k values of the k ablation (`figures/ablation_k.png`), each >= 2; `[]` skips it.",
    "qualitative": "VPR methods whose cells get the qualitative figure (cells with images only); default: the "
    "figure is drawn where images are given.",
    "report": 'Report figures to write (`["table1", "pr_curves"]`; options as in a method name, '
    '`"qualitative:rank_by=RS"`); default: every figure whose needs the grid meets, including registered ones.',
    "bootstrap": "Paired bootstrap resamples over queries (95 % intervals and significance); 0 = none. "
    "`--bootstrap` overrides it.",
    "seed": "Seed of the bootstrap resamples. `--seed` overrides it.",
    "reference": "The method of the paired tests in `results.json` (one of `methods`; default SU). "
    "`--reference` overrides it.",
    "calibration": 'Held-out evaluation per cell: a table `{fraction, repeats, seed}` (keys below); with `"CAL"` '
    "among the methods Table 1 shows held-out means with a CAL row. Cannot be combined with `bootstrap` yet.",
    "verify_fraction": "Share of queries a cascade `SCORE+GV-*` verifies (the most uncertain by SCORE), in [0, 1]; "
    "only with a cascade among the methods. Default: the cascade's own, 0.3.",
}

#: Keys of one ``[[inputs]]`` table.
INPUTS = {
    "precomputed_matches": "A VPR-Bench `precomputed_matches` folder: one cell per VPR method subfolder holding "
    "`precomputed_data_corrected.npy`. Needs `ground_truth`.",
    "vpr_methods": "With `precomputed_matches`: the subfolders to use (default: all).",
    "scores": "One results file: a similarity matrix `.npy` (needs `ground_truth`) or a retrieval file `.npz`. "
    "Needs `vpr_method` and `dataset`.",
    "vpr_method": "The VPR method's name in the tables (with `scores`; with `model`, default: the model's name).",
    "model": "A descriptor model name: the cell is computed from images by the `run` pipeline. Needs `dataset`.",
    "dataset": "The dataset's name in the tables (with `scores`, `precomputed_matches`: default the folder's name); "
    "with `model`, a dataset folder or a named dataset under `root`.",
    "ground_truth": "Ground truth file (VPR-Bench `ground_truth_new.npy`, a boolean mask `.npy`, `.json`, "
    "`.txt`/`.csv`).",
    "images": "A VPR-Bench folder with `query/` and `ref/`: images for GV-* methods and the qualitative figure.",
    "format": "Results file format (default `auto`).",
    "score_kind": "With `scores` or `precomputed_matches`: what the matrix holds, as `evaluate --scores KIND` reads "
    "it: `similarity` (default), `l2-distance` (`:squared`, `:plain`), `cosine-distance` or `distance`.",
    "root": "With `model`: where named datasets are looked up.",
    "device": "With `model`: `cpu` or `cuda`.",
    "batch_size": "With `model`: images per extraction batch.",
    "index": "With `model`: the Faiss index (default exact search, `Flat`).",
    "split": "With `model`: the dataset split to read.",
}

#: Keys of the ``calibration`` table.
CALIBRATION = {
    "fraction": "Share of each cell's queries CAL is fitted on; every method is measured on the rest.",
    "repeats": "Number of seeded random splits; results are their means (and standard deviations).",
    "seed": "Seed of the splits.",
}


def _type_name(annotation: typing.Any) -> str:
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", repr(annotation))
    return text.replace("typing.", "")


def _default(field: dataclasses.Field) -> str:
    if field.default is not dataclasses.MISSING:
        value = field.default
    elif field.default_factory is not dataclasses.MISSING:
        value = field.default_factory()
    else:
        return "required" if field.name == "inputs" else "`runs/reproduce`"
    if value is None:
        return "none"
    if isinstance(value, list):
        return "`[" + ", ".join(f'"{v}"' if isinstance(v, str) else str(v) for v in value) + "]`"
    return f"`{value}`"


def _check(described: dict, actual: set, what: str) -> None:
    missing, extra = sorted(actual - set(described)), sorted(set(described) - actual)
    if missing or extra:
        raise ValueError(f"{what}: undocumented keys {missing}, documented keys the schema lacks {extra}")


def render() -> str:
    """The Markdown tables of the config reference; raises when the descriptions and the schema disagree."""
    src = str(ROOT / "src")  # this checkout's package (at call time: MkDocs restores sys.path after loading a hook)
    if src not in sys.path:
        sys.path.insert(0, src)
    from vpr_uncertainty.pipeline import grid_config

    if not Path(grid_config.__file__).is_relative_to(ROOT / "src"):
        raise RuntimeError(f"the schema was imported from {grid_config.__file__}, not from this checkout's {src}")

    fields = {field.name: field for field in dataclasses.fields(grid_config.GridConfig)}
    _check(TOP_LEVEL, set(grid_config._TOP_KEYS), "top-level keys")
    _check(TOP_LEVEL, set(fields), "GridConfig fields")
    _check(INPUTS, set(grid_config._INPUT_KEYS), "[[inputs]] keys")
    _check(CALIBRATION, set(grid_config.CALIBRATION_DEFAULTS), "calibration keys")
    lines = ["## Top-level keys", "", "| key | type | default | meaning |", "|---|---|---|---|"]
    for name, field in fields.items():
        lines.append(f"| `{name}` | `{_type_name(field.type)}` | {_default(field)} | {TOP_LEVEL[name]} |")
    lines += ["", "## `[[inputs]]` keys", "", "Give exactly one of `precomputed_matches`, `scores` or `model`.", ""]
    lines += ["| key | meaning |", "|---|---|"]
    lines += [f"| `{name}` | {INPUTS[name]} |" for name in sorted(grid_config._INPUT_KEYS)]
    lines += ["", "## `calibration` keys", "", "| key | default | meaning |", "|---|---|---|"]
    defaults = grid_config.CALIBRATION_DEFAULTS
    lines += [f"| `{name}` | `{default}` | {CALIBRATION[name]} |" for name, default in defaults.items()]
    return "\n".join(lines) + "\n"


def on_page_markdown(markdown: str, page, config, files) -> str:  # MkDocs hook signature
    return markdown.replace(MARKER, render()) if MARKER in markdown else markdown
