"""The configuration of a reproduction grid (see :mod:`vpr_uncertainty.study`): reading and checking it.

:func:`load_config` reads a TOML or YAML file and reports every problem at once, before any work: syntax errors
(one line naming the file and the line), unknown keys, values of the wrong type (naming the key and the value),
missing files, unknown uncertainty methods or method options, unknown report figures (``report``) or their
options, report figures whose needs no input meets, ``vpr_methods`` that do not exist (with the
folders that do), names in ``qualitative`` that match no cell, and every need of every (cell, method) pair that
the cell's inputs cannot meet (positions for SUE, images for GV-*, a head and descriptors for BTL).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vpr_uncertainty.cache import slug
from vpr_uncertainty.methods import default_method_names, get_method, split_method_list
from vpr_uncertainty.study.bootstrap_config import bootstrap_settings
from vpr_uncertainty.study.config_file import read_mapping
from vpr_uncertainty.study.heldout import calibration_option, full_query_methods, runs_cal
from vpr_uncertainty.study.needs import unmet_needs
from vpr_uncertainty.study.report_config import qualitative_methods, report_figures

__all__ = ["DEFAULT_ALPHAS", "DEFAULT_KS", "GridConfig", "InputEntry", "load_config"]

DEFAULT_ALPHAS: tuple[float, ...] = tuple(round(0.1 * i, 1) for i in range(11))
DEFAULT_KS: tuple[int, ...] = (2, 3, 5, 10, 15, 20, 30, 50)
VPRBENCH_FILE = "precomputed_data_corrected.npy"
_BOOTSTRAP_KEYS = ("bootstrap", "seed", "reference")
_TOP_KEYS = {
    "out",
    "methods",
    "k",
    "alpha",
    "alphas",
    "ks",
    "inputs",
    "report",
    "qualitative",
    "calibration",
    "verify_fraction",
    *_BOOTSTRAP_KEYS,
}
_INPUT_KEYS = {
    "precomputed_matches",
    "scores",
    "ground_truth",
    "dataset",
    "images",
    "vpr_methods",
    "vpr_method",
    "model",
    "root",
    "device",
    "batch_size",
    "index",
    "split",
    "format",
}
_RUN_OPTIONS = ("root", "device", "batch_size", "index", "split")


@dataclass(frozen=True)
class InputEntry:
    """One grid cell's input: a results file (matrix or retrieval) or a dataset + model for ``pipeline.run``."""

    vpr_method: str
    dataset: str
    scores: Path | None = None
    ground_truth: Path | None = None
    images: Path | None = None
    model: str | None = None
    dataset_source: str | None = None
    file_format: str = "auto"
    run_options: dict[str, Any] = field(default_factory=dict)

    @property
    def key(self) -> str:
        return f"{slug(self.vpr_method)}__{slug(self.dataset)}"

    def fingerprint(self) -> dict[str, Any]:
        """What the cell's result depends on: the content keys of its files and its options.

        Files are keyed by :func:`vpr_uncertainty.cache.content_key` (size, modification time, hash), so an
        edited results file or ground truth recomputes the cell. Image inputs (``model``) are covered by the
        stages' own caches, whose fingerprints the cell's result carries through the run.
        """
        from vpr_uncertainty.cache import content_key

        files = {}
        for name in ("scores", "ground_truth"):
            path = getattr(self, name)
            if path is not None:
                files[name] = [str(path.resolve()), content_key(path)]
        return {
            **files,
            "model": self.model,
            "dataset_source": self.dataset_source,
            "format": self.file_format,
            "run_options": {k: str(v) for k, v in self.run_options.items()},
        }


