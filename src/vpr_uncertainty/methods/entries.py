"""Uncertainty-method entries: what one is (:class:`UncertaintyMethod`), where they are kept (:data:`METHODS`), and
the functions that add, find, parse (method specs, ``"SUE:clip=one-sided"``) and check them. How options reach a
method: see docs/explanation/uncertainty-scores.md.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import functools
import inspect
import math
import warnings
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vpr_uncertainty import cache
from vpr_uncertainty import scores as _scores
from vpr_uncertainty.identity import target_identity
from vpr_uncertainty.plugins import Registry, load_plugins, load_target
from vpr_uncertainty.retrieval import Retrieval

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
    "spec_options",
    "split_method_list",
    "typed_option",
]


_TRUE, _FALSE = {"true", "yes", "1", "on"}, {"false", "no", "0", "off"}


def typed_option(text: str, default: Any, where: str) -> Any:
    """``text`` converted to the type of ``default`` (str when the default is None or a string)."""
    try:
        if isinstance(default, bool):
            if text.lower() not in _TRUE | _FALSE:
                raise ValueError
            return text.lower() in _TRUE
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float):
            value = float(text)
            if not math.isfinite(value):
                raise ValueError
            return value
    except ValueError:
        kind = {bool: "true or false", int: "an integer", float: "a finite number"}[type(default)]
        raise ValueError(f"{where} must be {kind}, got {text!r}") from None
    return text


def spec_options(spec: str, defaults: Mapping[str, Any], what: str) -> dict[str, Any]:
    """The ``option=value`` items after the colon of ``spec`` (a ``what``: ``"method spec"``, ``"report figure"``),
    each typed like its default in ``defaults``; a malformed, unknown or repeated option is a ValueError naming it."""
    name, _, rest = (part.strip() for part in spec.partition(":"))
    options: dict[str, Any] = {}
    for item in rest.split(","):
        key, equals, value = (part.strip() for part in item.partition("="))
        if not key or not equals or not value:
            raise ValueError(f"{what} {spec!r}: expected option=value after {name}:, got {item.strip()!r}")
        if key not in defaults:
            valid = ", ".join(sorted(defaults)) or "none"
            raise ValueError(f"{what} {spec!r}: {name} has no option {key!r} (its options: {valid})")
        if key in options:
            raise ValueError(f"{what} {spec!r}: option {key!r} is given twice")
        options[key] = typed_option(value, defaults[key], f"{what} {spec!r}: option {key!r}")
    return options


def split_method_list(text: str) -> list[str]:
    """Split a comma-separated list of method specs; ``option=value`` items belong to the spec before them.

    Examples
    --------
    >>> split_method_list("SU, SUE:clip=one-sided,slope=300, BM")
    ['SU', 'SUE:clip=one-sided,slope=300', 'BM']
    """
    specs: list[str] = []
    for item in (part.strip() for part in text.split(",")):
        if not item:
            continue
        if "=" in item and ":" not in item.split("=", 1)[0]:
            if not specs or ":" not in specs[-1]:
                raise ValueError(f"option {item!r} follows no method spec (write NAME:{item})")
            specs[-1] += f",{item}"
        else:
            specs.append(item)
    return specs


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
    details : dict of str to JSON values
        Reported beside the method's metrics, as for :class:`DetailedUncertainty` (e.g. BTL's
        ``trained_on_queries``).
    """

    uncertainty: np.ndarray
    retrieval: Retrieval
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class DetailedUncertainty:
    """What a method returns when it also reports numbers about its run (e.g. a cascade's ``verified_fraction``).

    Attributes
    ----------
    uncertainty : ndarray of shape (Q,)
        Higher = less trustworthy.
    details : dict of str to JSON values
        Reported beside the method's metrics (``results.json``, ``evaluate --json``).
    """

    uncertainty: np.ndarray
    details: dict[str, Any] = field(default_factory=dict)


MethodFunction = Callable[..., "np.ndarray | OwnRetrievalUncertainty | DetailedUncertainty"]

