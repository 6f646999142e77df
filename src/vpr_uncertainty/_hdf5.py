"""Reading HDF5 inputs without reaching outside the file that was named.

HDF5 lets a file take its bytes from elsewhere: a dataset with *external raw storage*
(``create_dataset(..., external=[(path, offset, size)])``) reads the bytes of any local file, a *virtual dataset*
maps datasets of other files, an *external link* names an object of another file, and a *soft link* makes one
object appear under a second name. A crafted descriptor or feature file could so feed the bytes of a file the
user never named to the toolkit as descriptors or keypoints (exit 0, wrong numbers), or hide an image from a
listing. Every HDF5 reader of the toolkit (hloc global and local features, the descriptor cache, the local-feature
cache) therefore opens each dataset it reads through :func:`open_dataset` and lists groups with
:func:`hard_links`, which refuse all four with a ``ValueError`` naming the file, the object and what was refused.
None of them is ever written by the toolkit or by hloc.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["check_dataset", "hard_links", "open_dataset", "open_present"]

_REFUSED = "an input file must hold its own data; refused"


def _refuse_link(path: str | Path, name: str, link: Any) -> None:
    import h5py

    if isinstance(link, h5py.ExternalLink):
        raise ValueError(f"{path}: {name!r} is an HDF5 external link to {link.path!r} in {link.filename!r}; {_REFUSED}")
    if isinstance(link, h5py.SoftLink):
        raise ValueError(f"{path}: {name!r} is an HDF5 soft link to {link.path!r}; {_REFUSED}")


def check_dataset(dataset: Any, path: str | Path, name: str | None = None) -> None:
    """Refuse a dataset whose bytes do not live in the file itself (external raw storage, a virtual dataset).

    Parameters
    ----------
    dataset : h5py.Dataset
    path : str or Path
        The file, for the message.
    name : str, optional
        The dataset's name in that file, for the message; by default ``dataset.name``.

    Raises
    ------
    ValueError
        Naming the file, the dataset and what was refused.
    """
    name = (dataset.name if name is None else name).strip("/")
    if dataset.external:
        files = ", ".join(sorted({str(entry[0]) for entry in dataset.external}))
        raise ValueError(
            f"{path}: dataset {name!r} uses HDF5 external storage (its bytes come from {files}); {_REFUSED}"
        )
    if dataset.is_virtual:
        raise ValueError(
            f"{path}: dataset {name!r} is an HDF5 virtual dataset (its bytes come from other datasets or files); "
            f"{_REFUSED}"
        )


def open_dataset(group: Any, name: str, path: str | Path) -> Any:
    """``group[name]``, checked: every link on the way a hard link, the dataset's bytes in the file itself.

    Parameters
    ----------
    group : h5py.Group or h5py.File
    name : str
        A dataset below ``group`` (``"database/descriptors"``).
    path : str or Path
        The file, for the messages.

    Returns
    -------
    h5py.Dataset

    Raises
    ------
    KeyError
        When ``name`` is missing (as ``group[name]``).
    ValueError
        For a soft or external link on the way, external storage, a virtual dataset, or a group instead of a
        dataset; the message names the file and the object.
    """
    import h5py

    prefix = group.name.strip("/")
    parts = [part for part in name.split("/") if part]
    current = group
    for depth, part in enumerate(parts):
        link = current.get(part, getlink=True)
        where = "/".join([*([prefix] if prefix else []), *parts[: depth + 1]])
        if link is None:
            raise KeyError(f"{path} has no {where!r}")
        _refuse_link(path, where, link)
        current = current[part]
    if not isinstance(current, h5py.Dataset):
        raise ValueError(f"{path}: {'/'.join([prefix, *parts]).strip('/')!r} is not a dataset")
    check_dataset(current, path, "/".join([*([prefix] if prefix else []), *parts]))
    return current


def open_present(group: Any, names: tuple[str, ...], path: str | Path) -> dict[str, Any]:
    """:func:`open_dataset` of each of ``names`` that ``group`` holds (a missing one is left out)."""
    return {name: open_dataset(group, name, path) for name in names if name in group}


def hard_links(group: Any, path: str | Path) -> Iterator[tuple[str, Any]]:
    """Every object below ``group`` by its hard-link names, refusing every other kind of link.

    Unlike ``visititems``, an object reachable by two names is yielded under both, and a soft or external link
    is refused instead of being skipped (skipping it would silently leave an image out). A group is entered once
    (a hard link back to a group already entered is yielded, not entered again). Datasets are checked with
    :func:`check_dataset` before they are yielded.

    Yields
    ------
    name : str
        Relative to ``group``, "/"-joined.
    item : h5py.Group or h5py.Dataset
    """
    import h5py

    stack: list[tuple[str, Any]] = [("", group)]
    entered = {group.id}
    while stack:
        prefix, current = stack.pop()
        for key in current.keys():
            name = f"{prefix}{key}"
            _refuse_link(path, name, current.get(key, getlink=True))
            item = current[key]
            if isinstance(item, h5py.Dataset):
                check_dataset(item, path, name)
            yield name, item
            if isinstance(item, h5py.Group) and item.id not in entered:
                entered.add(item.id)
                stack.append((f"{name}/", item))
