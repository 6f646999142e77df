"""Where independent work items run: in this process (``local``), as Ray tasks (``ray``), or an executor a plugin
registers in :data:`EXECUTORS`; :meth:`~BaseExecutor.imap` yields ``(position, result)`` pairs as items complete,
:meth:`~BaseExecutor.map` returns results in order. See docs/explanation/architecture.md.

Examples
--------
>>> with get_executor("local") as executor:
...     executor.map(abs, [-2, 1])
[2, 1]
>>> executor_names()
['local', 'ray']
"""

from __future__ import annotations

import contextlib
import inspect
import logging
import math
import os
import re
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vpr_uncertainty.plugins import Registry, Travelling, import_or_explain, load_plugins, load_target, merge_options

#: How many times Ray reruns a task whose worker died.
MAX_RETRIES = 3
#: Seconds to wait for a Ray cluster at an explicit address to answer (``--connect-timeout``).
CONNECT_TIMEOUT = 30.0
#: Seconds a Ray start-up (``ray.init``) may take before it is abandoned and what it started is shut down.
START_TIMEOUT = 180.0
#: ``host:port`` as Ray's core reads it: a host name, an IPv4 address or an IPv6 one in brackets, and a port number
_HOST_PORT = re.compile(r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):([1-9][0-9]{0,4})")
#: A GCS's reply to ``GetClusterId`` (one uncompressed gRPC message: an empty status, a 28-byte cluster id)
_CLUSTER_ID_REPLY = re.compile(rb"\0\0\0\0(\x1e|\x20\n\0)\x12\x1c.{28}", re.S)


def import_ray() -> Any:
    """The ``ray`` module, or an ImportError naming the extra that provides it."""
    return import_or_explain(
        "ray", "the ray executor needs Ray: pip install 'vpr-uncertainty[ray]' (or pip install 'ray[data]')"
    )


def _apply(function: Callable[[Any], Any], item: Any) -> Any:
    return function(item)


def _check_workers(workers: int | None) -> int | None:
    if workers is None:
        return None
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    return workers