#: Named needs: the retrieval fields or options that satisfy each (all of them), and how to say it.
NEEDS: dict[str, tuple[tuple[str, ...], str]] = {
    "database_positions": (("database_positions",), "database_positions"),
    "images": (("query_paths", "database_paths"), "the query and database image files (query_paths, database_paths)"),
    "btl_head": (("btl_head",), "a trained BTL head (option btl_head=HEAD.pt, written by train-btl)"),
    "descriptors": (
        ("query_descriptors", "database_descriptors"),
        "the frozen descriptors of queries and database (query_descriptors, database_descriptors)",
    ),
    "local_features": (("features_path",), "precomputed local features (option features_path=FILE.h5)"),
    "gate": (("gate",), "a fitted gate (option gate=GATE.json, written by `vpr-uncertainty calibrate`)"),
}


#: Options that name a file (relative to a grid's config file when given there).
PATH_OPTIONS: frozenset[str] = frozenset({"btl_head", "features_path", "gate"})


#: Inputs a stage offers every selected method: used by the methods that take them, ignored by the others
#: (``executor``: where the geometric verification methods verify their pairs, from the command's ``--executor``).
STAGE_INPUTS: frozenset[str] = frozenset(
    {"query_paths", "database_paths", "query_descriptors", "database_descriptors", "cache_dir", "device", "executor"}
)


