"""One plugin mechanism for every extension point (uncertainty methods, GV presets, descriptor models, dataset and
results formats, executors, report figures): :class:`Registry`, :func:`load_plugins`, :func:`load_target`,
:func:`merge_options` and :class:`Travelling` (plugins replayed on Ray workers). See docs/explanation/architecture.md.

Examples
--------
>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Colour:
...     name: str
...     warm: bool
>>> colours = Registry("colour")
>>> _ = colours.register(Colour("red", True)); _ = colours.register(Colour("purple", False))
>>> colours.names(warm=True)
['red']
>>> colours.get("purpel")
Traceback (most recent call last):
...
KeyError: "unknown colour 'purpel'; did you mean 'purple'? valid: red, purple"
>>> merge_options({"ratio": 0.8, "mutual": True}, {"ratio": 0.9}, what="matcher")
{'ratio': 0.9, 'mutual': True}
"""

from __future__ import annotations

import difflib
import importlib
import importlib.util
import sys
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, Generic, TypeVar

_T = TypeVar("_T")

#: The entry-point group whose modules :func:`load_plugins` imports (``module`` or ``module:function``).
ENTRY_POINT_GROUP = "vpr_uncertainty.plugins"
#: A known name is suggested for an unknown one above this similarity (difflib ratio), or at it for a name of the
#: same length (a swap or a wrong letter): "GV-SFIT" -> "GV-SIFT" (0.86), "alpah" -> "alpha" (0.8, same length),
#: but not "GPA" -> "PA" (0.8, a letter more).
SUGGESTION_CUTOFF = 0.8
_entry_points_loaded = False
#: What this process imported as plugins, in order: target -> (the sys.path folder its module was found in, the
#: digest of its code, :func:`vpr_uncertainty.identity.code_identity`; both None for the toolkit's own modules).
_loaded: dict[str, tuple[str | None, str | None]] = {}


def load_plugins(modules: Iterable[str] = ()) -> None:
    """Import the plugin modules of the entry-point group (once per process), then ``modules``.

    Importing a plugin module registers its entries. A ``module:function`` entry point is imported and its
    function called with no argument.

    Raises
    ------
    ImportError
        When one of ``modules``, or an entry point of this package, cannot be imported. A third-party entry point
        that fails is a warning (a broken plugin must not stop the toolkit).
    """
    global _entry_points_loaded
    if not _entry_points_loaded:
        _entry_points_loaded = True
        from importlib import metadata

        for entry_point in metadata.entry_points(group=ENTRY_POINT_GROUP):
            distribution = getattr(entry_point.dist, "name", None) or "unknown"
            try:
                _import_plugin(entry_point.value)
            except Exception as error:
                if distribution.replace("_", "-") == "vpr-uncertainty":
                    raise
                warnings.warn(
                    f"plugin {entry_point.name!r} ({entry_point.value}) of the package {distribution} could not be "
                    f"loaded and is left out ({type(error).__name__}: {' '.join(str(error).split())}); repair or "
                    f"uninstall that package (pip uninstall {distribution})",
                    stacklevel=2,
                )
    for module in modules:
        if not module.endswith(".py") and str(Path.cwd()) not in sys.path:
            sys.path.append(str(Path.cwd()))  # a module in the current folder, as `python -m` finds it
        try:  # a file by its absolute path, which a Ray worker imports too
            _import_plugin(str(Path(module).resolve()) if module.endswith(".py") else module)
        except ModuleNotFoundError as error:
            if error.name and module.startswith(error.name):
                message = f"plugin module {module!r} not found (on the Python path, or in this folder as {module}.py)"
                raise ImportError(message) from None
            raise


def _import_file(path: Path) -> Any:
    """The module of the file ``path``, imported once under its stem (a stable name: what it defines pickles by
    it), with its folder on the Python path (for the modules beside it, as for a script)."""
    module = sys.modules.get(path.stem)
    if module is None and path.is_file():
        if str(path.parent) not in sys.path:
            sys.path.append(str(path.parent))
        spec = importlib.util.spec_from_file_location(path.stem, path)
        sys.modules[path.stem] = module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        try:
            spec.loader.exec_module(module)  # type: ignore[union-attr]
        except BaseException:
            del sys.modules[path.stem]
            raise
    elif getattr(module, "__file__", None) != str(path):
        taken = f"the module {path.stem!r} is already imported, from {getattr(module, '__file__', None)}; rename it"
        raise ImportError(f"plugin file {path}: {'not found' if module is None else taken}")
    return module


