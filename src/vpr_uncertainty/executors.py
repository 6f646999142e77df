"""Where independent work items run: in this process (``local``) or as tasks on a Ray cluster (``ray``).

An executor has two operations: :meth:`map` applies a function to every item and returns the results in the order
of the items; :meth:`imap` yields ``(position, result)`` pairs as they complete, for callers that write each result
as it comes. The functions are plain module-level functions of this package (Ray pickles them by reference), and they
write their own cached artefacts (a grid cell, a descriptor file) to paths that every worker sees: with a cluster
of several machines the output folder must be on a shared filesystem.

Ray is an extra (``pip install 'vpr-uncertainty[ray]'``) imported only when the ``ray`` executor is chosen. A task
whose worker dies is retried by Ray (``max_retries``); a run that is stopped is resumed from the caches.
"""

from __future__ import annotations

import contextlib
import math
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

__all__ = [
    "CONNECT_TIMEOUT",
    "EXECUTORS",
    "START_TIMEOUT",
    "LocalExecutor",
    "RayExecutor",
    "get_executor",
    "import_ray",
    "start_ray",
    "wait_for_address",
]

#: The executor names accepted by :func:`get_executor` (and by ``--executor``).
EXECUTORS = ("local", "ray")
#: How many times Ray reruns a task whose worker died.
MAX_RETRIES = 3
#: Seconds to wait for a Ray cluster at an explicit address to accept a connection (``--connect-timeout``).
CONNECT_TIMEOUT = 30.0
#: Seconds a Ray start-up (``ray.init``: a new local cluster, or the connection to one) may take before it is
#: abandoned and whatever it started is shut down.
START_TIMEOUT = 180.0


def import_ray() -> Any:
    """The ``ray`` module, or an ImportError naming the extra that provides it."""
    try:
        import ray
    except ImportError as error:
        raise ImportError(
            "the ray executor needs Ray: pip install 'vpr-uncertainty[ray]' (or pip install 'ray[data]')"
        ) from error
    return ray


def _apply(function: Callable[[Any], Any], item: Any) -> Any:
    """``function(item)``: the one remote function of :class:`RayExecutor` (``function`` may be a partial)."""
    return function(item)


def _check_workers(workers: int | None) -> int | None:
    if workers is None:
        return None
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    return workers


def _check_gpus(gpus_per_worker: float) -> float:
    if isinstance(gpus_per_worker, bool) or not isinstance(gpus_per_worker, (int, float)) or gpus_per_worker < 0:
        raise ValueError(f"gpus_per_worker must be a number >= 0, got {gpus_per_worker!r}")
    return float(gpus_per_worker)


