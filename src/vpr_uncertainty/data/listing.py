"""Listing the image files of a folder without ever dropping one silently.

:func:`scan_images` walks a folder recursively:

* hidden entries (names starting with ``.``: ``.hidden.jpg``, ``.thumbnails/``, macOS ``._0001.jpg``) are never
  listed nor entered, as :func:`glob.glob` skips them: a stray hidden file would otherwise become image 0 and
  shift every index of a ground truth given by index;
* a file with an image suffix (:data:`IMAGE_EXTENSIONS`) is listed, even when it is a broken or looping symbolic
  link: extraction then reports it as an image that cannot be used, with the reason, and the indices of the other
  images stay what they would be without the fault (VPR-Bench's ground truth is by index);
* file names that are not valid UTF-8 are listed as Python decodes them (surrogate escapes);
* symbolic links to folders are followed, except those leading back to a folder being listed (a loop: its
  images are already listed under their own path);
* a folder that cannot be read, and a broken symbolic link without an image suffix (it may have pointed to a
  folder), are *listing problems*: images may be missing. :func:`list_images` raises
  :class:`ImageListingError` naming them, or hands them to the caller, which reports or refuses them.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

__all__ = ["IMAGE_EXTENSIONS", "ImageListingError", "describe_unlisted", "is_hidden", "list_images", "scan_images"]

#: File extensions read as images (case-insensitive).
IMAGE_EXTENSIONS: frozenset[str] = frozenset(
    {".jpg", ".jpeg", ".png", ".ppm", ".pgm", ".bmp", ".tif", ".tiff", ".webp"}
)


def is_hidden(name: str) -> bool:
    """Whether a file or folder name is hidden (starts with ``.``); hidden entries are never listed as images.

    Examples
    --------
    >>> is_hidden(".hidden.jpg"), is_hidden("0000000.jpg")
    (True, False)
    """
    return name.startswith(".")


class ImageListingError(ValueError):
    """A folder of images could not be listed completely; the message names what could not be read.

    Attributes
    ----------
    problems : list of dict
        ``{"path": ..., "error": ...}`` for every folder or link that could not be listed.
    """

    def __init__(self, folder: str | Path, problems: list[dict[str, str]]) -> None:
        self.problems = list(problems)
        super().__init__(f"cannot list every image under {_printable(folder)}: {describe_unlisted(problems)}")


def _printable(path: str | Path) -> str:
    return os.fsencode(str(path)).decode("utf-8", "backslashreplace")


def describe_unlisted(problems: list[dict[str, str]], *, shown: int = 3) -> str:
    """The first ``shown`` listing problems, ``path (error)``, separated by semicolons."""
    listed = "; ".join(f"{_printable(item['path'])} ({item['error']})" for item in problems[:shown])
    return listed + (f"; and {len(problems) - shown} more" if len(problems) > shown else "")


def _link_error(path: Path) -> str:
    try:
        os.stat(path)
    except OSError as error:
        kind = "loops back on itself" if error.errno == errno.ELOOP else "whose target does not exist"
        return f"symbolic link to '{_printable(os.readlink(path))}' {kind}; if it was a folder, its images are missing"
    return "cannot be read"


def scan_images(folder: str | Path) -> tuple[list[Path], list[dict[str, str]]]:
    """Image files under ``folder`` (recursively, following links to folders) and what could not be listed.

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    paths : list of Path
        Files whose suffix is in :data:`IMAGE_EXTENSIONS` (case-insensitive) and that are not hidden (nor under a
        hidden folder), sorted by their POSIX path relative to ``folder``; broken or looping links with such a
        suffix included (they fail when read, naming the reason). File names that are not valid UTF-8 are kept
        as Python decodes them (surrogate escapes).
    problems : list of dict
        ``{"path": ..., "error": ...}`` for each sub-folder that cannot be read and each broken link without an
        image suffix; images under them may be missing.
    """
    folder = Path(folder)
    images: list[Path] = []
    problems: list[dict[str, str]] = []

    def visit(directory: Path, ancestors: frozenset[str]) -> None:
        try:
            with os.scandir(directory) as iterator:
                entries = list(iterator)
        except OSError as error:
            problems.append({"path": str(directory), "error": f"cannot read the folder: {error.strerror or error}"})
            return
        for entry in entries:
            if is_hidden(entry.name):
                continue
            path = Path(entry.path)
            try:
                is_dir = entry.is_dir()
                is_file = not is_dir and entry.is_file()
            except OSError:
                is_dir = is_file = False
            if is_dir:
                real = os.path.realpath(path)
                if real not in ancestors:  # a link back to a folder being listed adds no image
                    visit(path, ancestors | {real})
            elif path.suffix.lower() in IMAGE_EXTENSIONS:
                if is_file or entry.is_symlink():
                    images.append(path)
            elif entry.is_symlink() and not os.path.exists(path):
                problems.append({"path": str(path), "error": _link_error(path)})

    visit(folder, frozenset({os.path.realpath(folder)}))
    return sorted(images, key=lambda path: path.relative_to(folder).as_posix()), problems


def list_images(folder: str | Path, *, problems: list[dict[str, str]] | None = None) -> list[Path]:
    """Image files under ``folder`` (recursively), sorted by their POSIX path relative to it.

    Parameters
    ----------
    folder : str or Path
    problems : list, optional
        Receives the listing problems of :func:`scan_images` (folders that cannot be read, broken links). By
        default a problem raises :class:`ImageListingError`: a silently incomplete list would shift indices.
    """
    paths, found = scan_images(folder)
    if found and problems is None:
        raise ImageListingError(folder, found)
    if problems is not None:
        problems.extend(found)
    return paths
