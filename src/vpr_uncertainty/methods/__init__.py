"""Uncertainty methods: the names users type (``SU``, ``PA``, ``SUE``, ``GV-SIFT``, ``SU+GV-SIFT``), called alike.

``get_method("SU")(retrieval, k=10, alpha=0.5)`` returns an ndarray of shape (Q,), higher = less trustworthy.
"""

# Importing the built-ins and the cascades registers them (before any caller can look one up).
from vpr_uncertainty.methods import builtin, cascade  # noqa: F401
from vpr_uncertainty.methods.entries import (
    METHODS,
    NEEDS,
    PATH_OPTIONS,
    STAGE_INPUTS,
    DetailedUncertainty,
    OwnRetrievalUncertainty,
    UncertaintyMethod,
    available_methods,
    check_options,
    default_method_names,
    describe_needs,
    get_method,
    parse_method_spec,
    register_composer,
    register_method,
    split_method_list,
    typed_option,
)

__all__ = [
    "METHODS",
    "NEEDS",
    "PATH_OPTIONS",
    "STAGE_INPUTS",
    "DetailedUncertainty",
    "OwnRetrievalUncertainty",
    "UncertaintyMethod",
    "available_methods",
    "check_options",
    "default_method_names",
    "describe_needs",
    "get_method",
    "parse_method_spec",
    "register_composer",
    "register_method",
    "split_method_list",
    "typed_option",
]