def _import_plugin(target: str) -> None:
    name, _, function = (target, "", "") if target.endswith(".py") else (p.strip() for p in target.partition(":"))
    path = Path(name) if name.endswith(".py") else None
    name = path.stem if path else name
    before = sys.modules.get(name)
    try:
        module = _import_file(path) if path else importlib.import_module(name)
        if function:
            getattr(module, function)()
    except SyntaxError as error:  # in the user's code: their file and line (an IndentationError too)
        line = f", line {error.lineno}" if error.lineno else ""
        raise ImportError(f"plugin {error.filename or target}{line}: {error.msg}; correct it there") from error
    if target not in _loaded or module is not before:  # the code of the module as it was executed
        from vpr_uncertainty.identity import code_identity

        file, own = getattr(module, "__file__", None), name.split(".")[0] == "vpr_uncertainty"
        depth = name.count(".") + (file is not None and file.endswith("__init__.py"))
        folder = None if own or file is None else str(Path(file).absolute().parents[depth])
        _loaded[target] = (folder, None if own else code_identity(name))


def loaded_plugins() -> tuple[tuple[str, str | None, str | None], ...]:
    """The plugins this process imported (entry points first, loaded now if they were not), in order:
    ``(target, folder, code)``, the folder of ``sys.path`` the module came from and the digest of its code."""
    load_plugins()
    return tuple((target, *found) for target, found in _loaded.items())


def replay_plugins(loaded: Iterable[tuple[str, str | None, str | None]]) -> None:
    """Import in this process (a Ray worker) the plugins another one imported (:func:`loaded_plugins`), in its order
    and instead of this process's own entry points, so that every name means what it means there.

    Raises
    ------
    ImportError
        Naming the plugin, when one cannot be imported here or its code is not the code the other process runs.
    """
    global _entry_points_loaded
    _entry_points_loaded = True
    for target, folder, code in loaded:
        if target not in _loaded:
            if folder is not None and folder not in sys.path:
                sys.path.append(folder)
            try:
                _import_plugin(target)
            except Exception as error:
                raise ImportError(
                    f"plugin {target!r} cannot be imported on a Ray worker ({type(error).__name__}: "
                    f"{' '.join(str(error).split())}); it must be importable at the same path on every node"
                    f"{f' ({folder})' if folder else ''}"
                ) from None
        if str(_loaded[target][1]).partition("#run-")[0] != str(code).partition("#run-")[0]:  # code of one run
            raise ImportError(
                f"plugin {target!r} on a Ray worker is not the code this run loaded (its source in {folder} changed "
                "since, or differs on that node); run again, with the same file on every node"
            )


class Travelling:
    """``payload`` wrapped so that, unpickled in another process (a Ray worker), it is ``payload`` itself, read
    only after the plugins this process loaded were imported there (:func:`replay_plugins`), so that the classes
    of the payload that a plugin defines are found too."""

    def __init__(self, payload: Any, loaded: tuple[tuple[str, str | None, str | None], ...] | None = None) -> None:
        self.payload, self.loaded = payload, loaded

    def __reduce__(self) -> tuple[Any, ...]:
        if self.loaded is not None:  # unpickled: the plugins imported
            return replay_plugins, (self.loaded,)
        # a pickle is read in order: the plugins are imported, then the payload is read and returned as it is
        return _arrived, (Travelling(None, loaded_plugins()), self.payload)


def _arrived(replayed: None, payload: _T) -> _T:
    return payload


def missing_extra_message(what: str, module: str | None, extra: str | None) -> str:
    """``"<what> needs a missing dependency (<module>); install it with: pip install 'vpr-uncertainty[<extra>]'"``."""
    hint = f"; install it with: pip install 'vpr-uncertainty[{extra}]'" if extra else ""
    return f"{what} needs a missing dependency ({module}){hint}"