@dataclass
class UncertaintyMethod:
    """One registered uncertainty method, or a variant of one with its own options (a method spec).

    Attributes
    ----------
    name : str
        The name users type (for a variant, the spec, e.g. ``"SUE:clip=one-sided"``).
    description : str
        One line for tables and ``--help``.
    target : callable or str
        ``function(retrieval, **options) -> ndarray (Q,)`` or its dotted path ``"module:function"``.
    requires : tuple of str
        What the method cannot run without: retrieval fields or options (e.g. ``("database_positions",)``), or
        names of :data:`NEEDS` (e.g. ``"images"``).
    extra : str or None
        The pip extra that provides its dependencies, named in the error when they are missing.
    options : dict or None
        The options a spec may set, with their defaults (whose types type the values); None: the keyword
        parameters of the function.
    validate : callable or str or None
        ``validate(**options)`` raises ValueError for a bad value (or its dotted path).
    kind : {"score", "spatial", "calibrated", "geometric", "learned", "cascade"}
        What the method works from: the top-k scores only, database positions, a fitted gate, the images, a trained
        model, or a cascade of two methods; listings are ordered by kind.
    default : bool
        Evaluated when no methods are named (``evaluate``'s default list).
    resolve : callable or str or None
        ``resolve(retrieval, options) -> options`` that reads the files named by options (paths) into what the
        function takes (arrays, a loaded model); run once by the stage before timing (or its dotted path).
    bound : dict
        Options of this variant; they override the options given at call time.
    base : str or None
        The registered name of a variant (None for a registered entry).
    reads : tuple of str
        Retrieval fields the function takes in place of the retrieval (e.g. ``("scores", "distances")`` for
        ``l2_distance(scores, k, *, distances)``): the first positionally, the others as keywords of their name.
    scores : {"any", "similarity", "cosine"}
        What the method assumes of the retrieval's scores: nothing (``"any"``: BM, margin, the methods that do not
        read them), similarities with a positive best score (``"similarity"``: RS, SD, SU divide by s_1), or
        cosine similarities in [−1, 1] unless the retrieval holds its distances (``"cosine"``: L2, PA, SUE use
        d² = 2 − 2s). :meth:`unsuited_to` says why a retrieval does not fit; such a method is left out of the
        default list (:func:`default_method_names`), and named explicitly it raises its own error.
    replaces : str or None
        The module of the built-in method of this name that this (a plugin's) entry replaced.
    """

    name: str
    description: str
    target: MethodFunction | str
    requires: tuple[str, ...] = ()
    extra: str | None = None
    options: dict[str, Any] | None = None
    validate: Callable[..., None] | str | None = None
    kind: str = "score"
    default: bool = False
    resolve: Callable[..., dict[str, Any]] | str | None = None
    bound: dict[str, Any] = field(default_factory=dict)
    base: str | None = None
    reads: tuple[str, ...] = ()
    scores: str = "any"
    replaces: str | None = None
    _function: MethodFunction | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.scores not in SCORE_ASSUMPTIONS:
            raise ValueError(f"scores must be one of {SCORE_ASSUMPTIONS}, got {self.scores!r}")

    def identity(self) -> dict[str, Any]:
        """What this method's output depends on besides its inputs, for the fingerprints of the caches: its name,
        the content of every file its bound options name, and the code of its function and hooks (a cascade's
        two methods included), by :func:`~vpr_uncertainty.identity.target_identity`."""
        hooks = [hook for hook in (self.target, self.resolve, self.validate) if hook is not None]
        closure = [cell.cell_contents for cell in getattr(self.target, "__closure__", None) or ()]
        return {
            "name": self.name,
            "files": cache.named_files_key(self.bound.values()),
            "code": [target_identity(hook) for hook in hooks]
            + [part.identity() for part in closure if isinstance(part, UncertaintyMethod)],
        }

    def unsuited_to(self, retrieval: Retrieval) -> str | None:
        """Why the retrieval's scores do not fit what this method assumes (:attr:`scores`), or None when they do."""
        if self.scores == "similarity":
            if retrieval.score_kind == "distance":
                return "they divide by the best similarity s_1, and these scores are distances"
            if retrieval.n_queries and not (retrieval.scores[:, 0] > 0).any():
                low, high = _score_range(retrieval.scores[:, :1])
                return (
                    f"they divide by the best similarity s_1, and no query's is positive (s_1 in [{low:.4g}, "
                    f"{high:.4g}]; for distances or negated distances, read them as distances: --scores distance, "
                    "or l2-distance / cosine-distance of unit-norm descriptors)"
                )
        if self.scores == "cosine" and retrieval.distances is None:
            if retrieval.score_kind == "distance":
                return "it needs squared L2 distances, and these lower-is-better scores hold values below 0"
            low, high = _score_range(retrieval.scores[:, :2])
            tolerance = _scores.COSINE_TOLERANCE
            if low < -1 - tolerance or high > 1 + tolerance:
                return (
                    f"they need cosine similarities in [-1, 1] (d² = 2 − 2s) or the candidates' distances, and "
                    f"the scores lie in [{low:.4g}, {high:.4g}]"
                )
        return None

    @property
    def function(self) -> MethodFunction:
        if self._function is None:
            self._function = load_target(self.target, what=f"uncertainty method {self.name!r}", extra=self.extra)
        return self._function

    def resolve_inputs(self, retrieval: Retrieval, options: Mapping[str, Any]) -> dict[str, Any]:
        """``options`` with this variant's bound options, and files read by the declared ``resolve`` hook."""
        options = {**options, **self.bound}
        if self.resolve is None:
            return options
        hook = load_target(self.resolve, what=f"uncertainty method {self.name!r}", extra=self.extra)
        return dict(hook(retrieval, options))

    def accepted_options(self) -> set[str] | None:
        """Keyword options the function takes (None when it takes any); with ``reads``, the declared options."""
        if self.reads:
            return set(self.option_defaults())
        parameters = inspect.signature(self.function).parameters.values()
        if any(parameter.kind is inspect.Parameter.VAR_KEYWORD for parameter in parameters):
            return None
        return {parameter.name for parameter in parameters if parameter.kind is not inspect.Parameter.POSITIONAL_ONLY}

    def option_defaults(self) -> dict[str, Any]:
        """The options a spec may set, with their defaults (declared, else the function's keyword parameters)."""
        if self.options is not None:
            return dict(self.options)
        parameters = inspect.signature(self.function).parameters.values()
        return {
            p.name: p.default
            for p in parameters
            if p.kind is inspect.Parameter.KEYWORD_ONLY
            or (p.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD and p.default is not inspect.Parameter.empty)
        }

    def unmet_needs(self, available: Collection[str]) -> list[str]:
        """The entries of ``requires`` not met by ``available`` (names of retrieval fields and options present).

        Examples
        --------
        >>> get_method("GV-SIFT").unmet_needs({"scores", "indices"})
        ['images']
        >>> describe_needs(["images"])
        'the query and database image files (query_paths, database_paths)'
        """
        given = set(available) | {key for key, value in self.bound.items() if value is not None}
        return [need for need in self.requires if not all(key in given for key in NEEDS.get(need, ((need,), ""))[0])]

    def bind(self, retrieval: Retrieval, options: Mapping[str, Any]) -> Callable[[], Any]:
        """The function on ``retrieval`` with the ``options`` it takes, as a call without arguments.

        ``options`` are already resolved (:meth:`resolve_inputs`); an unmet need is a ValueError, raised now. The
        function gets read-only views of the retrieval's arrays: writing into them fails instead of misleading the next.
        """
        present = [name for name in vars(retrieval) if getattr(retrieval, name) is not None]
        missing = self.unmet_needs([*present, *(key for key, value in options.items() if value is not None)])
        if missing:
            raise ValueError(f"uncertainty method {self.name!r} needs {describe_needs(missing)}")
        if self.scores == "cosine" and retrieval.score_kind == "distance" and retrieval.distances is None:
            where = retrieval.config.get("source", "the retrieval")
            raise ValueError(f"uncertainty method {self.name!r} on {where}: {self.unsuited_to(retrieval)}")
        accepted = self.accepted_options()
        if accepted is not None:
            options = {key: value for key, value in options.items() if key in accepted}
        retrieval = _read_only(retrieval)
        if not self.reads:
            return functools.partial(self.function, retrieval, **options)
        first, *others = self.reads
        fields = {name: getattr(retrieval, name) for name in others}
        return functools.partial(self.function, getattr(retrieval, first), **options, **fields)

    def check_result(
        self, result: Any, retrieval: Retrieval
    ) -> np.ndarray | OwnRetrievalUncertainty | DetailedUncertainty:
        """``result`` when it holds one finite real uncertainty per query of ``retrieval``, else an error naming it."""
        wrapped = isinstance(result, (OwnRetrievalUncertainty, DetailedUncertainty))
        uncertainty = np.asarray(result.uncertainty if wrapped else result)
        if uncertainty.dtype.kind not in "biuf":
            kinds = {"c": "complex numbers", "U": "strings", "S": "bytes", "O": "Python objects"}
            what = f"returned {kinds.get(uncertainty.dtype.kind, uncertainty.dtype)}"
            raise TypeError(f"uncertainty method {self.name!r} {what}; it must return one real number per query")
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

    def __call__(
        self, retrieval: Retrieval, **options: Any
    ) -> np.ndarray | OwnRetrievalUncertainty | DetailedUncertainty:
        call = self.bind(retrieval, self.resolve_inputs(retrieval, options))
        with self.naming_errors():
            return self.check_result(call(), retrieval)

    @contextlib.contextmanager
    def naming_errors(self) -> Iterator[None]:
        """Re-raise an error of the method's call as one line that names the method (its traceback: ``--debug``), of
        the same kind when it is one the command line reports as such (its exit status), else as a RuntimeError."""
        try:
            yield
        except Exception as error:
            if str(error).startswith("uncertainty method "):  # names a method already (this one, or one it called)
                raise
            kinds = (ImportError, FileNotFoundError, PermissionError, ValueError, TypeError, KeyError, OSError)
            text = str(error.args[0] if isinstance(error, KeyError) and error.args else error) or type(error).__name__
            if "read-only" in text:
                text += " (the retrieval's arrays are read-only: a method copies what it changes)"
            kind = next((kind for kind in kinds if isinstance(error, kind)), RuntimeError)
            raise kind(f"uncertainty method {self.name!r} failed: {text}") from error