class LocalExecutor:
    """Run every item in this process, one after the other (the default; what the toolkit did before executors).

    Parameters
    ----------
    workers : int, optional
        Ignored (accepted so that both executors take the same options).
    """

    name = "local"

    def __init__(self, workers: int | None = None) -> None:
        self.workers = _check_workers(workers)

    def map(
        self, function: Callable[[Any], Any], items: Iterable[Any], *, on_result: Callable[[Any], None] | None = None
    ) -> list[Any]:
        """``[function(item) for item in items]``, calling ``on_result`` with each result as it comes.

        Parameters
        ----------
        function : callable
        items : iterable
        on_result : callable, optional
            Called with each result (e.g. to advance a progress bar).

        Returns
        -------
        list
            In the order of ``items``.
        """
        results = []
        for _, result in self.imap(function, items):
            results.append(result)
            if on_result is not None:
                on_result(result)
        return results

    def imap(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        """Yield ``(position, function(item))`` for every item, one after the other (in order here)."""
        for position, item in enumerate(items):
            yield position, function(item)

    def close(self) -> None:
        """Nothing to release."""

    def __enter__(self) -> LocalExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RayExecutor:
    """Run every item as a Ray task, at most ``workers`` at once, each with ``gpus_per_worker`` GPUs.

    Connects to the cluster at ``address`` (``"auto"``: the one started by ``ray start`` on this machine), or,
    without one, starts a local cluster with ``workers`` CPUs. When Ray is already initialised in this process
    (e.g. by the caller), that cluster is used and left running by :meth:`close`.

    Parameters
    ----------
    address : str, optional
        The cluster's address (``host:port``, ``ray://host:10001`` or ``"auto"``).
    workers : int, optional
        The most tasks in flight at once; default: the cluster's CPUs.
    gpus_per_worker : float, default=0
        GPUs Ray assigns to each task (fractions share one GPU).
    connect_timeout : float, default=30
        Seconds to wait for the cluster at ``host:port`` (or ``ray://host:port``) to accept a connection before a
        ConnectionError (Ray itself would wait for minutes on an address where nothing listens).
    start_timeout : float, default=180
        Seconds ``ray.init`` may take (see :func:`start_ray`).
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        workers: int | None = None,
        gpus_per_worker: float = 0.0,
        connect_timeout: float = CONNECT_TIMEOUT,
        start_timeout: float = START_TIMEOUT,
    ) -> None:
        self.workers = _check_workers(workers)
        self.gpus_per_worker = _check_gpus(gpus_per_worker)
        if address is not None and (not isinstance(address, str) or not address.strip()):
            raise ValueError(f"address must be a non-empty string such as 'auto' or 'host:6379', got {address!r}")
        for option, value in (("connect_timeout", connect_timeout), ("start_timeout", start_timeout)):
            if not (isinstance(value, (int, float)) and 0 < value < math.inf):
                raise ValueError(f"{option} must be a positive number of seconds, got {value!r}")
        if address is not None:
            wait_for_address(address, connect_timeout)
        self.ray = import_ray()
        self._owns_cluster = False
        if not self.ray.is_initialized():
            # "local": a new cluster, never one that a `ray start` on this machine left behind
            options: dict[str, Any] = {"address": address or "local", "include_dashboard": False}
            options["log_to_driver"] = False
            if address is None and self.workers is not None:
                options["num_cpus"] = self.workers
            start_ray(self.ray, options, start_timeout)
            self._owns_cluster = True
        if self.workers is None:
            self.workers = max(1, int(self.ray.cluster_resources().get("CPU", 1)))

    def map(
        self, function: Callable[[Any], Any], items: Iterable[Any], *, on_result: Callable[[Any], None] | None = None
    ) -> list[Any]:
        """``[function(item) for item in items]`` as Ray tasks, at most ``workers`` in flight.

        A task whose worker process dies is rerun (up to :data:`MAX_RETRIES` times); an exception raised by
        ``function`` is raised here, as the original exception type.

        Parameters
        ----------
        function : callable
            A module-level function or a partial of one (the workers import this package).
        items : iterable
        on_result : callable, optional
            Called with each result as it completes (in completion order).

        Returns
        -------
        list
            In the order of ``items``.
        """
        items = list(items)
        results: list[Any] = [None] * len(items)
        for position, result in self.imap(function, items):
            results[position] = result
            if on_result is not None:
                on_result(result)
        return results

    def imap(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        """Yield ``(position, function(item))`` for every item as its task completes (completion order).

        At most ``workers`` tasks are in flight, so a consumer that writes each result as it comes (a cache)
        keeps what finished when the run stops. Retries and errors as in :meth:`map`.
        """
        ray = self.ray
        remote = ray.remote(_apply).options(
            num_cpus=1, num_gpus=self.gpus_per_worker, max_retries=MAX_RETRIES, retry_exceptions=False
        )
        function = ray.put(function)  # serialised once (a partial may hold a model), not once per task
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
                    raise error.as_instanceof_cause() from None
                for next_position, item in queue:
                    pending[remote.remote(function, item)] = next_position
                    break
                yield position, result
        finally:
            for reference in pending:  # the consumer stopped early (an error, Ctrl-C): no orphan tasks
                ray.cancel(reference, force=True)

    def close(self) -> None:
        """Shut down the local cluster this executor started (a cluster it connected to keeps running)."""
        if self._owns_cluster and self.ray.is_initialized():
            self.ray.shutdown()
        self._owns_cluster = False

    def __enter__(self) -> RayExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


Executor = LocalExecutor | RayExecutor


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


def wait_for_address(address: str, timeout: float) -> None:
    """Wait until something accepts a TCP connection at a Ray ``address`` (``host:port`` or ``ray://host:port``).

    ``"auto"`` and ``"local"`` name no port and pass unchecked (Ray answers those at once). Raises
    ConnectionError after ``timeout`` seconds, naming the address.
    """
    target = address.split("://", 1)[1] if "://" in address else address
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit():
        return
    deadline = time.monotonic() + timeout
    while True:
        try:
            with socket.create_connection((host.strip("[]"), int(port)), timeout=min(2.0, timeout)):
                return
        except OSError as error:
            if time.monotonic() >= deadline:
                raise ConnectionError(
                    f"no Ray cluster answers at {address} within {timeout:g} s ({error.strerror or error}); start "
                    "one there (`ray start --head`), or raise --connect-timeout"
                ) from None
            time.sleep(min(0.5, max(deadline - time.monotonic(), 0.0)))


def get_executor(
    name: str = "local",
    *,
    address: str | None = None,
    workers: int | None = None,
    gpus_per_worker: float = 0.0,
    connect_timeout: float = CONNECT_TIMEOUT,
    start_timeout: float = START_TIMEOUT,
) -> Executor:
    """The executor called ``name``.

    Parameters
    ----------
    name : {"local", "ray"}
    address : str, optional
        The Ray cluster's address (``ray`` only).
    workers : int, optional
        The most items in flight at once (``ray``; the local executor runs one at a time).
    gpus_per_worker : float, default=0
        GPUs per Ray task or actor (``ray`` only).
    connect_timeout : float, default=30
        Seconds to wait for a Ray cluster at ``address`` (``ray`` only).
    start_timeout : float, default=180
        Seconds Ray's start-up may take (``ray`` only).

    Returns
    -------
    LocalExecutor or RayExecutor
        Use as a context manager (or call ``close``) to release a cluster it started.
    """
    if name not in EXECUTORS:
        raise ValueError(f"executor must be one of {', '.join(EXECUTORS)}, got {name!r}")
    if name == "local":
        if address is not None or _check_gpus(gpus_per_worker):
            raise ValueError("address and gpus_per_worker apply to the ray executor only, not to 'local'")
        return LocalExecutor(workers)
    return RayExecutor(
        address=address,
        workers=workers,
        gpus_per_worker=gpus_per_worker,
        connect_timeout=connect_timeout,
        start_timeout=start_timeout,
    )