@dataclass
class GridConfig:
    """The parsed configuration of a grid (see :mod:`vpr_uncertainty.study`)."""

    out: Path
    inputs: list[InputEntry]
    methods: list[str] = field(default_factory=default_method_names)
    k: int = 10
    alpha: float = 0.5
    alphas: list[float] = field(default_factory=lambda: list(DEFAULT_ALPHAS))
    ks: list[int] = field(default_factory=lambda: list(DEFAULT_KS))
    qualitative: list[str] | None = None
    report: list[str] | None = None
    bootstrap: int = 0
    seed: int = 0
    reference: str | None = None
    calibration: dict[str, Any] | None = None  # {fraction, repeats, seed}: see vpr_uncertainty.study.heldout
    verify_fraction: float | None = None

    def settings(self) -> dict[str, Any]:
        settings = {"methods": self.methods, "k": self.k, "alpha": self.alpha, "alphas": self.alphas, "ks": self.ks}
        if self.bootstrap:  # only then: the caches of grids without a bootstrap stay valid
            settings.update(bootstrap=self.bootstrap, seed=self.seed, reference=self.reference)
        if self.calibration is not None:  # only then: the settings (and cell fingerprints) without it are unchanged
            settings["calibration"] = dict(self.calibration)
        if self.verify_fraction is not None:  # cascades SCORE+GV only
            settings["verify_fraction"] = self.verify_fraction
        return settings

    def method_options(self) -> dict[str, Any]:
        """Options for the uncertainty methods beyond k and α (the cascades' ``verify_fraction``)."""
        return {} if self.verify_fraction is None else {"verify_fraction": self.verify_fraction}


def _numbers(data: dict, key: str, default: Any, kind: type, problems: list[str]) -> list:
    """``data[key]`` as a list of ``kind`` (int or float); a bad value is a problem naming the key and the value."""
    values = data.get(key, default)
    if not isinstance(values, (list, tuple)):
        problems.append(f"{key} must be a list of numbers, got {values!r}")
        return list(default)
    bad = [v for v in values if isinstance(v, bool) or not isinstance(v, int if kind is int else (int, float))]
    if bad:
        what = "integers" if kind is int else "numbers"
        problems.append(f"{key} must be a list of {what}, got {bad[0]!r} in {values!r}")
        return list(default)
    return [kind(v) for v in values]


def _methods(data: dict, problems: list[str]) -> list[str]:
    """The method specs of ``methods`` (a list, or one comma-separated string), each checked."""
    raw = data.get("methods") or default_method_names()
    try:
        specs = split_method_list(raw) if isinstance(raw, str) else raw
    except ValueError as error:
        problems.append(f"methods: {error}")
        return []
    if not isinstance(specs, list) or not all(isinstance(spec, str) for spec in specs):
        problems.append(f'methods must be a list of method names such as ["SU", "SUE:clip=one-sided"], got {raw!r}')
        return []
    if not specs:
        problems.append("methods is empty: name at least one uncertainty method")
    names = []
    for spec in specs:
        try:
            names.append(get_method(spec).name)
        except (KeyError, ValueError, TypeError, ImportError) as error:
            problems.append(str(error.args[0]) if error.args else str(error))
    problems += [
        f"method {name!r} is listed more than once" for name in sorted({n for n in names if names.count(n) > 1})
    ]
    return names


def _vpr_method_folders(folder: Path, wanted: Any, where: str, problems: list[str]) -> list[str]:
    """The method subfolders of a precomputed_matches folder to use; unknown names list the ones there."""
    found = sorted(p.name for p in folder.iterdir() if p.is_dir())
    if wanted is None:
        return found
    if isinstance(wanted, str):
        wanted = [wanted]
    if not isinstance(wanted, list) or not all(isinstance(name, str) for name in wanted):
        problems.append(f"{where}: vpr_methods must be a list of subfolder names of {folder}, got {wanted!r}")
        return []
    lower = {name.lower(): name for name in found}
    for name in wanted:
        if name not in found:
            close = difflib.get_close_matches(name.lower(), list(lower), n=1, cutoff=0.6)
            hint = f"; did you mean {lower[close[0]]!r}?" if close else ""
            problems.append(
                f"{where}: vpr_methods has {name!r}, which is not a folder of {folder}{hint} "
                f"Folders there: {', '.join(found) or 'none'}"
            )
    return [name for name in wanted if name in found]