def _read_only(retrieval: Retrieval) -> Retrieval:
    """A shallow copy of ``retrieval`` whose arrays (the sparse positives' too) are read-only views; config copied."""
    guarded, frozen = copy.copy(retrieval), functools.partial(np.lib.stride_tricks.as_strided, writeable=False)
    for name, value in vars(retrieval).items():
        if isinstance(value, np.ndarray):
            setattr(guarded, name, frozen(value))
        elif hasattr(value, "indptr"):  # scipy.sparse positives
            setattr(guarded, name, sparse := copy.copy(value))
            sparse.data, sparse.indices, sparse.indptr = map(frozen, (value.data, value.indices, value.indptr))
        elif isinstance(value, dict):
            setattr(guarded, name, dict(value))
    return guarded


#: What a method may assume of the scores (:attr:`UncertaintyMethod.scores`).
SCORE_ASSUMPTIONS: tuple[str, ...] = ("any", "similarity", "cosine")


def _score_range(scores: np.ndarray) -> tuple[float, float]:
    """The smallest and largest finite score (0, 0 when there is none)."""
    finite = scores[np.isfinite(scores)]
    return (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)


def describe_needs(needs: Collection[str]) -> str:
    """Say what the named needs (entries of ``UncertaintyMethod.requires``) are, in words, joined by "; "."""
    return "; ".join(NEEDS[need][1] if need in NEEDS else need for need in needs)


#: Listings show the methods by kind (in this order), each kind in registration order: plugins, the package's own
#: higher layers included, register in the order their modules are imported.
_KIND_ORDER = {"score": 0, "spatial": 1, "calibrated": 2, "geometric": 3, "learned": 4}


