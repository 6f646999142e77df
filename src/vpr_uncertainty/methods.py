"""Registry of uncertainty methods: the names users type (``SU``, ``PA``, ``SUE``, ``GV-SIFT``, ...).

Every registered method is called the same way, on a :class:`~vpr_uncertainty.retrieval.Retrieval`::

    get_method("SU")(retrieval, k=10, alpha=0.5)   # -> ndarray of shape (Q,), higher = less trustworthy

Options a method does not use are ignored, so one set of options can be passed to all methods. A method that
needs heavy dependencies is registered by the dotted path of its function (``"package.module:function"``) and
imported only when first called.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vpr_uncertainty import scores as _scores
from vpr_uncertainty.retrieval import Retrieval

__all__ = ["OwnRetrievalUncertainty", "UncertaintyMethod", "available_methods", "get_method", "register_method"]

MethodFunction = Callable[..., "np.ndarray | OwnRetrievalUncertainty"]


@dataclass
class OwnRetrievalUncertainty:
    """What a method returns when it answers the queries with its own retrieval (e.g. BTL's mean embeddings).

    The evaluation then judges correctness by the top-1 of ``retrieval``, not by the shared retrieval, and says
    so in its notes.

    Attributes
    ----------
    uncertainty : ndarray of shape (Q,)
        Higher = less trustworthy.
    retrieval : Retrieval
        The method's own top-k for the same queries, with the same ground truth.
    """

    uncertainty: np.ndarray
    retrieval: Retrieval


@dataclass
class UncertaintyMethod:
    """One registered uncertainty method.

    Attributes
    ----------
    name : str
        The name users type.
    description : str
        One line for tables and ``--help``.
    target : callable or str
        ``function(retrieval, **options) -> ndarray (Q,)`` or its dotted path ``"module:function"``.
    requires : tuple of str
        Retrieval fields that must be present (e.g. ``("database_positions",)``).
    extra : str or None
        The pip extra that provides its dependencies, named in the error when they are missing.
    """

    name: str
    description: str
    target: MethodFunction | str
    requires: tuple[str, ...] = ()
    extra: str | None = None
    _function: MethodFunction | None = field(default=None, init=False, repr=False)

    @property
    def function(self) -> MethodFunction:
        if self._function is None:
            if callable(self.target):
                self._function = self.target
            else:
                module_name, _, attribute = self.target.partition(":")
                try:
                    module = importlib.import_module(module_name)
                except ImportError as error:
                    hint = f"; install it with: pip install 'vpr-uncertainty[{self.extra}]'" if self.extra else ""
                    raise ImportError(
                        f"uncertainty method {self.name!r} needs a missing dependency ({error.name}){hint}"
                    ) from error
                self._function = getattr(module, attribute)
        return self._function

    def accepted_options(self) -> set[str] | None:
        """Keyword options the function takes (None when it takes any)."""
        parameters = inspect.signature(self.function).parameters.values()
        if any(parameter.kind is inspect.Parameter.VAR_KEYWORD for parameter in parameters):
            return None
        return {parameter.name for parameter in parameters if parameter.kind is not inspect.Parameter.POSITIONAL_ONLY}

    def __call__(self, retrieval: Retrieval, **options: Any) -> np.ndarray | OwnRetrievalUncertainty:
        missing = [name for name in self.requires if getattr(retrieval, name, None) is None]
        if missing:
            raise ValueError(f"uncertainty method {self.name!r} needs {', '.join(missing)} in the retrieval")
        accepted = self.accepted_options()
        if accepted is not None:
            options = {key: value for key, value in options.items() if key in accepted}
        result = self.function(retrieval, **options)
        uncertainty = np.asarray(result.uncertainty if isinstance(result, OwnRetrievalUncertainty) else result)
        if isinstance(result, OwnRetrievalUncertainty) and result.retrieval.n_queries != retrieval.n_queries:
            raise RuntimeError(f"uncertainty method {self.name!r} answered a different number of queries")
        if uncertainty.shape != (retrieval.n_queries,):
            raise RuntimeError(
                f"uncertainty method {self.name!r} returned shape {uncertainty.shape}, "
                f"expected ({retrieval.n_queries},)"
            )
        if not np.isfinite(uncertainty).all():
            raise RuntimeError(f"uncertainty method {self.name!r} returned NaN or inf")
        return result


_REGISTRY: dict[str, UncertaintyMethod] = {}


def register_method(
    name: str,
    target: MethodFunction | str,
    *,
    description: str,
    requires: tuple[str, ...] = (),
    extra: str | None = None,
    overwrite: bool = False,
) -> UncertaintyMethod:
    """Add a method to the registry and return its entry.

    Parameters
    ----------
    name : str
        The name users type; must be new unless ``overwrite=True``.
    target : callable or str
        ``function(retrieval, **options) -> ndarray (Q,)``, higher = less trustworthy, or its dotted path.
    description : str
        One line for tables and ``--help``.
    requires : tuple of str
        Retrieval fields the method needs.
    extra : str, optional
        The pip extra that provides its dependencies.
    overwrite : bool
        Replace an existing entry of that name.
    """
    if name in _REGISTRY and not overwrite:
        raise ValueError(f"an uncertainty method named {name!r} is already registered")
    entry = UncertaintyMethod(name=name, description=description, target=target, requires=requires, extra=extra)
    _REGISTRY[name] = entry
    return entry


def get_method(name: str) -> UncertaintyMethod:
    """The registered method called ``name`` (case-sensitive, as in ``SU`` or ``GV-SIFT``)."""
    try:
        return _REGISTRY[name]
    except KeyError:
        close = [known for known in _REGISTRY if known.lower() == name.lower()]
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise KeyError(
            f"unknown uncertainty method {name!r}{hint} Available: {', '.join(available_methods())}"
        ) from None


def available_methods() -> list[str]:
    """Names of all registered methods, in registration order."""
    return list(_REGISTRY)


# --- score-only methods ------------------------------------------------------------------------------------


def _ratio_spread(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.ratio_spread(retrieval.scores, k)


def _similarity_distribution(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.similarity_distribution(retrieval.scores, k)


def _statistical_uncertainty(retrieval: Retrieval, *, k: int = 10, alpha: float = 0.5) -> np.ndarray:
    return _scores.statistical_uncertainty(retrieval.scores, k, alpha)


def _best_match(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.best_match(retrieval.scores, k)


def _l2_distance(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.l2_distance(retrieval.scores, k, distances=retrieval.distances)


def _perceptual_aliasing(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.perceptual_aliasing(retrieval.scores, k, distances=retrieval.distances)


def _margin(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.margin(retrieval.scores, k)


register_method("RS", _ratio_spread, description="Ratio Spread: mean s_i/s_1 of the runners-up")
register_method("SD", _similarity_distribution, description="Similarity Distribution: median/s_1")
register_method("SU", _statistical_uncertainty, description="Statistical Uncertainty: α·RS + (1−α)·SD")
register_method("BM", _best_match, description="Best match: −s_1")
register_method("L2", _l2_distance, description="Top-1 L2 descriptor distance d_1")
register_method("PA", _perceptual_aliasing, description="Perceptual aliasing: d_1/d_2")
register_method("margin", _margin, description="Negated margin s_2 − s_1")

SCORE_ONLY_METHODS: tuple[str, ...] = ("RS", "SD", "SU", "BM", "L2", "PA", "margin")

register_method(
    "SUE",
    "vpr_uncertainty.spatial:sue_from_retrieval",
    description="Spatial uncertainty: weighted spread of the top-k database positions (Zaffar et al. 2024)",
    requires=("database_positions",),
)

# --- geometric verification: −(RANSAC inliers between each query and its top-1); needs the image files ----------

_GV = "vpr_uncertainty.geometric.verify:"
register_method(
    "GV-SIFT", _GV + "gv_sift", description="−RANSAC inliers with the top-1: SIFT, ratio test, MAGSAC++", extra="opencv"
)
register_method("GV-DISK-LG", _GV + "gv_disk_lightglue", description="−RANSAC inliers: DISK + LightGlue", extra="gv")
register_method("GV-XFEAT", _GV + "gv_xfeat", description="−RANSAC inliers: XFeat + LighterGlue", extra="gv")
register_method(
    "GV-SP-SG", _GV + "gv_superpoint_superglue", description="−RANSAC inliers: SuperPoint + SuperGlue", extra="gv"
)
register_method(
    "GV-SP-LG", _GV + "gv_superpoint_lightglue", description="−RANSAC inliers: SuperPoint + LightGlue", extra="gv"
)
register_method(
    "GV-H5", _GV + "gv_h5", description="−RANSAC inliers from precomputed local features (hloc HDF5)", extra="opencv"
)
GEOMETRIC_METHODS: tuple[str, ...] = ("GV-SIFT", "GV-DISK-LG", "GV-XFEAT", "GV-SP-SG", "GV-SP-LG", "GV-H5")

register_method(
    "BTL",
    "vpr_uncertainty.learned.method:btl_uncertainty",
    description="Bayesian triplet loss: query variance of a trained head, with its own retrieval (Warburg et al. 2021)",
    extra="torch",
)
