"""The configuration of a reproduction grid (``reproduce CONFIG``), read and checked in one place: :func:`load_config`
reads a TOML or YAML file and reports every problem at once, before any work (which problems: see
docs/reference/reproduce-config.md). The schema is in ``reproduce --help``.
"""

from __future__ import annotations

import dataclasses
import difflib
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty._validation import did_you_mean
from vpr_uncertainty.cache import content_key, slug
from vpr_uncertainty.methods import (
    PATH_OPTIONS,
    STAGE_INPUTS,
    default_method_names,
    describe_needs,
    get_method,
    split_method_list,
)
from vpr_uncertainty.plugins import import_or_explain
from vpr_uncertainty.reports.figures import REPORT_FIGURES, parse_figure_spec, unmet_figure_needs
from vpr_uncertainty.retrieval.result import SCORE_KINDS
from vpr_uncertainty.scores import check_alpha


def _unknown(what: str, key: object, expected: list[str]) -> str:
    """``what 'key'; did you mean 'near'? (expected ...)``: a problem naming the near key when there is one."""
    close = difflib.get_close_matches(str(key), expected, n=1, cutoff=0.6)
    return f"{what} {key!r}{f'; did you mean {close[0]!r}?' if close else ''} (expected {', '.join(expected)})"


def read_mapping(path: Path) -> dict[str, Any]:
    """The top-level mapping of a TOML or YAML file; a syntax error is one line naming the file and the line."""
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".yaml", ".yml"):
        raise ValueError(f"unsupported configuration file {path}: expected .toml, .yaml or .yml")
    try:
        if suffix == ".toml":
            import tomllib

            try:
                with path.open("rb") as file:
                    return tomllib.load(file)
            except tomllib.TOMLDecodeError as error:  # its message ends with "(at line L, column C)"
                raise ValueError(f"{path}: invalid TOML: {error}") from None
        yaml = import_or_explain(
            "yaml", f"reading {path} needs pyyaml (pip install pyyaml), or write the config as TOML"
        )
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except yaml.YAMLError as error:
            mark = getattr(error, "problem_mark", None)
            where = f", line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
            problem = getattr(error, "problem", None) or str(error).splitlines()[0]
            raise ValueError(f"{path}{where}: invalid YAML: {problem}") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not a UTF-8 text file ({error.reason} at byte {error.start})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: the configuration must be a mapping at the top level")
    return data


def _integer(value: Any, name: str, low: int, problems: list[str]) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        problems.append(f"{name} must be an integer >= {low}, got {value!r}")
        return None
    return int(value)


def bootstrap_settings(data: dict[str, Any], methods: list[str], problems: list[str]) -> tuple[int, int, str | None]:
    """``(bootstrap, seed, reference)`` of the config; a reference must be one of the grid's methods."""
    bootstrap, seed = (_integer(data.get(key, 0), key, 0, problems) or 0 for key in ("bootstrap", "seed"))
    reference = data.get("reference")
    if reference is not None:
        if not isinstance(reference, str):
            problems.append(f"reference must be a method name, got {reference!r}")
            reference = None
        elif methods and reference not in methods:
            problems.append(
                f"reference {reference!r} (the method of the paired tests) is not among methods ({', '.join(methods)})"
            )
    return bootstrap, seed, reference


#: The keys of the ``calibration`` table, with their defaults.
CALIBRATION_DEFAULTS: dict[str, Any] = {"fraction": 0.3, "repeats": 20, "seed": 0}
_EXAMPLE = "calibration = {fraction = 0.3, repeats = 20, seed = 0}"


def fitted_per_split(spec: str) -> bool:
    """Whether ``spec`` is CAL without a gate file: a gate exists only for the splits of a held-out evaluation.

    Examples
    --------
    >>> fitted_per_split("CAL"), fitted_per_split("CAL:gate=gate.json"), fitted_per_split("SU")
    (True, False, False)
    """
    entry = get_method(spec)
    return (entry.base or entry.name) == "CAL" and not entry.bound.get("gate")


