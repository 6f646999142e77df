"""Readers of what a user brings: results files (retrieval files, similarity matrices, VPR-Bench, VPR-methods-evaluation
logs) and descriptor files."""

from __future__ import annotations

import ast
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.data.dataset import attach_ground_truth, ground_truth_fields
from vpr_uncertainty.data.ground_truth import load_ground_truth, read_npy
from vpr_uncertainty.data.images import is_hidden
from vpr_uncertainty.plugins import Registry, load_plugins, load_target
from vpr_uncertainty.retrieval.blocks import DescriptorRows, MappedRows, top_k_blocks
from vpr_uncertainty.retrieval.file_format import load_retrieval
from vpr_uncertainty.retrieval.result import SCORE_KINDS, Retrieval, check_positive_int
from vpr_uncertainty.retrieval.search import retrieve

#: Candidates kept per query when a full matrix is read, unless a larger k asks for more (recall@20 needs 20).
DEFAULT_TOP_K = 50
DESCRIPTOR_SPLITS: tuple[str, ...] = ("database", "queries")
DESCRIPTOR_SUFFIXES: tuple[str, ...] = (".npy", ".h5", ".hdf5")


# --- results formats: what read_results reads ------------------------------------------------------------------


@dataclass(frozen=True)
class ResultsFormat:
    """One format of precomputed results that :func:`read_results` reads.

    Attributes
    ----------
    name, description : str
    reader : callable or str
        ``reader(path, *, ground_truth, top_k) -> Retrieval``, or its dotted path ``"module:function"``; with
        ``reads_distances``, it also takes ``scores=`` a kind of :data:`~vpr_uncertainty.retrieval.result.SCORE_KINDS`.
    detect : callable or None
        ``detect(path) -> bool``: whether ``file_format="auto"`` reads ``path`` with this format (formats are tried
        in registration order). None: only read when named.
    provides : tuple of str
        What a file of this format gives the methods (``"scores"``, ``"distances"``, ``"positives"``, ``"names"``).
    extra : str or None
        The pip extra its reader needs.
    reads_distances : bool
        Whether a file of this format may hold distances (``read_results(scores=...)``).
    """

    name: str
    description: str
    reader: Callable[..., Retrieval] | str
    detect: Callable[[Path], bool] | None = None
    provides: tuple[str, ...] = ()
    extra: str | None = None
    reads_distances: bool = False


#: The registered results formats, in detection order.
RESULTS_FORMAT_REGISTRY: Registry[ResultsFormat] = Registry("results format", label="formats")


def register_results_format(entry: ResultsFormat, *, overwrite: bool = False) -> ResultsFormat:
    """Add a results format (``file_format="auto"`` tries it after the ones registered before it)."""
    return RESULTS_FORMAT_REGISTRY.register(entry, overwrite=overwrite)


def input_formats() -> tuple[str, ...]:
    """The values of ``read_results(file_format=...)``: ``"auto"`` and every registered results format."""
    load_plugins()
    return ("auto", *RESULTS_FORMAT_REGISTRY.names())


