"""Uncertainty methods: the names users type (``SU``, ``PA``, ``SUE``, ``GV-SIFT``, ...).

Every registered method is called the same way, on a :class:`~vpr_uncertainty.retrieval.Retrieval`::

    get_method("SU")(retrieval, k=10, alpha=0.5)   # -> ndarray of shape (Q,), higher = less trustworthy

The registry is a :class:`~vpr_uncertainty.plugins.Registry` (:data:`METHODS`): each entry declares its
``kind`` (``"score"``, ``"spatial"``, ``"geometric"``, ``"learned"``), whether it is evaluated by ``default``,
what it ``requires``, its ``extra`` and its ``options``; ``available_methods(kind="score")`` queries them.
Options a method does not use are ignored, so one set of options can be passed to all methods, but an option
that no selected method takes is an error (:func:`check_options`). A method that needs heavy dependencies is
registered by the dotted path of its function (``"package.module:function"``) and imported only when first
called; a method that reads files declares a ``resolve`` hook, run once by the stage, that turns paths into the
arrays and models the function receives.

Method specs
------------
A name can carry the method's own options: ``"SUE:clip=one-sided,slope=300"`` (:func:`parse_method_spec`).
Values are typed like the option's default, unknown option names are errors that list the valid ones, and
:func:`get_method` returns an entry named by the spec, whose options override those passed at call time, so two
variants of one method are evaluated (and shown) side by side.

Cascades
--------
``"SU+GV-SIFT"`` (any score method ``+`` any ``GV-*`` method) ranks every query by the score method and runs
geometric verification only on the ``verify_fraction`` (default 0.3) it doubts most
(:mod:`vpr_uncertainty.methods.cascade`); ``"SU+GV-SIFT:verify_fraction=0.5"`` sets the fraction.

Needs
-----
``requires`` names what a method cannot run without: a retrieval field or an option, or one of the groups of
:data:`NEEDS` (``"images"``, ``"btl_head"``, ``"descriptors"``, ``"local_features"``, ``"database_positions"``).
:meth:`UncertaintyMethod.unmet_needs` says which are missing before any work.
"""

# Importing the built-ins registers them (before any caller can look one up).
from vpr_uncertainty.methods.builtin import GEOMETRIC_METHODS, SCORE_ONLY_METHODS
from vpr_uncertainty.methods.entries import (
    METHODS,
    NEEDS,
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
    register_method,
    split_method_list,
)

__all__ = [
    "GEOMETRIC_METHODS",
    "METHODS",
    "NEEDS",
    "SCORE_ONLY_METHODS",
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
    "register_method",
    "split_method_list",
]