def runs_cal(methods: list[str]) -> bool:
    """Whether ``methods`` holds CAL (with or without a gate file)."""
    return any((get_method(spec).base or get_method(spec).name) == "CAL" for spec in methods)


def full_query_methods(methods: list[str], calibration: dict[str, Any] | None) -> list[str]:
    """The methods evaluated on all queries: ``methods`` less CAL without a gate file when the option is set."""
    return list(methods) if calibration is None else [spec for spec in methods if not fitted_per_split(spec)]


def _number(table: dict, key: str, problems: list[str]) -> Any:
    value = table.get(key, CALIBRATION_DEFAULTS[key])
    if key == "fraction":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < 1.0:
            problems.append(f"calibration.fraction must be a number strictly between 0 and 1, got {value!r}")
            return None
        return float(value)
    return _integer(value, f"calibration.{key}", 1 if key == "repeats" else 0, problems)


def calibration_option(raw: Any, methods: list[str], problems: list[str]) -> dict[str, Any] | None:
    """The checked ``calibration`` table ``{fraction, repeats, seed}`` (missing keys take their defaults), or None.

    Problems (appended to ``problems``): not a table, unknown keys, values of the wrong type or range, no method
    left for the evaluation on all queries, methods the held-out splits cannot serve (a trained BTL head).

    Examples
    --------
    >>> calibration_option({"fraction": 0.5}, ["SU", "CAL"], [])
    {'fraction': 0.5, 'repeats': 20, 'seed': 0}
    >>> problems = []
    >>> calibration_option({"fraction": 1.5, "repeat": 3}, ["SU"], problems)
    >>> problems[0]
    "calibration: unknown key 'repeat'; did you mean 'repeats'? (expected fraction, repeats, seed)"
    """
    if raw is None:
        return None
    if not isinstance(raw, dict):
        problems.append(f"calibration must be a table such as {_EXAMPLE}, got {raw!r}")
        return None
    count = len(problems)
    problems += [
        _unknown("calibration: unknown key", key, list(CALIBRATION_DEFAULTS))
        for key in raw
        if key not in CALIBRATION_DEFAULTS
    ]
    option = {key: _number(raw, key, problems) for key in CALIBRATION_DEFAULTS}
    try:
        entries = [get_method(spec) for spec in methods]  # already checked by the caller; unknown ones skipped
    except (KeyError, ValueError, TypeError, ImportError):
        entries = []
    if entries and not full_query_methods(methods, option):
        problems.append("calibration: methods holds only CAL; add a method to evaluate on all queries (e.g. SU)")
    problems += [
        f"calibration: {entry.name} is not supported by the held-out evaluation (it needs "
        f"{' and '.join(entry.requires)}, which the splits do not pass on); remove it or the calibration table"
        for entry in entries
        if entry.kind == "learned"
    ]
    return option if len(problems) == count else None


#: What the grid gives every method of a cell: a local-feature cache folder; image paths when it has images.
_GRID_OPTIONS = ("cache_dir",)
_IMAGE_OPTIONS = ("query_paths", "database_paths")
#: How a config meets each need (see vpr_uncertainty.methods.NEEDS).
_HINTS = {
    "database_positions": "a retrieval .npz holding database_positions, or a dataset with positions",
    "images": 'images = "FOLDER" (with query/ and ref/) in this input, or a model input',
    "btl_head": 'the option in the method name, e.g. "BTL:btl_head=HEAD.pt"',
    "descriptors": "a model input, or BTL:query_descriptors=DESC.h5,database_descriptors=DESC.h5",
    "local_features": 'the option in the method name, e.g. "GV-H5:features_path=FEATURES.h5"',
    "gate": 'the option in the method name ("CAL:gate=GATE.json"), or calibration = {fraction = 0.3, repeats = 20, '
    "seed = 0} to fit CAL on each split of a held-out evaluation",
}