class _MethodRegistry(Registry[UncertaintyMethod]):
    def entries(self, **attributes: Any) -> list[UncertaintyMethod]:
        """Entries with the given attributes, by kind (:data:`_KIND_ORDER`), each kind in registration order."""
        return sorted(super().entries(**attributes), key=lambda entry: _KIND_ORDER.get(entry.kind, len(_KIND_ORDER)))


#: The registered uncertainty methods.
METHODS: Registry[UncertaintyMethod] = _MethodRegistry("uncertainty method", label="available")


def check_options(methods: Sequence[UncertaintyMethod], options: Collection[str]) -> None:
    """Raise ValueError when an option is taken by none of ``methods`` (nor one of :data:`STAGE_INPUTS`).

    Examples
    --------
    >>> check_options([get_method("SU")], ["alpha"])
    >>> check_options([get_method("SU"), get_method("BM")], ["btl_haed"])
    Traceback (most recent call last):
    ...
    ValueError: no selected uncertainty method (SU, BM) takes the option 'btl_haed'; their options: alpha, k
    """
    taken: set[str] = set()
    for entry in methods:
        accepted = entry.accepted_options() if entry.options is None else set(entry.option_defaults())
        if accepted is None:
            return
        taken |= accepted
    unknown = [name for name in options if name not in taken and name not in STAGE_INPUTS]
    if unknown:
        names = ", ".join(entry.name for entry in methods)
        valid = ", ".join(sorted(taken - {"retrieval"})) or "none"
        listed = ", ".join(repr(name) for name in unknown)
        raise ValueError(f"no selected uncertainty method ({names}) takes the option {listed}; their options: {valid}")


def register_method(
    name: str,
    target: MethodFunction | str,
    *,
    description: str,
    requires: tuple[str, ...] = (),
    extra: str | None = None,
    options: Mapping[str, Any] | None = None,
    validate: Callable[..., None] | str | None = None,
    kind: str = "score",
    default: bool = False,
    resolve: Callable[..., dict[str, Any]] | str | None = None,
    reads: Sequence[str] = (),
    scores: str = "any",
    overwrite: bool = False,
) -> UncertaintyMethod:
    """Add a method to the registry and return its entry.

    The arguments are the attributes of :class:`UncertaintyMethod`; ``name`` must be new unless ``overwrite=True``
    and hold no ``:``, ``,``, ``=`` or ``+``. The function (``target``) returns an ndarray of shape (Q,), higher =
    less trustworthy.

    Examples
    --------
    >>> import numpy as np
    >>> entry = register_method("ENT-demo", lambda retrieval, *, k=10: -retrieval.scores[:, 0], description="demo")
    >>> entry.option_defaults(), METHODS.unregister("ENT-demo").name
    ({'k': 10}, 'ENT-demo')
    """
    if name in METHODS and not overwrite:
        raise ValueError(f"an uncertainty method named {name!r} is already registered")
    previous, replaces = METHODS.get(name) if name in METHODS else None, None
    if previous is not None and not _is_builtin(target):  # a user's method in place of a built-in: tables say so
        replaces = previous.replaces or (_module(previous.target) if _is_builtin(previous.target) else None)
    if not name or any(character in name for character in ":,=+"):
        raise ValueError(f"a method name must be non-empty and hold no ':', ',', '=' or '+', got {name!r}")
    entry = UncertaintyMethod(
        name=name,
        description=description,
        target=target,
        requires=tuple(requires),
        extra=extra,
        options=None if options is None else dict(options),
        validate=validate,
        kind=kind,
        default=default,
        resolve=resolve,
        reads=tuple(reads),
        scores=scores,
        replaces=replaces,
    )
    return METHODS.register(entry, overwrite=overwrite)


def _module(target: Any) -> str:
    """The module of a callable or dotted target."""
    return target.partition(":")[0] if isinstance(target, str) else str(getattr(target, "__module__", ""))


def _is_builtin(target: Any) -> bool:
    return _module(target).split(".")[0] == "vpr_uncertainty"