def read_results(
    path: str | Path,
    *,
    ground_truth: str | Path | None = None,
    file_format: str = "auto",
    top_k: int = DEFAULT_TOP_K,
    scores: str = "similarity",
    higher_is_better: bool = True,
) -> Retrieval:
    """Read precomputed results and their ground truth into a Retrieval.

    Parameters
    ----------
    path : str or Path
        A retrieval ``.npz``, a similarity matrix ``.npy`` (higher = more similar), a VPR-Bench
        precomputed-matches file, or the log folder of VPR-methods-evaluation run with ``--save_descriptors``
        (its ground truth is derived when not given).
    ground_truth : str or Path, optional
        Ground-truth file; required unless the results hold their positives. When given, it replaces the positives
        stored in a retrieval file.
    file_format : str, default="auto"
        A name of :data:`RESULTS_FORMAT_REGISTRY` (``"retrieval"``, ``"matrix"``, ``"vprbench"``,
        ``"vpr-methods-evaluation"``, or a plugin's); ``"auto"``: the first registered format whose ``detect``
        accepts the path, else a similarity matrix, plain or VPR-Bench's, as the file holds.
    top_k : int
        Candidates kept per query when a full matrix is read (all of them when the database is smaller); pass at
        least the largest k the methods will use. A retrieval file keeps the candidates it holds.
    scores : str, default="similarity"
        What a matrix holds (:data:`~vpr_uncertainty.retrieval.result.SCORE_KINDS`): similarities, higher = more
        similar; or distances, whose k smallest values per query are kept and converted by
        :meth:`~vpr_uncertainty.retrieval.Retrieval.from_distances` (``"cosine-distance"`` and ``"l2-distance"``
        of unit-norm descriptors into exact cosine similarities, ``"distance"`` negated). A retrieval file stores
        similarities (other kinds are refused); a log folder is searched again by cosine similarity (the ranking of
        its L2 distances), so ``"l2-distance"`` and ``"cosine-distance"`` are accepted there and ``"distance"`` not.
    higher_is_better : bool, default=True
        False: ``scores="distance"`` (the earlier spelling).
    """
    path = Path(path)
    if not isinstance(higher_is_better, bool):
        raise TypeError(f"higher_is_better must be True or False, got {higher_is_better!r}")
    if scores not in SCORE_KINDS:
        raise ValueError(f"scores must be one of {SCORE_KINDS}, got {scores!r}")
    scores = "distance" if not higher_is_better and scores == "similarity" else scores
    if file_format == "auto":  # among the formats registered so far (the CLI loads the plugins first)
        entry = next((entry for entry in RESULTS_FORMAT_REGISTRY if entry.detect and entry.detect(path)), None)
        if entry is None:
            return _read_matrix(path, ground_truth=ground_truth, top_k=top_k, file_format="auto", scores=scores)
    else:
        try:
            entry = RESULTS_FORMAT_REGISTRY.get(file_format)  # a miss loads the plugins
        except KeyError:
            raise ValueError(f"file_format must be one of {input_formats()}, got {file_format!r}") from None
    reader = load_target(entry.reader, what=f"results format {entry.name!r}", extra=entry.extra)
    if scores == "similarity" or (entry.name == "vpr-methods-evaluation" and scores != "distance"):
        return reader(path, ground_truth=ground_truth, top_k=top_k)
    if not entry.reads_distances:
        raise ValueError(
            f"{path} is read as {entry.description}, whose scores are similarities; lower-is-better scores "
            "(distances) are read from a similarity or distance matrix only (formats: "
            f"{', '.join(e.name for e in RESULTS_FORMAT_REGISTRY if e.reads_distances)})"
        )
    return reader(path, ground_truth=ground_truth, top_k=top_k, scores=scores)


def _read_retrieval_file(path: Path, *, ground_truth: str | Path | None, **_: Any) -> Retrieval:
    if is_regular_file(path, "a retrieval file"):
        with path.open("rb") as handle:
            if handle.read(6) == b"\x93NUMPY":
                raise ValueError(
                    f"{path} is a .npy array, not a retrieval file (a .npz archive with scores and indices); "
                    "read it as a similarity matrix (format 'matrix' or 'auto')"
                )
    retrieval = load_retrieval(path)
    if ground_truth is not None:
        n_database = retrieval.positives.shape[1] if retrieval.positives is not None else None
        retrieval.positives = load_ground_truth(ground_truth, n_queries=retrieval.n_queries, n_database=n_database)
        retrieval.config.pop("positives_vs_mean", None)  # measured against the positives replaced
        retrieval.__post_init__()
    return retrieval


def _read_matrix(
    path: Path,
    *,
    ground_truth: str | Path | None,
    top_k: int,
    file_format: str = "matrix",
    scores: str = "similarity",
    **_: Any,
) -> Retrieval:
    from vpr_uncertainty.evaluation.metrics import positives_against_mean

    if ground_truth is None:
        raise ValueError(
            f"{path} is a similarity matrix without ground truth; give the ground truth (argument ground_truth)"
        )
    higher_is_better = scores == "similarity"
    read: dict[str, Any] = {"ordering": [0, 0], "largest": 0.0}  # queries whose positives score above / below

    def measure(block: np.ndarray, first_row: int, shape: tuple[int, int]) -> None:
        if first_row == 0:  # sized by the matrix: a positive beyond its columns is an error naming the file
            read["positives"] = load_ground_truth(ground_truth, n_queries=shape[0], n_database=shape[1])
        rows, columns = read["positives"][first_row : first_row + len(block)].nonzero()
        for side, count in enumerate(positives_against_mean(block if higher_is_better else -block, rows, columns)):
            read["ordering"][side] += count  # ... their row's mean
        if not higher_is_better and np.isfinite(block).any():
            read["largest"] = max(read["largest"], float(block[np.isfinite(block)].max()))

    # Memory-mapped and cut to its top-k one block of queries at a time: never the whole matrix in memory.
    top, indices, _ = read_similarity_top_k(
        path, top_k, file_format=file_format, higher_is_better=higher_is_better, on_block=measure
    )
    config = {"source": str(path), "ground_truth": str(ground_truth), "top_k": int(top.shape[1])}
    config["positives_vs_mean"], positives = read["ordering"], read["positives"]
    if higher_is_better:
        return Retrieval(scores=top, indices=indices, positives=positives, config=config)
    kind, largest = scores, read["largest"]
    return Retrieval.from_distances(-top, indices, kind=kind, largest=largest, positives=positives, config=config)


