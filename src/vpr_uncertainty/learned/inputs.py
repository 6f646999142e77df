"""Reading what the ``BTL`` method needs from files: the head file and the frozen descriptors.

This is the method's declared ``resolve`` hook (see :class:`~vpr_uncertainty.methods.UncertaintyMethod`): the
stage that evaluates methods calls :func:`resolve_btl_inputs` once, before timing, and the method itself
(:func:`~vpr_uncertainty.learned.method.btl_uncertainty`) receives only a loaded :class:`BTLHead` and arrays.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from vpr_uncertainty.learned.model import BTLHead, load_btl_head
from vpr_uncertainty.learned.training import resolve_device
from vpr_uncertainty.retrieval import Retrieval

__all__ = ["read_btl_descriptors", "read_btl_head", "resolve_btl_inputs"]


def read_btl_head(value: object, *, device: str = "cpu") -> BTLHead:
    """A loaded head from ``value`` (a head file written by ``train-btl``, or a :class:`BTLHead`), on ``device``."""
    if value is None or isinstance(value, BTLHead):
        return value  # type: ignore[return-value]  # the method says what is missing
    if not isinstance(value, (str, Path)):
        raise TypeError(f"btl_head must be the path of a head file or a BTLHead, got {type(value).__name__}")
    path = Path(value)
    if not path.is_file():
        raise FileNotFoundError(f"BTL head file not found: {path} (train one with `vpr-uncertainty train-btl`)")
    head = load_btl_head(path, device=resolve_device(device))
    head.source_path = str(path)  # recorded in the config of BTL's own retrieval
    return head


def read_btl_descriptors(value: object, split: str, names: object = None) -> object:
    """Descriptors of ``split`` (``"queries"`` or ``"database"``) from a ``.npy`` or descriptor-cache ``.h5`` path.

    Arrays (and None) are returned as they are. The image names of a cache are checked against ``names`` (the
    retrieval's) when both are known.
    """
    if not isinstance(value, (str, Path)):
        return value
    from vpr_uncertainty.retrieval import load_descriptors

    option = "query_descriptors" if split == "queries" else "database_descriptors"
    file_names, array = load_descriptors(value, split)
    if file_names is not None and names is not None and list(file_names) != [str(name) for name in names]:
        raise ValueError(f"{option}: the image names in the descriptor file differ from the retrieval's {split} names")
    return array


def resolve_btl_inputs(retrieval: Retrieval, options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` with ``btl_head`` loaded and ``query_descriptors`` / ``database_descriptors`` read from files."""
    resolved = dict(options)
    device = str(resolved.get("device") or "cpu")
    resolved["btl_head"] = read_btl_head(resolved.get("btl_head"), device=device)
    resolved["query_descriptors"] = read_btl_descriptors(
        resolved.get("query_descriptors"), "queries", retrieval.query_names
    )
    resolved["database_descriptors"] = read_btl_descriptors(
        resolved.get("database_descriptors"), "database", retrieval.database_names
    )
    return resolved