def parse_method_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """Split a method spec ``"NAME[:option=value[,option=value...]]"`` into the registered name and its options.

    Values are typed like the option's default and checked by the method; an unknown name or option is an
    error that lists the valid ones.

    Examples
    --------
    >>> parse_method_spec("SUE:clip=one-sided,slope=300")
    ('SUE', {'clip': 'one-sided', 'slope': 300.0})
    >>> parse_method_spec("SU")
    ('SU', {})
    """
    if not isinstance(spec, str):
        raise TypeError(f"a method spec must be a string, got {spec!r}")
    name, colon, _ = (part.strip() for part in spec.partition(":"))
    entry = _lookup(name)
    if not colon:
        return name, {}
    options = spec_options(spec, entry.option_defaults(), "method spec")
    if entry.validate is not None:
        try:
            load_target(entry.validate, what=f"uncertainty method {name!r}", extra=entry.extra)(**options)
        except (ValueError, TypeError) as error:
            raise ValueError(f"method spec {spec!r}: {error}") from None
    return name, options


def get_method(name: str) -> UncertaintyMethod:
    """The registered method called ``name`` (case-sensitive, as in ``SU`` or ``GV-SIFT``), or a method spec.

    A spec such as ``"SUE:clip=one-sided"`` (see :func:`parse_method_spec`) gives the variant of the registered
    entry with those options bound, named by the spec (its options separated by ``,``, without spaces).
    """
    if isinstance(name, str) and ":" not in name:
        return _lookup(name.strip() if name.strip() in METHODS or "+" in name else name)
    base, options = parse_method_spec(name)
    entry = _lookup(base)
    if not options:
        return entry
    text = ",".join("=".join(part.strip() for part in item.split("=", 1)) for item in name.partition(":")[2].split(","))
    return dataclasses.replace(entry, name=f"{base}:{text}", bound={**entry.bound, **options}, base=base)


#: Builders of composite entries, by the separator their names hold (``"+"``: the cascades of :mod:`.cascade`).
_COMPOSERS: dict[str, Callable[[str], UncertaintyMethod]] = {}


def register_composer(separator: str, compose: Callable[[str], UncertaintyMethod]) -> None:
    """Make :func:`get_method` answer an unregistered name holding ``separator`` with ``compose(name)``."""
    _COMPOSERS[separator] = compose


def _lookup(name: str) -> UncertaintyMethod:
    """The registered entry ``name``, or the composite it names (e.g. the cascade ``"SU+GV-SIFT"``)."""
    if name not in METHODS:
        for separator, compose in _COMPOSERS.items():
            if separator in name:
                return compose(name)
    return METHODS.get(name)


def available_methods(**attributes: Any) -> list[str]:
    """Names of the registered methods by kind (score, spatial, calibrated, geometric, learned, others), each kind in
    registration order; optionally those with the given attributes.

    Examples
    --------
    >>> available_methods(kind="geometric")[:2]
    ['GV-SIFT', 'GV-DISK-LG']
    """
    load_plugins()
    return METHODS.names(**attributes)


def default_method_names(*, metric_positions: bool = False, retrieval: Retrieval | None = None) -> list[str]:
    """The methods evaluated when none are named, by ``evaluate``, ``run`` and ``demo`` alike.

    The registry's entries with ``default=True`` (in registration order), then its spatial methods (SUE) when
    the database positions are metric, since those need nothing else. Given the ``retrieval``, the methods whose
    assumptions about the scores it does not meet (:meth:`UncertaintyMethod.unsuited_to`: RS, SD, SU on distances;
    L2, PA, SUE on similarities outside [−1, 1] without distances) are left out, with one UserWarning that names them.

    Examples
    --------
    >>> default_method_names()
    ['RS', 'SD', 'SU', 'PA', 'L2', 'BM']
    >>> default_method_names(metric_positions=True)[-1]
    'SUE'
    """
    names = available_methods(default=True)
    if metric_positions:
        names += [name for name in available_methods(kind="spatial") if name not in names]
    if retrieval is None:
        return names
    reasons: dict[str, list[str]] = {}
    for name in names:
        reason = get_method(name).unsuited_to(retrieval)
        if reason is not None:
            reasons.setdefault(reason, []).append(name)
    if reasons:
        left_out = "; ".join(f"{', '.join(group)}: {reason}" for reason, group in reasons.items())
        warnings.warn(
            f"left out of the default methods ({left_out}); name one explicitly to run it anyway",
            UserWarning,
            stacklevel=2,
        )
    unsuited = {name for group in reasons.values() for name in group}
    return [name for name in names if name not in unsuited]