def _read_log(path: Path, *, ground_truth: str | Path | None, top_k: int, **_: Any) -> Retrieval:
    return read_vpr_methods_evaluation(path, ground_truth=ground_truth, top_k=top_k).retrieval


for _entry in (
    ResultsFormat(
        "vpr-methods-evaluation",
        "a VPR-methods-evaluation log folder saved with --save_descriptors (searched again with Faiss)",
        _read_log,
        detect=Path.is_dir,
        provides=("scores", "distances", "positives", "names"),
    ),
    ResultsFormat(
        "retrieval",
        "a retrieval file (.npz: scores, indices and optionally the ground truth)",
        _read_retrieval_file,
        detect=lambda path: path.suffix.lower() == ".npz",
        provides=("scores", "distances", "positives", "names", "positions"),
    ),
    ResultsFormat(
        "matrix",
        "a full (queries × database) similarity or distance matrix (.npy)",
        _read_matrix,
        provides=("scores",),
        reads_distances=True,
    ),
    ResultsFormat(
        "vprbench",
        "VPR-Bench's precomputed_data_corrected.npy",
        partial(_read_matrix, file_format="vprbench"),
        provides=("scores",),
        reads_distances=True,
    ),
):
    register_results_format(_entry)


# --- similarity matrices ---------------------------------------------------------------------------------------

_MATRIX = "a numeric (queries × database) similarity matrix"


def _check_similarity_shape(matrix: np.ndarray, path: Path) -> np.ndarray:
    """Dtype and shape of a similarity matrix read (or memory-mapped) from ``path``."""
    if matrix.dtype.kind not in "iuf":
        raise ValueError(f"{path}: a similarity matrix must hold integers or floats, got dtype {matrix.dtype}")
    if matrix.ndim != 2:
        raise ValueError(f"{path}: a similarity matrix must be 2-D (queries × database), got shape {matrix.shape}")
    if matrix.shape[0] == 0 or matrix.shape[1] == 0:
        raise ValueError(f"{path}: the similarity matrix is empty (shape {matrix.shape}); expected queries × database")
    return matrix


def _check_similarity_values(
    block: np.ndarray, path: Path, first_row: int = 0, *, higher_is_better: bool = True
) -> None:
    """No NaN or +inf in rows ``first_row`` … of a similarity matrix; -inf (no candidate) is allowed. For a distance
    matrix (``higher_is_better=False``) the other way round: no NaN or -inf; +inf marks no candidate."""
    # NaN when any value is NaN; one pass, no temporary the size of the block
    extreme = block.max() if higher_is_better else block.min()
    wrong_infinity = np.inf if higher_is_better else -np.inf
    if np.isnan(extreme) or extreme == wrong_infinity:
        bad = np.isnan(block) | (block == wrong_infinity)
        row, column = (int(i) for i in np.argwhere(bad)[0])
        last = first_row + len(block) - 1
        matrix, what, missing = (
            ("similarity", "similarities", "-inf") if higher_is_better else ("distance", "distances", "+inf")
        )
        raise ValueError(
            f"{path}: the {matrix} matrix holds {block[row, column]} at query {first_row + row}, database image "
            f"{column} ({int(bad.sum())} such values in queries {first_row}–{last}); expected finite "
            f"{what} ({missing} marks a database image that is no candidate)"
        )


