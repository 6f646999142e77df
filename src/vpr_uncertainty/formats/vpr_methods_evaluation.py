"""Log folders of VPR-methods-evaluation (gmberton) saved with ``--save_descriptors``: its descriptors searched
again by cosine similarity (the ranking of that tool's Faiss ``IndexFlatL2`` on L2-normalised descriptors), with the
ground truth given or derived from the UTM coordinates in its image names."""

from __future__ import annotations

import ast
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.formats.ground_truth import load_ground_truth
from vpr_uncertainty.formats.matrix import load_descriptors, open_descriptors
from vpr_uncertainty.retrieval.ground_truth import attach_ground_truth, ground_truth_fields
from vpr_uncertainty.retrieval.result import Retrieval
from vpr_uncertainty.retrieval.search import retrieve

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
    found = (p for p in folder.glob("**/*.jpg") if not any(s.startswith(".") for s in p.relative_to(folder).parts))
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


def sniff(path: Path) -> bool:
    """Whether ``path`` is a folder (read as a log folder; its reader says what is missing)."""
    return Path(path).is_dir()


def read(path: Path, *, ground_truth: str | Path | None, top_k: int, scores: str = "similarity", **_: Any) -> Retrieval:
    """The retrieval of a log folder (:func:`read_vpr_methods_evaluation`); ``scores`` other than ``"distance"``
    are accepted: the folder says its own kind (L2 distances of L2-normalised descriptors, searched again as the
    cosine similarities that rank them)."""
    if scores == "distance":
        raise ValueError(f"{path}: a VPR-methods-evaluation log folder is searched by similarity, not as distances")
    return read_vpr_methods_evaluation(path, ground_truth=ground_truth, top_k=top_k).retrieval