def _retrieval_fields(entry: InputEntry) -> set[str] | str:
    """Names of the fields a cell's retrieval will have, or a problem (str) when its file cannot be read."""
    if entry.model is not None:
        from vpr_uncertainty.data import load_dataset

        options = entry.run_options
        try:
            dataset = load_dataset(entry.dataset_source, root=options.get("root"), split=options.get("split"))
        except (OSError, ValueError, KeyError) as error:
            return f"dataset {entry.dataset_source!r} cannot be read: {error}"
        return {key for key, value in dataset.retrieval_fields().items() if value is not None}
    fields = {"scores", "indices", "distances", "positives"}
    is_retrieval = entry.file_format == "retrieval" or (
        entry.file_format == "auto" and entry.scores.suffix.lower() == ".npz"
    )
    if is_retrieval:
        try:
            with zipfile.ZipFile(entry.scores) as archive:
                fields = {name.removesuffix(".npy") for name in archive.namelist()}
        except (OSError, zipfile.BadZipFile) as error:
            return f"{entry.scores} is not a readable retrieval file (.npz): {error}"
    return fields


def _inputs_exist(entry: InputEntry) -> bool:
    if entry.model is None:
        return entry.scores is not None and entry.scores.is_file()
    root = entry.run_options.get("root")
    return Path(entry.dataset_source).exists() or (root is not None and (Path(root) / entry.dataset_source).exists())


def unmet_needs(entries: list[InputEntry], methods: list[str]) -> list[str]:
    """Every (cell, method) pair whose method needs what the cell's inputs do not give, one line each.

    A cell gives its retrieval's fields (a retrieval file's arrays, the positions of a dataset), the image files
    when it has images (``images`` or a model input), the descriptors for a model input, and a feature cache.
    """
    found = [get_method(name) for name in methods]
    lines = []
    for entry in entries:
        if not _inputs_exist(entry):
            continue  # reported as missing by the config loader
        cell = f"cell {entry.vpr_method} / {entry.dataset}"
        given = {*_GRID_OPTIONS, *(_IMAGE_OPTIONS if entry.images is not None else ())}
        if entry.model is not None:
            given |= STAGE_INPUTS
        if any(method.unmet_needs(given) for method in found):  # read the inputs only when it matters
            fields = _retrieval_fields(entry)
            if isinstance(fields, str):
                lines.append(f"{cell}: {fields}")
                continue
            given |= fields
        for method in found:
            for need in method.unmet_needs(given):
                hint = f"; give {_HINTS[need]}" if need in _HINTS else ""
                lines.append(f"{cell}: {method.name} needs {describe_needs([need])}{hint}")
    return lines


def qualitative_methods(raw: Any, entries: list[InputEntry], problems: list[str]) -> list[str] | None:
    """The VPR methods whose cells get a qualitative figure; a name that matches no cell is a problem."""
    if raw is None:
        return None
    names = [raw] if isinstance(raw, str) else raw
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        problems.append(f"qualitative must be a list of VPR method names (cells of the grid), got {raw!r}")
        return None
    known = sorted({entry.vpr_method for entry in entries})
    with_images = {entry.vpr_method for entry in entries if entry.images is not None or entry.model is not None}
    for name in names:
        if name not in known:
            hint = did_you_mean(name, known)
            problems.append(
                f"qualitative names {name!r}, which is no VPR method of the grid{'; ' + hint if hint else ' '}"
                f"VPR methods: {', '.join(known)}"
            )
        elif name not in with_images:
            problems.append(f"qualitative names {name!r}, but no input of that VPR method has images (images = ...)")
    return names