def _open_similarity(path: Path, file_format: str, *, mmap: bool) -> np.ndarray:
    """The matrix of ``path`` with dtype and shape checked (values not yet); memory-mapped when ``mmap``."""
    if not is_regular_file(path, "a similarity matrix"):
        raise FileNotFoundError(f"similarity file not found: {path}")
    if file_format == "vprbench":
        return _check_similarity_shape(load_vprbench_similarity(path), path)
    if file_format == "matrix":
        what = f"{_MATRIX} (VPR-Bench's precomputed matches are read with format 'vprbench' or 'auto')"
        return _check_similarity_shape(read_npy(path, what=what, mmap=mmap), path)
    what = f"{_MATRIX} or VPR-Bench precomputed matches (an object array of 6 items)"
    matrix = read_npy(path, what=what, allow_objects=True, mmap=mmap)
    if matrix.dtype == object:
        if matrix.shape != (6,):
            raise ValueError(f"{path} holds Python objects (an object array of shape {matrix.shape}); expected {what}")
        return _check_similarity_shape(load_vprbench_similarity(path), path)
    return _check_similarity_shape(matrix, path)


def load_similarity_matrix(path: str | Path, *, file_format: str = "auto") -> np.ndarray:
    """Read a whole (queries × database) similarity matrix, higher = more similar, from ``.npy`` (plain or VPR-Bench's).

    ``file_format``: ``"matrix"``, ``"vprbench"`` or ``"auto"`` (whichever the file is; VPR-Bench's object arrays are
    read without running code from the file). Returns a (Q, D) integer or float array, Q, D ≥ 1, without NaN or
    +inf (``-inf`` marks a database image that is no candidate). Raises FileNotFoundError for a missing file and
    ValueError naming the file (and the query) for an empty, truncated, foreign or malformed one.
    """
    path = Path(path)
    matrix = _open_similarity(path, file_format, mmap=False)
    _check_similarity_values(matrix, path)
    return matrix


def read_similarity_top_k(
    path: str | Path,
    top_k: int,
    *,
    file_format: str = "auto",
    block_rows: int | None = None,
    higher_is_better: bool = True,
    on_block: Callable[[np.ndarray, int, tuple[int, int]], None] | None = None,
) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """The top-k of every query of a similarity matrix file, memory-mapped and read one block of queries at a time.

    Peak memory is the (Q × k) result plus one block (``block_rows`` queries, by default about 4 M values); values are
    checked block by block with the errors of :func:`load_similarity_matrix`; VPR-Bench's legacy files are read whole.
    Returns scores and indices of shape (Q, min(top_k, D)) as :func:`~vpr_uncertainty.retrieval.top_k_from_similarity`
    does, and the matrix's shape (Q, D). ``higher_is_better=False``: the file holds distances; the k nearest are
    returned with their distances negated (the scores of a Retrieval are higher = better). ``on_block(block,
    first_row, shape)`` sees every block of values as stored, once checked.
    """
    path = Path(path)
    matrix = _open_similarity(path, file_format, mmap=True)
    check_positive_int(top_k, "top_k")
    shape = (int(matrix.shape[0]), int(matrix.shape[1]))

    def check_block(block: np.ndarray, first_row: int) -> None:
        _check_similarity_values(block, path, first_row, higher_is_better=higher_is_better)
        if on_block is not None:
            on_block(block, first_row, shape)

    if isinstance(matrix, np.memmap) and matrix.flags.c_contiguous:
        matrix = MappedRows(matrix)  # one mapping per block: read pages do not pile up in resident memory
    scores, indices = top_k_blocks(
        matrix, top_k, block_rows=block_rows, check_block=check_block, higher_is_better=higher_is_better
    )
    return scores, indices, shape


#: The descriptor files of ``--save_descriptors``: (queries, database).
LOG_FILES: tuple[str, str] = ("queries_descriptors.npy", "database_descriptors.npy")
_ARGUMENTS = re.compile(r"Arguments: (Namespace\(.*\))\s*$")


@dataclass
class VprMethodsEvaluationLog:
    """A log folder read by :func:`read_vpr_methods_evaluation`: the retrieval, the run's ``arguments`` (from
    ``info.log``), the image files when the folders named there exist, and ``notes`` on how the ground truth was had.
    """

    retrieval: Retrieval
    arguments: dict[str, Any] = field(default_factory=dict)
    query_paths: list[Path] | None = None
    database_paths: list[Path] | None = None
    notes: list[str] = field(default_factory=list)