def import_or_explain(module: str, message: str) -> Any:
    """Import and return ``module``, or raise an ImportError with ``message`` (what needs it, how to install it)."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise ImportError(message) from error


def lazy_exports(package: str, exports: Mapping[str, str], namespace: dict[str, Any]) -> tuple[Callable, Callable]:
    """A package's PEP 562 ``__getattr__`` and ``__dir__``: each name of ``exports`` (name -> module) is imported
    from its module on first use and kept in ``namespace`` (the package's ``globals()``), so the next access is a
    plain attribute; any other name is an AttributeError."""

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(exports[name]), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *exports})

    return __getattr__, __dir__


def load_target(target: Any, *, what: str, extra: str | None = None) -> Any:
    """``target`` itself, or the attribute a dotted path ``"package.module:attribute"`` names (imported now).

    Raises
    ------
    ImportError
        When the module (or a module it imports) is missing; the message names ``what`` and the pip ``extra``.
    """
    if not isinstance(target, str):
        return target
    module_name, colon, attribute = target.partition(":")
    if not colon or not module_name or not attribute:
        raise ValueError(f"{what}: a dotted target must read 'package.module:attribute', got {target!r}")
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise ImportError(missing_extra_message(what, error.name, extra), name=error.name) from error
    try:
        return getattr(module, attribute)
    except AttributeError:
        raise ImportError(f"{what}: module {module_name} has no attribute {attribute!r}") from None


def merge_options(defaults: Mapping[str, Any], given: Mapping[str, Any], *, what: str) -> dict[str, Any]:
    """``given`` merged over ``defaults``; a name not among the defaults is an error that lists the valid ones.

    Nested mappings are merged recursively (``{"matcher": {"ratio": 0.9}}`` keeps the matcher's other options).
    """
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        valid = ", ".join(sorted(defaults)) or "none"
        names = ", ".join(repr(name) for name in unknown)
        raise ValueError(f"{what} has no option {names} (valid options: {valid})")
    merged = dict(defaults)
    for key, value in given.items():
        if isinstance(merged[key], Mapping) and isinstance(value, Mapping):
            value = merge_options(merged[key], value, what=f"{what}, {key}")
        merged[key] = value
    return merged


def registered_code() -> dict[str, str]:
    """The code identity of every plugin of a user this process imported (entry points and ``--plugin``), by
    target, as it was executed (:func:`loaded_plugins`): part of the key of what the registries' entries compute,
    the same in a Ray worker, which imports the same plugins."""
    return {target: code for target, _, code in loaded_plugins() if code}


class Registry(Generic[_T]):
    """Named entries of one kind (``"uncertainty method"``, ``"dataset format"``, ...).

    Parameters
    ----------
    kind : str
        What an entry is, in words, for error messages.
    normalise : callable, optional
        Maps a name to its lookup key (default: the name itself, so lookups are exact). Registering two names
        with the same key is an error.
    label : str
        What the list of valid names is called in the error of an unknown name.
    """

    def __init__(self, kind: str, *, normalise: Callable[[str], str] | None = None, label: str = "valid") -> None:
        self.kind = kind
        self.label = label
        self._normalise = normalise or (lambda name: name)
        self._entries: dict[str, _T] = {}
        self._aliases: dict[str, str] = {}

    def register(self, entry: _T, *, aliases: tuple[str, ...] = (), overwrite: bool = False) -> _T:
        """Add ``entry`` under ``entry.name`` (and ``aliases``) and return it."""
        name = getattr(entry, "name", None)
        if not isinstance(name, str) or not name:
            raise ValueError(f"a {self.kind} needs a non-empty string name, got {name!r}")
        key = self._normalise(name)
        if not overwrite and (key in self._entries or key in self._aliases):
            raise ValueError(f"a {self.kind} named {name!r} is already registered; pass overwrite=True to replace it")
        self._entries[key] = entry
        for alias in aliases:
            self._aliases[self._normalise(alias)] = key
        return entry

    def unregister(self, name: str) -> _T:
        """Remove the entry called ``name`` (and its aliases) and return it."""
        key = self._key(name)
        self._aliases = {alias: target for alias, target in self._aliases.items() if target != key}
        return self._entries.pop(key)

    def _key(self, name: str) -> str:
        key = self._normalise(name)
        key = self._aliases.get(key, key)
        if key in self._entries:
            return key
        if not _entry_points_loaded:
            load_plugins()
            return self._key(name)
        close = [
            known
            for known in difflib.get_close_matches(key, [*self._entries, *self._aliases], n=1, cutoff=SUGGESTION_CUTOFF)
            if len(known) == len(key)
            or key.startswith(known)
            or known.startswith(key)
            or difflib.SequenceMatcher(None, key, known).ratio() > SUGGESTION_CUTOFF
        ]
        close = close or [known for known in self._entries if known.lower() == key.lower()]
        hint = ""
        if close:
            target = self._aliases.get(close[0], close[0])
            hint = f"did you mean {getattr(self._entries[target], 'name', target)!r}? "
        raise KeyError(f"unknown {self.kind} {name!r}; {hint}{self.label}: {', '.join(self.names())}")

    def get(self, name: str) -> _T:
        """The entry called ``name``; a ``KeyError`` suggests the closest name and lists the valid ones."""
        return self._entries[self._key(name)]

    def __contains__(self, name: object) -> bool:
        if not isinstance(name, str):
            return False
        key = self._normalise(name)
        return key in self._entries or key in self._aliases

    def __iter__(self) -> Iterator[_T]:
        return iter(list(self._entries.values()))

    def __len__(self) -> int:
        return len(self._entries)

    def entries(self, **attributes: Any) -> list[_T]:
        """Entries in registration order whose attributes equal ``attributes`` (all entries without any)."""
        return [
            entry
            for entry in self._entries.values()
            if all(getattr(entry, key, None) == value for key, value in attributes.items())
        ]

    def names(self, **attributes: Any) -> list[str]:
        """Names of :meth:`entries` (same filter)."""
        return [entry.name for entry in self.entries(**attributes)]  # type: ignore[attr-defined]