def report_figures(
    raw: Any,
    entries: list[InputEntry],
    ablations: bool,
    problems: list[str],
    methods: Sequence[str] = (),
    *,
    calibrated: bool = False,
) -> list[str] | None:
    """The report figures to write (names or specs, see :mod:`vpr_uncertainty.reports.figures`); None: all.

    ``methods`` (the grid's uncertainty methods) tell whether the cascade figure can be drawn; ``calibrated``: CAL
    runs on held-out queries (the ``calibration`` option with CAL among the methods).
    """
    if raw is None:
        return None
    try:
        specs = split_method_list(raw) if isinstance(raw, str) else raw
    except ValueError as error:
        problems.append(f"report: {error}")
        return None
    if not isinstance(specs, list) or not all(isinstance(spec, str) for spec in specs):
        problems.append(f'report must be a list of report figure names such as ["table1", "pr_curves"], got {raw!r}')
        return None
    if not specs:
        problems.append(f"report is empty: name at least one report figure ({', '.join(REPORT_FIGURES.names())})")
    available = {"evaluation", "uncertainties"} | ({"ablations"} if ablations else set())
    if calibrated:
        available.add("calibration")
    if any(entry.images is not None or entry.model is not None for entry in entries):
        available.add("images")
    bases = {name.split(":")[0] for name in methods}
    if any(set(name.split("+")) <= bases for name in bases if name.count("+") == 1):
        available.add("cascade")
    names = []
    for spec in specs:
        try:
            name, _ = parse_figure_spec(spec)
        except (KeyError, ValueError) as error:
            problems.append(str(error.args[0]) if error.args else str(error))
            continue
        names.append(name)
        note = unmet_figure_needs(REPORT_FIGURES.get(name), available)
        if note:
            problems.append(f"{note}, which no input of the grid gives")
    problems += [
        f"report figure {name!r} is listed more than once" for name in sorted({n for n in names if names.count(n) > 1})
    ]
    return list(specs)


DEFAULT_ALPHAS: tuple[float, ...] = tuple(round(0.1 * i, 1) for i in range(11))
DEFAULT_KS: tuple[int, ...] = (2, 3, 5, 10, 15, 20, 30, 50)
VPRBENCH_FILE = "precomputed_data_corrected.npy"
_OVERRIDES = ("bootstrap", "seed", "reference", "verify_fraction")
_RUN_OPTIONS = ("root", "device", "batch_size", "index", "split")
_INPUT_KEYS = {
    "precomputed_matches",
    "scores",
    "ground_truth",
    "dataset",
    "images",
    "vpr_methods",
    "vpr_method",
    "model",
    "format",
    "score_kind",
    *_RUN_OPTIONS,
}


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
    score_kind: str = "similarity"  # what a matrix holds: a kind of SCORE_KINDS

    @property
    def key(self) -> str:
        return f"{slug(self.vpr_method)}__{slug(self.dataset)}"

    def fingerprint(self) -> dict[str, Any]:
        """What the cell's result depends on: the content keys of its files and its options.

        Files are keyed by :func:`vpr_uncertainty.cache.content_key` (size, modification time, hash), so an
        edited results file or ground truth recomputes the cell. Image inputs (``model``) are covered by the
        stages' own caches, whose fingerprints the cell's result carries through the run.
        """
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
            **({"score_kind": self.score_kind} if self.score_kind != "similarity" else {}),  # the caches before it
        }


@dataclass
class GridConfig:
    """The parsed configuration of a grid (``reproduce --help``)."""

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
    calibration: dict[str, Any] | None = None  # {fraction, repeats, seed}: held-out evaluation per cell
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


#: The top-level keys of a configuration: the fields of :class:`GridConfig`.
_TOP_KEYS = {field.name for field in dataclasses.fields(GridConfig)}


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


def _config_relative(spec: str, base: Path) -> str:
    """``spec`` with each option that names a file (:data:`~vpr_uncertainty.methods.PATH_OPTIONS`, or a value that
    is a file beside the config) resolved against the config's folder ``base``: ``CAL:gate=gate.json``."""
    name, colon, rest = spec.partition(":")
    items = []
    for item in rest.split(",") if colon else ():
        key, equals, value = (part.strip() for part in item.partition("="))
        path = base / Path(value).expanduser() if equals and value else None
        items.append(f"{key}={path}" if path and (key in PATH_OPTIONS or path.is_file()) else item.strip())
    return f"{name}:{','.join(items)}" if colon else spec


