"""What defines a descriptor model given as Python: its code, parameters, buffers and plain attributes, as a digest.

The descriptor cache reuses descriptors only when the model's identity is unchanged, so the identity of a callable
or ``torch.nn.Module`` must change whenever its output may: :func:`callable_identity` hashes (SHA-256)

* a ``torch.nn.Module``: its class (qualified name and source), every plain attribute (``GeM.p = 3.0``), every
  parameter and buffer (bytes, dtype, shape), and each submodule the same way;
* a function or lambda: its code (bytecode, constants, names, nested code), defaults, closure values, and the
  globals it names (tensors, modules, plain values, functions of the same module);
* ``functools.partial``, bound methods and other callable objects: what they wrap, their class and attributes.

A value it cannot describe (an open file, a socket, an object of unknown state) raises
:class:`UnfingerprintableModel`: pass ``weights_id=`` (a key that names the model) instead. Python modules and
classes referenced by name are identified by name only: code in other files is not hashed.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import sys
import types
from typing import Any

_PLAIN = (bool, int, float, complex, str, bytes, type(None))
#: Attributes of a torch Module that are torch's own bookkeeping, not the model's state.
_MODULE_INTERNALS = frozenset(
    {"_parameters", "_buffers", "_modules", "_non_persistent_buffers_set", "training", "_is_full_backward_hook"}
)


class UnfingerprintableModel(ValueError):
    """The model holds a value whose content cannot be hashed: the cache could not tell when it changed."""


def callable_identity(network: Any) -> str:
    """A digest of everything that defines ``network``'s output (see the module docstring).

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
            return
        if isinstance(value, (tuple, list, frozenset, set)):
            items = sorted(value, key=repr) if isinstance(value, (set, frozenset)) else value
            self.tag(type(value).__name__, len(items))
            for index, item in enumerate(items):
                self.feed(item, f"{where}[{index}]")
            return
        if isinstance(value, dict):
            self.tag("dict", len(value))
            for key in sorted(value, key=repr):
                self.feed(key, f"{where} key")
                self.feed(value[key], f"{where}[{key!r}]")
            return
        if id(value) in self.seen:  # a cycle or a shared object: described once
            self.tag("seen", type(value).__qualname__)
            return
        self.seen.add(id(value))
        torch = self.torch
        if torch is not None and isinstance(value, torch.Tensor):
            tensor = value.detach().to("cpu").contiguous()
            self.tag("tensor", str(tensor.dtype), tuple(tensor.shape))
            self.digest.update(tensor.view(-1).view(torch.uint8).numpy().tobytes() if tensor.numel() else b"")
            return
        if type(value).__module__ == "numpy" and hasattr(value, "tobytes"):
            self.tag("ndarray", str(getattr(value, "dtype", "")), getattr(value, "shape", ()))
            self.digest.update(value.tobytes())
            return
        if torch is not None and isinstance(value, (torch.dtype, torch.device)):
            self.tag(type(value).__name__, str(value))
            return
        if torch is not None and isinstance(value, torch.nn.Module):
            self.module(value, where)
            return
        if isinstance(value, types.ModuleType):
            self.tag("module", value.__name__)
            return
        if isinstance(value, type):
            self.tag("class", value.__module__, value.__qualname__)
            return
        if isinstance(value, types.BuiltinFunctionType):
            self.tag("builtin", getattr(value, "__module__", None), value.__qualname__)
            return
        if isinstance(value, types.FunctionType):
            self.function(value, where)
            return
        if isinstance(value, types.MethodType):
            self.tag("method")
            self.feed(value.__func__, f"{where}.__func__")
            self.feed(value.__self__, f"{where}.__self__")
            return
        if isinstance(value, functools.partial):
            self.tag("partial")
            self.feed(value.func, f"{where}.func")
            self.feed(value.args, f"{where}.args")
            self.feed(value.keywords, f"{where}.keywords")
            return
        if hasattr(value, "__dict__") and type(value).__module__ not in {"builtins", "io", "socket", "_io"}:
            cls = type(value)
            self.tag("object", cls.__module__, cls.__qualname__, _class_source(cls))
            for name, attribute in sorted(vars(value).items()):
                self.tag("attribute", name)
                self.feed(attribute, f"{where}.{name}")
            return
        raise UnfingerprintableModel(
            f"cannot fingerprint {where} ({type(value).__module__}.{type(value).__qualname__}): the descriptor cache "
            "could not tell when it changes; name the model with weights_id=... (a key you change with it)"
        )

    def module(self, module: Any, where: str) -> None:
        cls = type(module)
        self.tag("nn.Module", cls.__module__, cls.__qualname__, _class_source(cls))
        for name, attribute in sorted(vars(module).items()):
            if name in _MODULE_INTERNALS or (name.startswith("_") and name.endswith("hooks")):
                continue
            if name.startswith("_") and isinstance(attribute, dict) and not attribute:
                continue  # empty hook and state dictionaries of torch
            self.tag("attribute", name)
            self.feed(attribute, f"{where}.{name}")
        for kind in ("_parameters", "_buffers"):
            for name, tensor in sorted(vars(module).get(kind, {}).items()):
                self.tag(kind, name)
                self.feed(tensor, f"{where}.{name}")
        for name, child in sorted(vars(module).get("_modules", {}).items()):
            self.tag("submodule", name)
            self.feed(child, f"{where}.{name}")

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