def _literal(node: ast.AST) -> Any:
    """A value of the Namespace repr: literals, and ``PosixPath('x')``-style calls read as their string."""
    if isinstance(node, ast.Call) and len(node.args) == 1 and not node.keywords:
        return _literal(node.args[0])
    try:
        return ast.literal_eval(node)
    except ValueError:
        return None  # a value that is not a literal (an object repr): unknown


def read_arguments(log: str | Path) -> dict[str, Any]:
    """The arguments of a VPR-methods-evaluation run from the ``Arguments: Namespace(...)`` line of its ``info.log``."""
    path = Path(log)
    if not is_regular_file(path, "a log file"):
        return {}
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        found = _ARGUMENTS.search(line)
        if found is None:
            continue
        try:
            call = ast.parse(found.group(1), mode="eval").body
        except SyntaxError:
            return {}
        if isinstance(call, ast.Call):
            return {keyword.arg: _literal(keyword.value) for keyword in call.keywords if keyword.arg}
    return {}


def _jpg_images(folder: Path) -> list[Path]:
    """That tool's image list: every ``*.jpg`` under ``folder``, recursively, sorted by path, hidden ones left out."""
    found = (path for path in folder.glob("**/*.jpg") if not any(map(is_hidden, path.relative_to(folder).parts)))
    return sorted(found, key=lambda path: str(path))


def _utm(paths: list[Path], folder: Path) -> np.ndarray:
    rows = []
    for path in paths:
        fields = path.name.split("@")
        try:
            rows.append((float(fields[1]), float(fields[2])))
        except (IndexError, ValueError):
            raise ValueError(
                f"{path}: the image names under {folder} hold no UTM coordinates (@UTM_east@UTM_north@...@.jpg), "
                "so the positives cannot be derived; give the ground truth (argument ground_truth)"
            ) from None
    return np.asarray(rows, dtype=np.float64)


def _image_lists(arguments: dict[str, Any], n_queries: int, n_database: int, log: Path) -> tuple[list, list] | None:
    folders = [arguments.get("queries_folder"), arguments.get("database_folder")]
    if not all(isinstance(folder, str) for folder in folders):
        return None
    queries_folder, database_folder = (Path(folder) for folder in folders)
    if not (queries_folder.is_dir() and database_folder.is_dir()):
        return None
    query_paths, database_paths = _jpg_images(queries_folder), _jpg_images(database_folder)
    if (len(query_paths), len(database_paths)) != (n_queries, n_database):
        raise ValueError(
            f"{log}: the descriptors are of {n_queries} queries and {n_database} database images, but "
            f"{queries_folder} and {database_folder} now hold {len(query_paths)} and {len(database_paths)} .jpg "
            "images; give the ground truth (argument ground_truth)"
        )
    return query_paths, database_paths


def _check_predictions(folder: Path, retrieval: Retrieval, database_paths: list[Path]) -> str | None:
    """Compare the saved top-1 predictions (``preds/*.txt``) with the search; a note, or None without preds."""
    files = sorted((folder / "preds").glob("*.txt")) if (folder / "preds").is_dir() else []
    if not files:
        return None
    position = {str(path): index for index, path in enumerate(database_paths)}
    checked = differ = 0
    for file in files:
        if not file.stem.isdigit() or int(file.stem) >= retrieval.n_queries:
            continue
        lines = file.read_text(encoding="utf-8", errors="replace").splitlines()
        if "Predictions paths:" not in lines:
            continue
        after = lines[lines.index("Predictions paths:") + 1 :]
        if not after or after[0] not in position:
            continue
        checked += 1
        differ += position[after[0]] != int(retrieval.indices[int(file.stem), 0])
    if differ:
        warnings.warn(
            f"{folder}: the top-1 of {differ} of {checked} queries differs from the predictions saved in preds/ "
            "(approximate ties, or descriptors that are not L2-normalised: this toolkit ranks by cosine similarity)",
            stacklevel=3,
        )
    return f"top-1 checked against preds/ for {checked} queries: {checked - differ} agree" if checked else None