def _inputs(raw_inputs: Any, problems: list[str]) -> list:
    if isinstance(raw_inputs, dict):
        problems.append(
            "inputs is a single table: write [[inputs]] (two brackets, one block per input) in TOML, or a list "
            "(- precomputed_matches: ...) in YAML; [inputs] defines one table, not a list"
        )
        return [raw_inputs]
    if not isinstance(raw_inputs, list):
        problems.append(f"inputs must be a list of tables ([[inputs]] blocks), got {raw_inputs!r}")
        return []
    return raw_inputs


def load_config(path: str | Path, *, out: str | Path | None = None, **overrides: Any) -> GridConfig:
    """Read and validate a grid configuration; every problem is reported at once, before any work.

    ``overrides`` (``bootstrap``, ``seed``, ``reference``; None = keep the config's) replace the config's values
    before the checks.

    Raises
    ------
    FileNotFoundError
        When the config file is missing.
    ValueError
        Listing every problem found (syntax, missing inputs, unknown methods or keys, bad values, needs of the
        methods that the inputs cannot meet).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"configuration file not found: {path}")
    data = read_mapping(path)
    unknown = sorted(set(overrides) - set(_BOOTSTRAP_KEYS))
    if unknown:
        raise TypeError(f"load_config got unexpected overrides {unknown} (valid: {', '.join(_BOOTSTRAP_KEYS)})")
    data.update({key: value for key, value in overrides.items() if value is not None})
    base = path.resolve().parent
    problems: list[str] = []

    def resolve(value: Any) -> Path:
        candidate = Path(str(value)).expanduser()
        return candidate if candidate.is_absolute() else base / candidate

    problems += [
        f"unknown top-level key {key!r} (expected {sorted(_TOP_KEYS)})" for key in data if key not in _TOP_KEYS
    ]
    methods = _methods(data, problems)
    k = data.get("k", 10)
    alpha = data.get("alpha", 0.5)
    alphas = _numbers(data, "alphas", DEFAULT_ALPHAS, float, problems)
    ks = _numbers(data, "ks", DEFAULT_KS, int, problems)
    if isinstance(k, bool) or not isinstance(k, int) or k < 2:
        problems.append(f"k must be an integer >= 2, got {k!r}")
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float)):
        problems.append(f"alpha must be a number in [0, 1], got {alpha!r}")
        alpha = 0.5
    if not 0.0 <= float(alpha) <= 1.0 or any(not 0.0 <= a <= 1.0 for a in alphas):
        problems.append(f"alpha and alphas must lie in [0, 1], got {alpha!r} and {alphas}")
    if any(v < 2 for v in ks):
        problems.append(f"every k of the k ablation must be >= 2, got {ks}")
    verify_fraction = data.get("verify_fraction")
    if verify_fraction is not None:
        if isinstance(verify_fraction, bool) or not isinstance(verify_fraction, (int, float)):
            problems.append(f"verify_fraction must be a number in [0, 1], got {verify_fraction!r}")
        elif not 0.0 <= verify_fraction <= 1.0:
            problems.append(f"verify_fraction must lie in [0, 1], got {verify_fraction!r}")
        elif not any("+" in name.split(":")[0] for name in methods):
            problems.append("verify_fraction is set but methods has no cascade SCORE+GV (e.g. SU+GV-SIFT)")

    entries: list[InputEntry] = []
    raw_inputs = _inputs(data.get("inputs") or [], problems)
    if not raw_inputs:
        problems.append("no [[inputs]] given: nothing to run")
    for number, raw in enumerate(raw_inputs, 1):
        where = f"inputs #{number}"
        if not isinstance(raw, dict):
            problems.append(f"{where}: expected a table, got {raw!r}")
            continue
        problems += [
            f"{where}: unknown key {key!r} (expected {sorted(_INPUT_KEYS)})" for key in raw if key not in _INPUT_KEYS
        ]
        ground_truth = resolve(raw["ground_truth"]) if "ground_truth" in raw else None
        if ground_truth is not None and not ground_truth.is_file():
            problems.append(f"{where}: ground truth not found: {ground_truth}")
        images = resolve(raw["images"]) if "images" in raw else None
        if images is not None and not ((images / "query").is_dir() and (images / "ref").is_dir()):
            problems.append(f"{where}: images folder {images} must hold query/ and ref/ (a VPR-Bench dataset)")
        file_format = raw.get("format", "auto")
        kinds = [key for key in ("precomputed_matches", "scores", "model") if key in raw]
        if len(kinds) != 1:
            problems.append(f"{where}: give exactly one of precomputed_matches, scores or model (with dataset)")
            continue
        if "precomputed_matches" in raw:
            folder = resolve(raw["precomputed_matches"])
            if not folder.is_dir():
                problems.append(f"{where}: precomputed_matches folder not found: {folder}")
                continue
            if ground_truth is None:
                problems.append(f"{where}: precomputed_matches needs ground_truth")
            dataset = str(raw.get("dataset", folder.name))
            names = _vpr_method_folders(folder, raw.get("vpr_methods"), where, problems)
            for name in names:
                matrix = folder / name / VPRBENCH_FILE
                if not matrix.is_file():
                    problems.append(f"{where}: {matrix} not found")
                    continue
                entries.append(InputEntry(name, dataset, matrix, ground_truth, images, file_format=file_format))
            if not names and raw.get("vpr_methods") is None:
                problems.append(f"{where}: {folder} has no method subfolder")
        elif "scores" in raw:
            scores = resolve(raw["scores"])
            if not scores.is_file():
                problems.append(f"{where}: scores file not found: {scores}")
            if scores.suffix.lower() != ".npz" and ground_truth is None:
                problems.append(f"{where}: the similarity matrix {scores.name} needs ground_truth")
            if "vpr_method" not in raw or "dataset" not in raw:
                problems.append(f"{where}: scores needs vpr_method and dataset names")
                continue
            entries.append(
                InputEntry(
                    str(raw["vpr_method"]), str(raw["dataset"]), scores, ground_truth, images, file_format=file_format
                )
            )
        else:
            if "dataset" not in raw:
                problems.append(f"{where}: model needs dataset (a path or a dataset name)")
                continue
            source = str(raw["dataset"])
            candidate = resolve(source)
            root = resolve(raw["root"]) if "root" in raw else None
            if candidate.exists():
                source = str(candidate)
            elif root is None or not (root / source).exists():
                problems.append(f"{where}: dataset {raw['dataset']!r} not found (neither a path nor under root)")
            options = {key: raw[key] for key in _RUN_OPTIONS if key in raw}
            if root is not None:
                options["root"] = root
            entries.append(
                InputEntry(
                    str(raw.get("vpr_method", raw["model"])),
                    Path(source).name if Path(source).exists() else source,
                    images=images,
                    model=str(raw["model"]),
                    dataset_source=source,
                    run_options=options,
                )
            )
    keys = [entry.key for entry in entries]
    problems += [f"the cell {key} appears more than once" for key in sorted({k for k in keys if keys.count(k) > 1})]
    qualitative = qualitative_methods(data.get("qualitative"), entries, problems)
    calibration = calibration_option(data.get("calibration"), methods, problems)
    calibrated = calibration is not None and runs_cal(methods)
    report = report_figures(data.get("report"), entries, bool(alphas or ks), problems, methods, calibrated=calibrated)

    bootstrap, seed, reference = bootstrap_settings(data, methods, problems)
    if bootstrap and calibration is not None:
        problems.append("bootstrap and calibration cannot be combined yet (the held-out evaluation repeats splits)")
    problems += unmet_needs(entries, full_query_methods(methods, data.get("calibration")))  # of the inputs that exist
    if problems:
        raise ValueError(f"{path}: {len(problems)} problem(s) in the configuration:\n  - " + "\n  - ".join(problems))
    return GridConfig(
        out=Path(out) if out is not None else resolve(data.get("out", "runs/reproduce")),
        inputs=entries,
        methods=list(methods),
        k=int(k),
        alpha=float(alpha),
        alphas=alphas,
        ks=ks,
        qualitative=qualitative,
        report=report,
        bootstrap=bootstrap,
        seed=seed,
        reference=reference,
        calibration=calibration,
        verify_fraction=None if verify_fraction is None else float(verify_fraction),
    )
