"""Pose-graph text files (g2o, TORO, the layout of GTSAM's City10000 files), read and written without losing anything:
every line kept as given, the lines of known tags read at full precision and checked (a refusal names the line),
the others passed through; the tags and their fields: docs/reference/file-formats.md, "Pose graphs".
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_uncertainty._files import open_regular
from vpr_uncertainty.cache import atomic_write

__all__ = ["GraphFile", "read_graph_file", "write_graph_file"]

#: tag -> (dimension, pose fields, information fields, rotation written as); None: a vertex.
TAGS = {
    "VERTEX_SE2": (2, 3, None, "theta"),
    "VERTEX2": (2, 3, None, "theta"),
    "EDGE_SE2": (2, 3, 6, "theta"),
    "EDGE2": (2, 3, 6, "theta"),
    "VERTEX_SE3:QUAT": (3, 7, None, "quaternion"),
    "VERTEX3": (3, 6, None, "rpy"),
    "EDGE_SE3:QUAT": (3, 7, 21, "quaternion"),
    "EDGE3": (3, 6, 21, "rpy"),
}
#: Where each value of TORO's EDGE2 information (I11 I12 I22 I33 I13 I23) stands in the upper triangle read row by
#: row (I11 I12 I13 I22 I23 I33).
TORO_2D_ORDER = [0, 1, 3, 5, 2, 4]
#: Information of the City10000 layout's measurements: σ = (1/30, 1/30, 1/100).
CITY10000_INFORMATION = np.diag([900.0, 900.0, 10000.0])


@dataclass(frozen=True)
class GraphFile:
    """The lines of a pose-graph file and the poses, edges and information matrices they hold.

    Attributes
    ----------
    path : Path
    lines : list of str
        Every line of the file, line ends included (``"".join(lines)`` is the file).
    dimension : {2, 3}
    vertex_ids : ndarray of shape (V,), int64
    vertex_poses : ndarray of shape (V, 3) or (V, 7)
        ``x y θ`` or ``x y z qx qy qz qw`` (a unit quaternion).
    edges : ndarray of shape (E, 2), int64
        The two vertex ids of each edge, in the order of the file.
    edge_lines : ndarray of shape (E,), int64
        The index in ``lines`` of each edge.
    measurements : ndarray of shape (E, 3) or (E, 7)
        The pose of vertex j in the frame of vertex i, as ``vertex_poses``.
    information : ndarray of shape (E, 3, 3) or (E, 6, 6)
        Symmetric positive definite, in the order of the measurement's tangent: x y θ, or x y z then the rotation.
    other_tags : dict of str to int
        The tags of the lines the toolkit does not interpret (comments as ``"#"``), with their counts.
    """

    path: Path
    lines: list[str]
    dimension: int
    vertex_ids: np.ndarray
    vertex_poses: np.ndarray
    edges: np.ndarray
    edge_lines: np.ndarray
    measurements: np.ndarray
    information: np.ndarray
    other_tags: dict[str, int]


def read_graph_file(path: str | Path) -> GraphFile:
    """Read a g2o, TORO or City10000 pose-graph file (see the module's table); a ValueError names the line at fault.

    Examples
    --------
    >>> import tempfile
    >>> file = Path(tempfile.mkdtemp()) / "g.g2o"
    >>> _ = file.write_text("VERTEX_SE2 0 512345.678901 5412345.123456 0\\nVERTEX_SE2 1 0 0 0\\n"
    ...                     "EDGE_SE2 0 1 1.23456789 0 0 100 0 0 100 0 400\\nFIX 0\\n")
    >>> graph = read_graph_file(file)
    >>> graph.vertex_poses[0, :2].tolist(), graph.measurements[0].tolist(), graph.other_tags
    ([512345.678901, 5412345.123456], [1.23456789, 0.0, 0.0], {'FIX': 1})
    """
    path = Path(path)
    with open_regular(path) as handle:
        data = handle.read()
    try:
        lines = data.decode("utf-8").splitlines(keepends=True)
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not a text pose graph (byte {error.start} is not UTF-8)") from None
    groups: dict[str, list[tuple[int, list[str]]]] = {}
    other: Counter[str] = Counter()
    for index, words in enumerate(line.split() for line in lines):
        if index == 0 and words:
            words[0] = words[0].removeprefix("\ufeff")  # a byte-order mark is no part of a tag
        if not words or words[0][0] == "#":
            other["#"] += bool(words)
        elif words[0] in TAGS:
            groups.setdefault(words[0], []).append((index, words))
        else:
            other[words[0]] += 1
    dimension = _dimension(path, groups)
    vertex_ids, vertex_poses, edges, edge_lines, measurements, information = _empty(dimension)
    parts: dict[str, list[np.ndarray]] = {name: [] for name in ("ids", "poses", "edges", "lines", "poses_e", "info")}
    for tag, rows in groups.items():
        _, n_pose, n_information, _ = TAGS[tag]
        city = tag == "EDGE2" and _is_city10000(rows[0][1])
        n_ids, n_values = (1, n_pose) if n_information is None else (2, n_pose + (0 if city else n_information))
        lines_of = np.array([number for number, _ in rows], dtype=np.int64)
        for number, words in rows if city or {len(words) for _, words in rows} != {1 + n_ids + n_values} else ():
            width = 1 + n_ids + n_values
            if city:
                width = 6 + 3 * int(words[5]) if len(words) > 5 and _is_int(words[5]) and int(words[5]) else None
            if len(words) != width:
                what = f"{tag} i 1 j 0 N x y θ … (N measurements)" if city else tag
                got = f"needs {width or '6 + 3N'} fields, got {len(words)}"
                raise ValueError(f"{path}, line {number + 1}: {what} {got}")
        ids = _ids(path, tag, rows, [1, 3] if city else list(range(1, 1 + n_ids)), lines_of)
        first = 6 if city else 1 + n_ids
        values = _numbers(path, [words[first : first + n_values] for _, words in rows], lines_of)
        poses = _poses(path, tag, values[:, :n_pose], lines_of)
        if n_information is None:
            parts["ids"].append(ids[:, 0])
            parts["poses"].append(poses)
        else:
            parts["edges"].append(ids)
            parts["lines"].append(lines_of)
            parts["poses_e"].append(poses)
            parts["info"].append(_information(path, tag, city, values[:, n_pose:], lines_of))
    if parts["ids"]:
        vertex_ids, vertex_poses = np.concatenate(parts["ids"]), np.concatenate(parts["poses"])
    if parts["edges"]:
        order = np.argsort(np.concatenate(parts["lines"]), kind="stable")  # the order of the file
        edges, edge_lines = np.concatenate(parts["edges"])[order], np.concatenate(parts["lines"])[order]
        measurements, information = np.concatenate(parts["poses_e"])[order], np.concatenate(parts["info"])[order]
    _check_graph(path, vertex_ids, edges)
    return GraphFile(
        path, lines, dimension, vertex_ids, vertex_poses, edges, edge_lines, measurements, information, dict(other)
    )


def write_graph_file(graph: GraphFile, path: str | Path, *, keep: np.ndarray | None = None) -> Path:
    """Write the lines of ``graph`` to ``path`` atomically, without the edges where ``keep`` (E,) is False."""
    drop = set() if keep is None else set(graph.edge_lines[~np.asarray(keep, dtype=bool)].tolist())
    with atomic_write(path, newline="") as handle:
        handle.writelines(line for index, line in enumerate(graph.lines) if index not in drop)
    return Path(path)


def _empty(dimension: int) -> tuple[np.ndarray, ...]:
    n_pose, n_tangent = (3, 3) if dimension == 2 else (7, 6)
    return (
        np.empty(0, np.int64),
        np.empty((0, n_pose)),
        np.empty((0, 2), np.int64),
        np.empty(0, np.int64),
        np.empty((0, n_pose)),
        np.empty((0, n_tangent, n_tangent)),
    )


def _dimension(path: Path, groups: dict[str, list[tuple[int, list[str]]]]) -> int:
    """2 or 3, from the tags; a file with both, or with neither, is refused."""
    firsts = {
        dimension: min((rows[0][0], tag) for tag, rows in groups.items() if TAGS[tag][0] == dimension)
        for dimension in {TAGS[tag][0] for tag in groups}
    }
    if not firsts:
        raise ValueError(f"{path}: no vertex or edge of a known tag ({', '.join(TAGS)})")
    if len(firsts) == 2:
        (line2, tag2), (line3, tag3) = firsts[2], firsts[3]
        raise ValueError(
            f"{path}: line {line2 + 1} is 2-D ({tag2}), line {line3 + 1} is 3-D ({tag3}): a graph is one or the other"
        )
    return next(iter(firsts))


def _is_int(word: str) -> bool:
    return word.isascii() and word.isdigit()


def _is_city10000(words: list[str]) -> bool:
    """Whether an EDGE2 line is ``EDGE2 i 1 j 0 N x y θ …`` (GTSAM's City10000 files), not TORO's."""
    if len(words) not in (9, 12) or words[2:5:2] != ["1", "0"] or not _is_int(words[5]):
        return False
    return len(words) == 6 + 3 * int(words[5])


def _ids(path: Path, tag: str, rows: list, columns: list[int], lines: np.ndarray) -> np.ndarray:
    """(N, len(columns)) int64 ids; a negative, fractional or huge one is refused with its line."""
    flat = [words[column] for _, words in rows for column in columns]
    joined = "".join(flat)
    if joined.isascii() and joined.isdigit() and max(map(len, flat), default=0) < 19:  # below 2^63: one check
        ids = np.fromiter(map(int, flat), np.int64, len(flat)).reshape(len(rows), len(columns))
    else:
        for number, words in rows:
            for word in (words[column] for column in columns):
                if not _is_int(word) or int(word) >= 2**63:
                    where = f"{path}, line {number + 1}: {tag} ids"
                    raise ValueError(f"{where} must be integers in [0, 2^63), got {word!r}")
        ids = np.array([[int(words[column]) for column in columns] for _, words in rows], dtype=np.uint64)
        ids = ids.astype(np.int64).reshape(len(rows), len(columns))
    if len(columns) == 2 and (same := np.flatnonzero(ids[:, 0] == ids[:, 1])).size:
        raise ValueError(f"{path}, line {lines[same[0]] + 1}: an edge from vertex {ids[same[0], 0]} to itself")
    return ids


def _numbers(path: Path, words: list[list[str]], lines: np.ndarray) -> np.ndarray:
    """(N, F) float64 of the words; a word that is no finite number is refused with its line."""
    try:
        values = np.array(words, dtype=np.float64)
    except ValueError:
        values = None
    if values is not None and np.isfinite(values).all():
        return values
    for number, row in zip(lines.tolist(), words, strict=True):
        for word in row:
            try:
                if np.isfinite(float(word)):
                    continue
            except ValueError:
                pass
            raise ValueError(f"{path}, line {number + 1}: expected a finite number, got {word!r}")
    raise AssertionError("unreachable")  # pragma: no cover


def _poses(path: Path, tag: str, values: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """``x y θ``, or ``x y z qx qy qz qw`` with a unit quaternion (roll, pitch, yaw converted)."""
    rotation = TAGS[tag][3]
    if rotation == "theta":
        return values
    if rotation == "rpy":
        from scipy.spatial.transform import Rotation

        return np.c_[values[:, :3], Rotation.from_euler("ZYX", values[:, 5:2:-1]).as_quat()]
    norm = np.linalg.norm(values[:, 3:], axis=1)
    if (bad := np.flatnonzero(np.abs(norm - 1) > 1e-3)).size:
        raise ValueError(
            f"{path}, line {lines[bad[0]] + 1}: the quaternion qx qy qz qw has norm {norm[bad[0]]:.6g}, not 1"
        )
    return np.c_[values[:, :3], values[:, 3:] / norm[:, None]]


def _information(path: Path, tag: str, city: bool, values: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """(N, d, d) symmetric information matrices from their upper triangles; one that is not positive definite is
    refused with its line."""
    if city:
        return np.broadcast_to(CITY10000_INFORMATION, (len(values), 3, 3)).copy()
    if tag == "EDGE2":
        values = values[:, np.argsort(TORO_2D_ORDER)]
    size = 3 if values.shape[1] == 6 else 6
    rows, columns = np.triu_indices(size)
    matrices = np.zeros((len(values), size, size))
    matrices[:, rows, columns] = values
    matrices[:, columns, rows] = values
    if (bad := np.flatnonzero(np.linalg.eigvalsh(matrices)[:, 0] <= 0)).size:
        raise ValueError(
            f"{path}, line {lines[bad[0]] + 1}: the information matrix of the edge is not positive definite "
            f"(upper triangle {' '.join(f'{v:g}' for v in values[bad[0]])}); give the inverse covariance"
        )
    return matrices


def _check_graph(path: Path, vertex_ids: np.ndarray, edges: np.ndarray) -> None:
    """Each vertex defined once; with vertices, every edge between defined ones."""
    unique, counts = np.unique(vertex_ids, return_counts=True)
    if (twice := unique[counts > 1]).size:
        raise ValueError(f"{path}: vertex {twice[0]} is defined {counts[counts > 1][0]} times")
    if vertex_ids.size and (missing := np.setdiff1d(edges, vertex_ids)).size:
        raise ValueError(f"{path}: edges name vertices the file does not define: {missing[:5].tolist()}")