def read_vpr_methods_evaluation(
    folder: str | Path,
    *,
    ground_truth: str | Path | None = None,
    radius: float | None = None,
    top_k: int = 50,
) -> VprMethodsEvaluationLog:
    """Read a log folder of VPR-methods-evaluation (gmberton) saved with ``--save_descriptors``.

    The folder holds ``queries_descriptors.npy`` and ``database_descriptors.npy`` (rows in the order of that tool's
    sorted ``*.jpg`` lists) and ``info.log`` with the run's arguments. Predictions have no scores, so the descriptors
    are searched again (exact cosine search; for that tool's L2-normalised descriptors its own ranking), and the
    top-1 is checked against ``preds/*.txt`` when saved. Ground truth is the file given, else derived as that tool
    does: the database images within ``radius`` metres (default: the run's ``positive_dist_threshold``, else 25)
    from the UTM coordinates in the image names, when the folders named in ``info.log`` are still there.

    Parameters
    ----------
    folder : str or Path
    ground_truth : str or Path, optional
        Any format of :func:`vpr_uncertainty.data.load_ground_truth`.
    radius : float, optional
    top_k : int
        Candidates kept per query (all of them for a smaller database).

    Raises
    ------
    FileNotFoundError
        When a descriptor file is missing (the message says which flag writes it).
    ValueError
        When the ground truth can neither be read nor derived (the message says why).
    """
    folder = Path(folder)
    missing = [name for name in LOG_FILES if not is_regular_file(folder / name, "a descriptor file")]
    if missing:
        raise FileNotFoundError(
            f"{folder} is not a VPR-methods-evaluation log folder with descriptors: {', '.join(missing)} missing "
            "(that tool writes them with --save_descriptors)"
        )
    _, queries = load_descriptors(folder / LOG_FILES[0])
    _, database = open_descriptors(folder / LOG_FILES[1])  # read lazily: a large database is searched by blocks
    arguments = read_arguments(folder / "info.log")
    worst = 0.0
    for block in database.row_blocks():
        worst = max(worst, float(np.abs(np.linalg.norm(block, axis=1) - 1.0).max(initial=0.0)))
        del block  # before the next block is read
    notes, config = [], {"source": str(folder), "format": "vpr-methods-eval"}
    if worst > 1e-3:
        notes.append("the descriptors are not L2-normalised: ranked by cosine similarity, not by L2 distance")
    else:  # what that tool's Faiss IndexFlatL2 ranks by: d² = 2 - 2s
        config["score_conversion"] = "L2-normalised descriptors searched by cosine similarity s = 1 - d²/2 (d: L2)"
    retrieval = retrieve(database, queries, min(int(top_k), len(database)), config=config)
    lists = _image_lists(arguments, len(queries), len(database), folder)
    query_paths, database_paths = lists if lists is not None else (None, None)
    names = {}
    if lists is not None:
        names = {"query_names": [str(p) for p in query_paths], "database_names": [str(p) for p in database_paths]}
    if ground_truth is not None:
        positives = load_ground_truth(ground_truth, n_queries=len(queries), n_database=len(database))
        fields = ground_truth_fields(len(queries), len(database), positives=positives, **names)
        notes.append(f"ground truth from {ground_truth}")
    elif lists is not None:
        threshold = radius if radius is not None else arguments.get("positive_dist_threshold") or 25.0
        fields = ground_truth_fields(
            len(queries),
            len(database),
            query_positions=_utm(query_paths, Path(arguments["queries_folder"])),  # type: ignore[arg-type]
            database_positions=_utm(database_paths, Path(arguments["database_folder"])),  # type: ignore[arg-type]
            radius=float(threshold),
            position_kind="metres",
            **names,
        )
        notes.append(f"ground truth: database images within {float(threshold):g} m (UTM in the image names)")
    else:
        named = arguments.get("database_folder"), arguments.get("queries_folder")
        why = (
            f"the image folders named in its info.log ({named[1]}, {named[0]}) are not there"
            if any(named)
            else "it has no info.log naming the image folders"
        )
        raise ValueError(f"{folder}: no ground truth: {why}; give the ground truth (argument ground_truth)")
    retrieval = attach_ground_truth(retrieval, fields)
    if database_paths is not None:
        checked = _check_predictions(folder, retrieval, database_paths)
        if checked:
            notes.append(checked)
    return VprMethodsEvaluationLog(retrieval, arguments, query_paths, database_paths, notes)