class BaseExecutor:
    """What every executor offers; a subclass sets :attr:`name` and implements :meth:`imap` (and :meth:`close`
    when it holds resources)."""

    name = ""
    workers: int | None = None

    def imap(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        """Yield ``(position, function(item))`` for every item, in completion order."""
        raise NotImplementedError

    def map(
        self, function: Callable[[Any], Any], items: Iterable[Any], *, on_result: Callable[[Any], None] | None = None
    ) -> list[Any]:
        """``[function(item) for item in items]``, in the order of ``items``.

        ``on_result`` is called with each result as it completes (e.g. to advance a progress bar). An exception
        raised by ``function`` is raised here, as its original type.
        """
        items = list(items)
        results: list[Any] = [None] * len(items)
        for position, result in self.imap(function, items):
            results[position] = result
            if on_result is not None:
                on_result(result)
        return results

    def close(self) -> None:
        """Release what the executor started (nothing by default)."""

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LocalExecutor(BaseExecutor):
    """Run every item in this process, one after the other (the default). ``workers`` is checked and ignored."""

    name = "local"

    def __init__(self, workers: int | None = None) -> None:
        self.workers = _check_workers(workers)

    def imap(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        for position, item in enumerate(items):
            yield position, function(item)


class RayExecutor(BaseExecutor):
    """Run every item as a Ray task, at most ``workers`` at once, each with ``gpus_per_worker`` GPUs.

    Connects to the cluster at ``address`` (``"auto"``: the one ``ray start`` started on this machine), or, without
    one, starts a local cluster with ``workers`` CPUs. When Ray is already initialised in this process, that cluster
    is used and left running by :meth:`close`.

    Parameters
    ----------
    address : str, optional
        The cluster's address (``host:port``, ``ray://host:10001`` or ``"auto"``).
    workers : int, optional
        The most tasks in flight at once; default: the cluster's CPUs.
    gpus_per_worker : float, default=0
        GPUs Ray assigns to each task (fractions share one GPU).
    connect_timeout : float, default=30
        Seconds to wait for the cluster at ``host:port`` to answer before a ConnectionError (see
        :func:`wait_for_address`; Ray itself waits for minutes, or for ever, where nothing or something else listens).
    start_timeout : float, default=180
        Seconds ``ray.init`` may take (see :func:`start_ray`).
    log_file : str or Path, optional
        Where Ray's own log lines in this process (its start-up notices and warnings, Ray Data's progress
        messages) go while the executor is open (see :func:`redirect_ray_logs`), and whatever Ray's C++ core writes
        to the standard error during ``ray.init``; by default Ray's own handling (the terminal). The command line
        passes a file unless ``--verbose``.
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        workers: int | None = None,
        gpus_per_worker: float = 0.0,
        connect_timeout: float = CONNECT_TIMEOUT,
        start_timeout: float = START_TIMEOUT,
        log_file: str | Path | None = None,
    ) -> None:
        self.workers = _check_workers(workers)
        if isinstance(gpus_per_worker, bool) or not isinstance(gpus_per_worker, (int, float)) or gpus_per_worker < 0:
            raise ValueError(f"gpus_per_worker must be a number >= 0, got {gpus_per_worker!r}")
        self.gpus_per_worker = float(gpus_per_worker)
        if address is not None and (not isinstance(address, str) or not address.strip()):
            raise ValueError(f"address must be a non-empty string such as 'auto' or 'host:6379', got {address!r}")
        for option, value in (("connect_timeout", connect_timeout), ("start_timeout", start_timeout)):
            if not (isinstance(value, (int, float)) and 0 < value < math.inf):
                raise ValueError(f"{option} must be a positive number of seconds, got {value!r}")
        if address is not None:
            wait_for_address(address, connect_timeout)
        self.ray = import_ray()
        self._owns_cluster = False
        self._restore_logs = redirect_ray_logs(log_file) if log_file is not None else None
        try:
            self._connect(address, start_timeout, log_file)
        except BaseException:
            self._put_logs_back()
            raise

    def _connect(self, address: str | None, start_timeout: float, log_file: str | Path | None) -> None:
        if not self.ray.is_initialized():
            # "local": a new cluster, never one that a `ray start` on this machine left behind
            options: dict[str, Any] = dict(address=address or "local", include_dashboard=False, log_to_driver=False)
            if address is None and self.workers is not None:
                options["num_cpus"] = self.workers
            with _stderr_to(log_file):
                start_ray(self.ray, options, start_timeout)
            self._owns_cluster = True
        if self.workers is None:
            self.workers = max(1, int(self.ray.cluster_resources().get("CPU", 1)))

    def imap(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        """Yield ``(position, function(item))`` as tasks complete, at most ``workers`` in flight (a consumer that
        writes each result as it comes keeps what finished when the run stops); a task whose worker process dies
        is rerun up to :data:`MAX_RETRIES` times."""
        ray = self.ray
        remote = ray.remote(_apply).options(
            num_cpus=1, num_gpus=self.gpus_per_worker, max_retries=MAX_RETRIES, retry_exceptions=False
        )
        # serialised once (a partial may hold a model), read in each worker after the plugins this process loaded
        function = ray.put(Travelling(function))
        pending: dict[Any, int] = {}
        queue = iter(enumerate(items))
        try:
            for position, item in queue:
                pending[remote.remote(function, item)] = position
                if len(pending) >= self.workers:
                    break
            while pending:
                (done,), _ = ray.wait(list(pending), num_returns=1)
                position = pending.pop(done)
                try:
                    result = ray.get(done)
                except ray.exceptions.RayTaskError as error:
                    # an argument the worker could not read (a plugin it cannot import): Ray's RaySystemError holds it
                    unread = getattr(error.cause, "client_exc", None)
                    raise unread if isinstance(unread, Exception) else error.as_instanceof_cause() from None
                for next_position, item in queue:
                    pending[remote.remote(function, item)] = next_position
                    break
                yield position, result
        finally:
            for reference in pending:  # the consumer stopped early (an error, Ctrl-C): no orphan tasks
                ray.cancel(reference, force=True)

    def close(self) -> None:
        """Shut down the local cluster this executor started (a cluster it connected to keeps running)."""
        try:
            if self._owns_cluster and self.ray.is_initialized():
                self.ray.shutdown()
            self._owns_cluster = False
        finally:
            self._put_logs_back()

    def _put_logs_back(self) -> None:
        if self._restore_logs is not None:
            self._restore_logs()
            self._restore_logs = None


def redirect_ray_logs(path: str | Path) -> Callable[[], None]:
    """Send the log records of Ray's ``ray`` logger (and its children) to the file ``path`` (appended, parent
    folders created) instead of the terminal; returns the function that puts Ray's handlers back.

    Ray's workers do not log to this process (``log_to_driver=False``); their own logs stay in Ray's session folder
    (``/tmp/ray/session_latest/logs``).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    logger = logging.getLogger("ray")
    previous = (list(logger.handlers), logger.propagate)
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logger.handlers = [handler]
    logger.propagate = False

    def put_back() -> None:
        handler.close()
        logger.handlers, logger.propagate = previous

    return put_back


def start_ray(ray: Any, options: dict[str, Any], timeout: float) -> None:
    """``ray.init(**options)`` bounded by ``timeout`` seconds, leaving nothing behind when it fails.

    A local cluster whose start-up stalls (a worker killed while it starts hung ``ray.init`` for 13 minutes) raises
    TimeoutError after ``timeout``; that, Ctrl-C or any other error during start-up shuts down whatever Ray had
    started before it propagates. The bound uses SIGALRM, so it applies in the main thread of a POSIX process
    (elsewhere ``ray.init`` runs unbounded). A Python SIGTERM handler of the caller (the command line's, which
    unwinds so that the cluster is shut down) is put back after Ray replaced it with its own.
    """
    bounded = hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()

    what = "a new local cluster" if options.get("address") == "local" else f"the cluster at {options.get('address')}"

    def expire(signum: int, frame: Any) -> None:
        raise TimeoutError(f"Ray did not start within {timeout:g} s ({what}); whatever it had started was shut down")

    previous = signal.signal(signal.SIGALRM, expire) if bounded else None
    terminate = signal.getsignal(signal.SIGTERM) if bounded else None
    try:
        if bounded:
            signal.setitimer(signal.ITIMER_REAL, timeout)
        ray.init(**options)
        if callable(terminate):  # Ray's core worker installs its own SIGTERM handler: keep the caller's
            signal.signal(signal.SIGTERM, terminate)
    except BaseException:
        if bounded:
            signal.setitimer(signal.ITIMER_REAL, 0)
        if ray.is_initialized() or options.get("address") == "local":
            with contextlib.suppress(Exception):  # the start-up error is the one to report
                ray.shutdown()
        raise
    finally:
        if bounded:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def _stderr_to(path: str | Path | None) -> Iterator[None]:
    """The standard error of this process (file descriptor 2, where Ray's C++ core writes) appended to ``path``."""
    saved = os.dup(2)
    try:
        if path is not None:
            with open(path, "ab") as file:
                os.dup2(file.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _frame(kind: int, flags: int, stream: int, payload: bytes = b"") -> bytes:
    """One HTTP/2 frame (RFC 9113, section 4.1)."""
    return len(payload).to_bytes(3, "big") + bytes([kind, flags]) + stream.to_bytes(4, "big") + payload


def _ray_answer(connection: socket.socket, authority: bytes, deadline: float, client: bool) -> str | None:
    """None when the peer speaks Ray's protocol (gRPC: HTTP/2; a GCS also answers ``GetClusterId`` with a cluster
    id, or refuses it as UNAUTHENTICATED), else what answered, in words; TimeoutError when nothing came by
    ``deadline``."""
    headers = [(b":path", b"/ray.rpc.NodeInfoGcsService/GetClusterId"), (b":authority", authority)]
    headers += [(b"content-type", b"application/grpc"), (b"te", b"trailers")]
    # HPACK: :method POST and :scheme http from the static table, the rest as literals (names and values < 127 B)
    block = b"\x83\x86" + b"".join(b"\0" + bytes([len(n)]) + n + bytes([len(v)]) + v for n, v in headers)
    call = b"" if client else _frame(1, 4, 1, block) + _frame(0, 1, 1, bytes(5))  # an empty request message
    connection.sendall(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + _frame(4, 0, 0) + call)
    received, at = b"", 0
    while True:
        if time.monotonic() >= deadline or len(received) > 1 << 20:  # a GCS says what it has to say in a few bytes
            raise TimeoutError
        connection.settimeout(deadline - time.monotonic())
        chunk = connection.recv(65536)
        received += chunk
        if (len(received) >= 9 or not chunk) and received[3:4] != b"\x04":  # HTTP/2 servers start with SETTINGS
            if received.startswith(b"HTTP/") or received.lstrip().startswith(b"<"):  # an HTTP/1 error (page)
                return "an HTTP server answers there"
            return "something answers there in another protocol" if received else "something there hangs up"
        if not chunk:
            return "something there hangs up"
        while len(received) >= at + 9 + (length := int.from_bytes(received[at : at + 3], "big")):
            kind, flags, stream = received[at + 3], received[at + 4], int.from_bytes(received[at + 5 : at + 9], "big")
            payload, at = received[at + 9 : at + 9 + length], at + 9 + length
            ended = stream == 1 and kind in (0, 1) and flags & 1  # the call ended: its status says why
            # 16, UNAUTHENTICATED, as a GCS that wants the token ray.init sends writes it (none, or another: not Ray)
            token = ended and kind == 1 and b"\x0bgrpc-status\x0216" in payload
            if kind == 4 and not flags & 1:  # the server's SETTINGS: acknowledged (a client server is done)
                if client:
                    return None
                connection.sendall(_frame(4, 1, 0))
            elif (stream == 1 and kind == 0 and _CLUSTER_ID_REPLY.fullmatch(payload)) or token:
                return None
            elif ended or kind == 7 or (stream == 1 and kind == 3):  # another answer, GOAWAY, RST_STREAM
                grpc = b"grpc-status" in received
                return "a gRPC server there refuses Ray's calls" if grpc else "an HTTP/2 server answers there"


def wait_for_address(address: str, timeout: float) -> None:
    """Wait until a Ray cluster answers at ``address`` (``host:port``: its GCS; ``ray://host:port``: its client
    server), at most ``timeout`` seconds.

    ``ray.init`` waits for minutes (on a port where nothing listens) or for ever (on one where something else
    does: Ray's dashboard, any HTTP server, a silent listener, or a port Ray cannot read), in C++ that no signal
    interrupts. So the port is asked first, in Ray's protocol: it must speak HTTP/2, and a GCS must answer a
    ``GetClusterId`` call with a cluster id (or refuse it as UNAUTHENTICATED: the probe has no token). ``"auto"``
    is the address in ``RAY_ADDRESS`` where that is set (as ``ray.init`` reads it); ``"auto"`` otherwise and
    ``"local"`` name no port and pass unchecked; a connection refused is tried again until ``timeout``. Raises
    ValueError for an address that is not ``host:port`` (a port of digits, 1-65535, no spaces) or
    ``scheme://host:port``, ConnectionError naming the address, what answers there and the fix.
    """
    named = "Ray address"
    if address == "auto" and os.environ.get("RAY_ADDRESS"):
        named, address = "RAY_ADDRESS (what 'auto' reads)", os.environ["RAY_ADDRESS"]
    if address in ("auto", "local"):
        return
    client = address.startswith("ray://")
    form = _HOST_PORT.fullmatch(target := address.split("://", 1)[-1])
    fix = "give the address `ray start --head` prints (GCS port 6379 by default; 8265 is the dashboard)"
    if form is None or int(form[2]) > 65535:
        raise ValueError(
            f"{named} {address!r} is not host:port (a port of digits, 1-65535, no spaces), ray://host:port, "
            f"'auto' or 'local'; {fix}"
        )
    deadline = time.monotonic() + timeout
    while True:
        try:
            connection = socket.create_connection((form[1].strip("[]"), int(form[2])), timeout=min(2.0, timeout))
        except OSError as error:
            if time.monotonic() >= deadline:
                raise ConnectionError(
                    f"no Ray cluster answers at {address} within {timeout:g} s ({error.strerror or error}); start "
                    "one there (`ray start --head`), or raise --connect-timeout"
                ) from None
            time.sleep(min(0.5, max(deadline - time.monotonic(), 0.0)))
            continue
        try:
            with connection:
                answer = _ray_answer(connection, target.encode(), deadline, client)
        except OSError as error:
            answer = "something accepts connections there but does not answer" + (
                f" within {timeout:g} s" if isinstance(error, TimeoutError) else f" ({error.strerror or error})"
            )
        if answer is None:
            return
        raise ConnectionError(f"{address} is not a Ray {'client server' if client else 'GCS'}: {answer}; {fix}")


@dataclass(frozen=True)
class ExecutorEntry:
    """A registered executor: ``factory(**options)`` builds it; ``options`` are its options with their defaults."""

    name: str
    description: str
    factory: Callable[..., BaseExecutor] | str = field(repr=False)
    options: Mapping[str, Any] = field(default_factory=dict)
    extra: str | None = None

    def create(self, **options: Any) -> BaseExecutor:
        """The executor, ``options`` merged over the defaults (an unknown option is a ValueError)."""
        factory = load_target(self.factory, what=f"executor {self.name!r}", extra=self.extra)
        return factory(**merge_options(self.options, options, what=f"executor {self.name!r}"))


#: The executors ``--executor`` and :func:`get_executor` accept, by name.
EXECUTORS: Registry[ExecutorEntry] = Registry("executor")


def register_executor(
    name: str,
    factory: Callable[..., BaseExecutor] | str,
    *,
    description: str,
    options: Mapping[str, Any] | None = None,
    extra: str | None = None,
    overwrite: bool = False,
) -> ExecutorEntry:
    """Add an executor and return its entry.

    ``factory(**options)`` builds the executor (a :class:`BaseExecutor`), or is its dotted path
    ``"package.module:attribute"``, imported when first used; ``options`` are every option it takes, with their
    defaults; ``description`` is one line for ``--help``; ``extra`` the pip extra its dependencies come from.

    Examples
    --------
    >>> class Serial(LocalExecutor):
    ...     name = "serial"
    >>> _ = register_executor("serial", Serial, description="one item after another", options={"workers": None})
    >>> get_executor("serial").map(abs, [-1])
    [1]
    >>> _ = EXECUTORS.unregister("serial")
    """
    entry = ExecutorEntry(name, description, factory, dict(options or {}), extra)
    return EXECUTORS.register(entry, overwrite=overwrite)


def executor_names() -> list[str]:
    """The registered executors' names (plugins loaded first)."""
    load_plugins()
    return EXECUTORS.names()


def get_executor(name: str = "local", **options: Any) -> BaseExecutor:
    """The executor called ``name`` (``"local"``, ``"ray"``: see :class:`RayExecutor`, or a plugin's), built with
    ``options``; use it as a context manager (or call ``close``) to release a cluster it started.

    An option of another executor is refused unless it has that executor's default (``address=None`` with local).
    """
    if name not in EXECUTORS:
        load_plugins()
    if name not in EXECUTORS:
        raise ValueError(f"executor must be one of {', '.join(EXECUTORS.names())}, got {name!r}")
    entry = EXECUTORS.get(name)
    owners = {key: other for other in EXECUTORS for key in other.options if key not in entry.options}
    misplaced = [key for key in options if key in owners and options[key] != owners[key].options[key]]
    if misplaced:
        where = " and ".join(sorted({owners[key].name for key in misplaced}))
        raise ValueError(f"{' and '.join(misplaced)} apply to the {where} executor only, not to {entry.name!r}")
    return entry.create(**{key: value for key, value in options.items() if key not in owners})


def _defaults(factory: Callable[..., BaseExecutor]) -> dict[str, Any]:
    return {name: parameter.default for name, parameter in inspect.signature(factory).parameters.items()}


register_executor("local", LocalExecutor, description="in this process (default)", options=_defaults(LocalExecutor))
register_executor(
    "ray", RayExecutor, description="as tasks on a Ray cluster", options=_defaults(RayExecutor), extra="ray"
)