def _methods(data: dict, problems: list[str], base: Path = Path()) -> list[str]:
    """The method specs of ``methods`` (a list, or one comma-separated string), each checked, with the files
    their options name resolved against the config's folder ``base``."""
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
            names.append(get_method(_config_relative(spec, base)).name)
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
    for name in wanted:
        if name not in found:
            hint = did_you_mean(name, found)
            problems.append(
                f"{where}: vpr_methods has {name!r}, which is not a folder of {folder}{'; ' + hint if hint else ' '}"
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

    ``overrides`` (``bootstrap``, ``seed``, ``reference``, ``verify_fraction``; None = keep the config's) replace the
    config's values before the checks.

    Raises
    ------
    FileNotFoundError
        When the config file is missing.
    ValueError
        Listing every problem found (syntax, missing inputs, unknown methods or keys, bad values, needs of the
        methods that the inputs cannot meet).
    """
    path = Path(path)
    if not is_regular_file(path, "a configuration file"):
        raise FileNotFoundError(f"configuration file not found: {path}")
    data = read_mapping(path)
    unknown = sorted(set(overrides) - set(_OVERRIDES))
    if unknown:
        raise TypeError(f"load_config got unexpected overrides {unknown} (valid: {', '.join(_OVERRIDES)})")
    data.update({key: value for key, value in overrides.items() if value is not None})
    base = path.resolve().parent
    problems: list[str] = []

    def resolve(value: Any) -> Path:
        candidate = Path(str(value)).expanduser()
        return candidate if candidate.is_absolute() else base / candidate

    problems += [_unknown("unknown top-level key", key, sorted(_TOP_KEYS)) for key in data if key not in _TOP_KEYS]
    methods = _methods(data, problems, base)
    k = _integer(data.get("k", 10), "k", 2, problems)
    alpha = data.get("alpha", 0.5)
    alphas = _numbers(data, "alphas", DEFAULT_ALPHAS, float, problems)
    ks = _numbers(data, "ks", DEFAULT_KS, int, problems)
    for name, value in [("alpha", alpha), *((f"alphas[{i}]", a) for i, a in enumerate(alphas))]:
        try:
            check_alpha(value, name=name)  # the one check of the range
        except (TypeError, ValueError) as error:
            problems.append(str(error))
    alpha = alpha if isinstance(alpha, (int, float)) and not isinstance(alpha, bool) else 0.5
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
            _unknown(f"{where}: unknown key", key, sorted(_INPUT_KEYS)) for key in raw if key not in _INPUT_KEYS
        ]
        ground_truth = resolve(raw["ground_truth"]) if "ground_truth" in raw else None
        if ground_truth is not None and not ground_truth.is_file():
            problems.append(f"{where}: ground truth not found: {ground_truth}")
        images = resolve(raw["images"]) if "images" in raw else None
        if images is not None and not ((images / "query").is_dir() and (images / "ref").is_dir()):
            problems.append(f"{where}: images folder {images} must hold query/ and ref/ (a VPR-Bench dataset)")
        reading = {"file_format": raw.get("format", "auto"), "score_kind": raw.get("score_kind", "similarity")}
        if reading["score_kind"] not in SCORE_KINDS or ("model" in raw and "score_kind" in raw):  # a model's: cosine
            what = f"{where}: score_kind (what the matrix of scores or precomputed_matches holds)"
            problems.append(_unknown(what, reading["score_kind"], list(SCORE_KINDS)))
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
                entries.append(InputEntry(name, dataset, matrix, ground_truth, images, **reading))
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
                InputEntry(str(raw["vpr_method"]), str(raw["dataset"]), scores, ground_truth, images, **reading)
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