_MATCHES = (
    "VPR-Bench precomputed matches (an object array of 6 items: query indices, top-1 indices, top-1 scores, "
    "similarity matrix, encoding time, matching time)"
)


def load_vprbench_similarity(path: str | Path) -> np.ndarray:
    """The (Q, D) float32 similarity matrix of VPR-Bench's ``precomputed_data_corrected.npy``.

    The file holds [query indices, top-1 indices, top-1 scores, similarity matrix, encoding time, matching time],
    read without running code from it; another layout raises a ValueError naming the file.
    """
    path = Path(path)
    content = read_npy(path, what=_MATCHES, allow_objects=True)
    if content.dtype != object:
        raise ValueError(
            f"{path} is a plain {content.dtype} array of shape {content.shape}, not {_MATCHES}; "
            "read it as a similarity matrix (format 'matrix')"
        )
    if content.shape != (6,):
        raise ValueError(f"{path}: expected {_MATCHES}, got an object array of shape {content.shape}")
    similarity = content[3]
    if not isinstance(similarity, np.ndarray) or similarity.dtype.kind not in "iuf" or similarity.ndim != 2:
        found = (
            f"a {similarity.dtype} array of shape {similarity.shape}"
            if isinstance(similarity, np.ndarray)
            else type(similarity).__name__
        )
        raise ValueError(f"{path}: item 3 should be the numeric (queries × database) similarity matrix, got {found}")
    order = content[0]
    # Some of VPR-Bench's own files (ap-gem-r101) store the query indices as floats 0.0, 1.0, ...: compared exactly.
    if not isinstance(order, np.ndarray) or order.dtype.kind not in "iuf" or order.ndim != 1:
        raise ValueError(f"{path}: item 0 should be the query indices 0..{similarity.shape[0] - 1}, got {order!r:.80}")
    if len(order) != similarity.shape[0] or not np.array_equal(order, np.arange(len(order))):
        raise ValueError(f"{path}: expected query indices 0..{similarity.shape[0] - 1} in order")
    return similarity.astype(np.float32)


def _descriptor_file(path: str | Path, split: str | None) -> tuple[Path, bool]:
    """The path of an existing descriptor file and whether it is HDF5 (which needs a valid ``split``)."""
    path = Path(path)
    if not is_regular_file(path, "a descriptor file"):
        raise FileNotFoundError(f"descriptor file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return path, False
    if suffix not in (".h5", ".hdf5"):
        raise ValueError(
            f"unsupported descriptor file {path}: expected one of {', '.join(DESCRIPTOR_SUFFIXES)} "
            "(a .npy array of shape (N, dim) or the HDF5 descriptor cache)"
        )
    if split not in DESCRIPTOR_SPLITS:
        raise ValueError(f"reading the descriptor cache {path} needs split in {DESCRIPTOR_SPLITS}, got {split!r}")
    return path, True


def _read_npy_descriptors(path: Path, *, mmap: bool) -> np.ndarray:
    """The numeric 2-D array of a ``.npy`` descriptor file (memory-mapped when ``mmap``)."""
    array = read_npy(path, what="a descriptor array of shape (n_images, dimension)", mmap=mmap)
    if array.dtype.kind not in "biuf":
        raise ValueError(f"{path} is not a numeric descriptor array (it holds dtype {array.dtype})")
    if array.ndim != 2:
        raise ValueError(f"{path}: descriptors must be 2-D (n_images, dimension), got shape {array.shape}")
    return array


def load_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """Read descriptors from a ``.npy`` array (N × dim), the HDF5 descriptor cache or hloc's global features.

    Parameters
    ----------
    path : str or Path
        ``.npy`` file (read without running code from it), descriptor cache ``.h5`` / ``.hdf5`` written by the
        feature extraction, or hloc's global features (:mod:`vpr_uncertainty.descriptors.hloc`).
    split : {"database", "queries"}, optional
        Which images to read from an HDF5 file; required for ``.h5``, ignored for ``.npy``. An hloc file whose
        names carry no split prefix (``query/``, ``db/``, ...) is read whole.

    Returns
    -------
    names : ndarray of str of shape (N,), or None
        Image names (None for ``.npy``).
    descriptors : ndarray of shape (N, dim), float32
        A new array owned by the caller (it may be normalised in place).

    Raises
    ------
    FileNotFoundError
        When ``path`` is not a file.
    ValueError
        For another suffix, a ``.h5`` without a valid ``split``, an unreadable file or an array that is not 2-D.
    """
    path, hdf5 = _descriptor_file(path, split)
    if not hdf5:
        array, names = _read_npy_descriptors(path, mmap=False), None
    else:
        from vpr_uncertainty.descriptors.cache import read_descriptors  # imported here: h5py only when needed
        from vpr_uncertainty.descriptors.hloc import is_hloc_file, read_hloc_descriptors

        read = read_hloc_descriptors if is_hloc_file(path) else read_descriptors
        names, array = read(path, split)
        names = None if names is None else np.asarray(names, dtype=str)
    array = np.asarray(array)
    if array.ndim != 2:
        raise ValueError(f"{path}: descriptors must be 2-D (n_images, dimension), got shape {array.shape}")
    if names is not None and len(names) != len(array):
        raise ValueError(f"{path}: {len(names)} names but {len(array)} descriptors")
    return names, np.ascontiguousarray(array, dtype=np.float32)


def open_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray | None, DescriptorRows]:
    """Open a descriptor file without reading its descriptors: rows are read later, one block at a time.

    The same files, arguments and errors as :func:`load_descriptors`; the rows stay on disk in a
    :class:`~vpr_uncertainty.retrieval.DescriptorRows` (hloc's files are read whole: no rows to slice).

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> np.save(folder / "db.npy", np.arange(6, dtype=np.float64).reshape(3, 2))
    >>> names, rows = open_descriptors(folder / "db.npy")
    >>> rows.shape, rows.read(1, 3)
    ((3, 2), array([[2., 3.],
           [4., 5.]], dtype=float32))
    """
    path, hdf5 = _descriptor_file(path, split)
    if not hdf5:
        return None, _open_npy(path)
    from vpr_uncertainty.descriptors.hloc import is_hloc_file, read_hloc_descriptors

    if is_hloc_file(path):
        names, array = read_hloc_descriptors(path, split)
        return np.asarray(names, dtype=str), DescriptorRows.from_array(np.asarray(array), source=str(path))
    return _open_cache(path, split)


