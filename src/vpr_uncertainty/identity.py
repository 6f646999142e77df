"""What determines a result's code, for the fingerprints of the caches (:func:`vpr_uncertainty.cache.fingerprint`):
:func:`code_identity` of a module and its own tree, :func:`target_identity` of a registry target, and
:func:`callable_identity` of a descriptor model given as Python (what it hashes: see docs/explanation/caches.md).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib.machinery
import inspect
import os
import re
import sys
import sysconfig
import types
import warnings
from pathlib import Path
from typing import Any

from vpr_uncertainty import __version__

_PLAIN = (bool, int, float, complex, str, bytes, type(None))
#: Attributes of a torch Module that are torch's own bookkeeping, not the model's state.
_MODULE_INTERNALS = frozenset(
    {"_parameters", "_buffers", "_modules", "_non_persistent_buffers_set", "training", "_is_full_backward_hook"}
)


_OPAQUE = frozenset({"builtins", "io", "socket", "_io"})
_SLOT_TYPES = (types.MemberDescriptorType, types.GetSetDescriptorType, staticmethod, classmethod, property)


def _slots(value: Any) -> dict[str, Any]:
    """The ``__slots__`` values set on ``value`` (of its class and bases)."""
    names = {name for cls in type(value).__mro__ for name in getattr(cls, "__dict__", {}).get("__slots__", ())}
    return {name: getattr(value, name) for name in sorted(names - {"__dict__", "__weakref__"}) if hasattr(value, name)}


class UnfingerprintableModel(ValueError):
    """The model holds a value whose content cannot be hashed: the cache could not tell when it changed."""


def callable_identity(network: Any) -> str:
    """A digest of everything that defines ``network``'s output (see docs/explanation/caches.md).

    Parameters
    ----------
    network : callable
        A function, ``torch.nn.Module``, ``functools.partial`` or callable object.

    Returns
    -------
    str
        ``"python-sha256:<64 hex digits>"``.

    Raises
    ------
    UnfingerprintableModel
        When part of the model cannot be described; the message names where.

    Examples
    --------
    >>> callable_identity(lambda x: x * 2) == callable_identity(lambda x: x * 2)
    True
    >>> callable_identity(lambda x: x * 2) == callable_identity(lambda x: x * 3)
    False
    """
    digest = hashlib.sha256()
    _Feeder(digest).feed(network, "model")
    return f"python-sha256:{digest.hexdigest()}"


@functools.lru_cache(maxsize=1024)
def _class_source(cls: type) -> str:
    try:
        return inspect.getsource(cls)
    except (OSError, TypeError):  # built-in or generated class: its name is all there is
        return ""


class _Feeder:
    def __init__(self, digest: Any) -> None:
        self.digest = digest
        self.seen: set[int] = set()
        self.torch = sys.modules.get("torch")

    def tag(self, *parts: object) -> None:
        self.digest.update(repr(parts).encode())

    def feed(self, value: Any, where: str) -> None:
        if isinstance(value, _PLAIN):
            self.tag(type(value).__name__, value)
        elif isinstance(value, (tuple, list, frozenset, set)):
            items = sorted(value, key=repr) if isinstance(value, (set, frozenset)) else value
            self.tag(type(value).__name__, len(items))
            for index, item in enumerate(items):
                self.feed(item, f"{where}[{index}]")
        elif isinstance(value, dict):
            self.tag("dict", len(value))
            for key in sorted(value, key=repr):
                self.feed(key, f"{where} key")
                self.feed(value[key], f"{where}[{key!r}]")
        elif id(value) in self.seen:  # a cycle or a shared object: described once
            self.tag("seen", type(value).__qualname__)
        else:
            self.seen.add(id(value))
            self.feed_object(value, where)

    def feed_object(self, value: Any, where: str) -> None:
        torch = self.torch
        if torch is not None and isinstance(value, torch.Tensor):
            tensor = value.detach().to("cpu").contiguous()
            self.tag("tensor", str(tensor.dtype), tuple(tensor.shape))
            self.digest.update(tensor.view(-1).view(torch.uint8).numpy().tobytes() if tensor.numel() else b"")
        elif type(value).__module__ == "numpy" and hasattr(value, "tobytes"):
            self.tag("ndarray", str(getattr(value, "dtype", "")), getattr(value, "shape", ()))
            self.digest.update(value.tobytes())
        elif torch is not None and isinstance(value, (torch.dtype, torch.device)):
            self.tag(type(value).__name__, str(value))
        elif torch is not None and isinstance(value, torch.nn.Module):
            self.module(value, where)
        elif isinstance(value, types.ModuleType):
            self.tag("module", value.__name__)
        elif isinstance(value, type):
            self.tag("class", value.__module__, value.__qualname__)
        elif isinstance(value, types.BuiltinFunctionType):
            self.tag("builtin", getattr(value, "__module__", None), value.__qualname__)
        elif isinstance(value, types.FunctionType):
            self.function(value, where)
        elif isinstance(value, types.MethodType):
            self.tag("method")
            self.feed(value.__func__, f"{where}.__func__")
            self.feed(value.__self__, f"{where}.__self__")
        elif isinstance(value, functools.partial):
            self.tag("partial")
            self.feed(value.func, f"{where}.func")
            self.feed(value.args, f"{where}.args")
            self.feed(value.keywords, f"{where}.keywords")
        elif (hasattr(value, "__dict__") or _slots(value)) and type(value).__module__ not in _OPAQUE:
            self.cls(type(value), where)
            for name, attribute in sorted({**getattr(value, "__dict__", {}), **_slots(value)}.items()):
                self.tag("attribute", name)
                self.feed(attribute, f"{where}.{name}")
        else:
            raise UnfingerprintableModel(
                f"cannot fingerprint {where} ({type(value).__module__}.{type(value).__qualname__}): the descriptor "
                "cache could not tell when it changes; name the model with weights_id=... (a key you change with it)"
            )

    def cls(self, cls: type, where: str) -> None:
        """A class by name and source, and what is set on it and its user-defined bases (``Net.scale = 2.0``)."""
        self.tag("class of", cls.__module__, cls.__qualname__, _class_source(cls))
        for base in cls.__mro__:
            if base.__module__.split(".")[0] in _OPAQUE | {"torch"}:
                continue
            for name, attribute in sorted(vars(base).items()):
                if not (name.startswith("__") and name.endswith("__")) and not isinstance(attribute, _SLOT_TYPES):
                    self.tag("class attribute", base.__qualname__, name)
                    self.feed(attribute, f"{where} class attribute {name}")

    def module(self, module: Any, where: str) -> None:
        self.cls(type(module), where)
        for name, attribute in sorted({**vars(module), **_slots(module)}.items()):
            if name in _MODULE_INTERNALS:
                continue
            if name.startswith("_") and isinstance(attribute, dict):
                if not attribute:
                    continue  # empty hook and state dictionaries of torch
                attribute = list(attribute.values())  # hooks: keyed by a registration counter
            self.tag("attribute", name)
            self.feed(attribute, f"{where}.{name}")
        for kind, label in (("_parameters", "_parameters"), ("_buffers", "_buffers"), ("_modules", "submodule")):
            for name, part in sorted(vars(module).get(kind, {}).items()):  # tensors, then submodules
                self.tag(label, name)
                self.feed(part, f"{where}.{name}")

    def function(self, function: types.FunctionType, where: str) -> None:
        self.tag("function", function.__module__, function.__qualname__)
        self.code(function.__code__)
        self.feed(function.__defaults__, f"{where} defaults")
        self.feed(function.__kwdefaults__, f"{where} keyword defaults")
        for index, cell in enumerate(function.__closure__ or ()):
            try:
                content = cell.cell_contents
            except ValueError:  # an empty cell
                content = None
            self.feed(content, f"{where} closure[{index}]")
        for name in _global_names(function.__code__):
            if name in function.__globals__:
                value = function.__globals__[name]
                if isinstance(value, types.FunctionType) and value.__module__ != function.__module__:
                    self.tag("global function", name, value.__module__, value.__qualname__)
                    continue
                self.tag("global", name)
                self.feed(value, f"{where} global {name}")

    def code(self, code: types.CodeType) -> None:
        self.tag("code", code.co_names, code.co_varnames, code.co_argcount)
        self.digest.update(code.co_code)
        for constant in code.co_consts:
            if isinstance(constant, types.CodeType):
                self.code(constant)
            else:
                self.feed(constant, "a constant")


def _global_names(code: types.CodeType) -> list[str]:
    names = list(code.co_names)
    for constant in code.co_consts:
        if isinstance(constant, types.CodeType):
            names += _global_names(constant)
    return sorted(set(names))


_FROM_IMPORT = re.compile(rb"^[ \t]*from[ \t]+(\.*[\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*)", re.M)
_IMPORT = re.compile(rb"^[ \t]*import[ \t]+([^\n#]+)", re.M)


@functools.lru_cache(maxsize=4096)
def _source(path: str, stamp: tuple[int, int]) -> tuple[str, tuple[tuple[str, int], ...]]:
    """The BLAKE2b of a source file and the modules its import statements (at any level) may name, as
    ``(name, dots)`` (re-read when its size or mtime change)."""
    data = Path(path).read_bytes()
    imports = [(name.decode().strip().split(" ")[0], 0) for line in _IMPORT.findall(data) for name in line.split(b",")]
    for base, names in _FROM_IMPORT.findall(data):
        module, dots = base.decode().lstrip("."), len(base) - len(base.lstrip(b"."))
        words = re.findall(r"[\w.]+", names.decode().split("#")[0].replace(" as ", " "))
        imports += [(module, dots)] + [(f"{module}.{word}".lstrip("."), dots) for word in words]
    return hashlib.blake2b(data, digest_size=16).hexdigest(), tuple(imports)


#: Calls that import a module by name: followed where the name is one absolute string literal.
_IMPORTERS = frozenset({"import_module", "__import__"})
#: What runs code the identity cannot follow, wherever it is named: an importer called otherwise, a file by its path.
_UNFOLLOWED = _IMPORTERS | {"spec_from_file_location", "SourceFileLoader", "run_path", "run_module"}
#: Part of the identity of code that runs what cannot be followed: never the same in another process (run).
_RUN = os.urandom(8).hex()


def _word(node: Any) -> Any:
    """What ``node`` names: ``f``, ``m.f``, ``"f"`` (``getattr(m, "f")``), ``from m import f as g``."""
    if isinstance(node, ast.alias):
        return node.name if node.asname else None
    return getattr(node, "id", None) or getattr(node, "attr", None) or getattr(node, "value", None)


@functools.lru_cache(maxsize=1024)
def _dynamic(path: str, stamp: tuple[int, int]) -> tuple[tuple[tuple[str, int], ...], int | None]:
    """The modules a user's source file imports at run time by a literal name (``importlib.import_module("helper")``,
    ``__import__("helper")``), as :func:`_source` gives them, and the line of the first code it runs that cannot be
    followed (None when none): an importer called otherwise or under an alias, ``exec``, ``eval``, a file by path."""
    try:
        tree = ast.parse(Path(path).read_bytes(), path)
    except (SyntaxError, ValueError, RecursionError):  # not importable either: its bytes are hashed
        return (), None
    imports: list[tuple[str, int]] = []
    followed: set[int] = set()
    for node in ast.walk(tree):  # breadth first: a call before its function
        call = node if isinstance(node, ast.Call) and len(node.args) == 1 and not node.keywords else None
        name = getattr(call.args[0], "value", None) if call else None
        if call and _word(call.func) in _IMPORTERS and isinstance(name, str) and not name.startswith("."):
            imports.append((name, 0))
            followed.add(id(call.func))
        elif id(node) not in followed and (_word(node) in _UNFOLLOWED or getattr(node, "id", None) in ("exec", "eval")):
            return tuple(imports), getattr(node, "lineno", 1)
    return tuple(imports), None


def _module_spec(name: str) -> Any:
    """The spec of module ``name`` (its loaded module's), found on the path without importing it or its parents."""
    module = sys.modules.get(name)
    if module is not None:
        return getattr(module, "__spec__", None) or module
    parent = name.rpartition(".")[0]
    search = getattr(_module_spec(parent), "submodule_search_locations", None) if parent else None
    try:
        return None if parent and not search else importlib.machinery.PathFinder.find_spec(name, search)
    except (ImportError, ValueError):
        return None


def _module_file(name: str) -> str | None:
    """The Python source file of module ``name`` (None for a built-in, compiled or missing module)."""
    origin = getattr(_module_spec(name), "origin", None) or getattr(sys.modules.get(name), "__file__", None)
    return origin if isinstance(origin, str) and origin.endswith(".py") and os.path.isfile(origin) else None


def is_installed(module: str) -> bool:
    """Whether module ``module`` comes from the standard library or site-packages, or has no Python source file."""
    found = _module_file(module)
    paths = sysconfig.get_paths()
    roots = tuple({os.path.realpath(paths[key]) + os.sep for key in ("stdlib", "platstdlib", "purelib", "platlib")})
    return found is None or os.path.realpath(found).startswith(roots)


def code_identity(module: str) -> str:
    """A digest of the code module ``module`` runs, for the fingerprints of what it computes.

    Hashed: the bytes of the module's source file and of every module its import statements name (at any level,
    transitively) in the same tree: its own top-level package, and for a module outside the toolkit (a user's
    ``--plugin``) every module that is not installed (neither the standard library nor site-packages), i.e. the
    user's own files; with the toolkit's version. A module without a Python source file counts by its name. In the
    user's files, ``import_module("name")`` and ``__import__("name")`` count as import statements; code that imports
    or runs what they cannot follow (:func:`_dynamic`) gets an identity of this process only, with a one-line
    :class:`~vpr_uncertainty.cache.CacheWarning`: what it computed in another run is not reused.

    Examples
    --------
    >>> code_identity("vpr_uncertainty.scores") == code_identity("vpr_uncertainty.scores")
    True
    >>> code_identity("vpr_uncertainty.scores") == code_identity("vpr_uncertainty.spatial")
    False
    """
    known = _CLOSURES.get(module)  # the files read last time, unchanged: the same identity, without the walk
    if known is not None and all(_stamp(path) == stamp for path, stamp in known[0]):
        return known[1]
    top = module.split(".")[0]
    hasher = hashlib.blake2b(f"vpr-uncertainty {__version__};".encode(), digest_size=16)
    seen: set[str] = set()
    pending, files, unfollowed = [module], [], ""
    while pending:
        name = pending.pop()
        path = _module_file(name)
        hasher.update(f"{name}:".encode())
        if path is None:
            continue
        files.append((path, _stamp(path)))
        digest, imports = _source(path, files[-1][1])
        hasher.update(digest.encode())
        if top != "vpr_uncertainty" and not is_installed(name):  # a user's file: its imports at run time too
            dynamic, line = _dynamic(path, files[-1][1])
            imports, unfollowed = imports + dynamic, unfollowed or (f"{path}, line {line}" if line else "")
        package = (name if path.endswith("__init__.py") else name.rpartition(".")[0]).split(".")
        for target, dots in imports:
            if dots:
                target = ".".join([*package[: len(package) - dots + 1], target]).strip(".")
            if target in seen or not target:
                continue
            seen.add(target)
            own = target.split(".")[0] == top
            if not own and "vpr_uncertainty" in (top, target.split(".")[0]):
                continue  # the toolkit's own tree only, and a user's tree without the toolkit (its version counts)
            if own or not is_installed(target):
                pending.append(target)
    if unfollowed:
        from vpr_uncertainty.cache import CacheWarning

        message = f"{unfollowed}: imports or runs code by a name the cache cannot follow, so what {module} computes is "
        warnings.warn(message + "recomputed on every run (import it by a literal name to cache it)", CacheWarning, 2)
    _CLOSURES[module] = (files, "code:" + hasher.hexdigest() + (f"#run-{_RUN}" if unfollowed else ""))
    return _CLOSURES[module][1]


_CLOSURES: dict[str, tuple[list[tuple[str, tuple[int, int]]], str]] = {}


def _stamp(path: str) -> tuple[int, int]:
    try:
        stat = os.stat(path)
    except OSError:  # deleted since: not the same
        return -1, -1
    return stat.st_size, stat.st_mtime_ns


def target_identity(target: Any) -> str:
    """:func:`code_identity` of the module of a callable or of a dotted target ``"module:attribute"``.

    A function without a source file behind its module (defined in a notebook or ``python -c``) is identified by its
    compiled code, constants and defaults; any other object by its type's module and a digest of its ``repr``.
    """
    if isinstance(target, str):
        return code_identity(target.partition(":")[0])
    function = getattr(target, "func", target)  # a functools.partial: what it calls
    module = getattr(function, "__module__", None) or type(function).__module__
    if _module_file(module) is not None:
        return code_identity(module)
    code = getattr(function, "__code__", None)
    text = repr((code.co_code, code.co_consts, function.__defaults__)) if code is not None else repr(target)
    return "code:" + hashlib.blake2b(text.encode(), digest_size=16).hexdigest()