def _open_npy(path: Path) -> DescriptorRows:
    """Rows of a ``.npy`` file: each block of a C-ordered file read from the file at its offset (not through a
    mapping, whose pages would count in resident memory); a Fortran-ordered one sliced through the mapping."""
    array = _read_npy_descriptors(path, mmap=True)
    if not isinstance(array, np.memmap) or not array.flags.c_contiguous:
        return DescriptorRows.from_array(array, source=str(path))  # empty, or Fortran-ordered: sliced
    shape, dtype, offset = array.shape, array.dtype, int(array.offset)  # a fresh mapping of the whole file
    dimension, row_bytes = shape[1], shape[1] * dtype.itemsize
    del array

    def read(start: int, stop: int) -> np.ndarray:
        block = np.empty((stop - start, dimension), dtype=dtype)
        with path.open("rb") as handle:
            handle.seek(offset + start * row_bytes)
            count = handle.readinto(memoryview(block).cast("B"))
        if count != block.nbytes:
            raise ValueError(f"{path} changed while it was read: rows {start}–{stop - 1} are no longer all there")
        return block

    return DescriptorRows(read, shape, source=str(path))


def _open_cache(path: Path, split: str) -> tuple[np.ndarray, DescriptorRows]:
    """Names and lazily read rows of one split of the descriptor cache, checked as ``read_descriptors`` does
    (payload checksum included: one pass over the rows when the file is opened)."""
    import h5py

    from vpr_uncertainty.descriptors.cache import check_finite, split_layout, verify_split

    names, count, dimension = split_layout(path, split, stacklevel=3)
    with h5py.File(path, "r") as handle:  # the payload checksum, one block of rows at a time
        verify_split(path, handle[split], split, count)
    if count == 0:
        return names, DescriptorRows.from_array(np.empty((0, 0), np.float32), source=str(path))

    def read(start: int, stop: int) -> np.ndarray:
        with h5py.File(path, "r") as block_handle:
            block = block_handle[split]["descriptors"][start:stop]
        check_finite(path, split, block, names, first_row=start)  # naming the file, not only "database row i"
        return block

    return names, DescriptorRows(read, (count, dimension), source=f"{path} ({split})")
