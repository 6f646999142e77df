"""Descriptor extraction as Ray Data batch inference (``--executor ray``): a pool of model actors, one writer.

The driver (:func:`~vpr_uncertainty.descriptors.extract.extract_descriptors`) keeps the HDF5 cache: it decides which
images are missing or changed (content keys) and hands only those to :func:`ray_described_batches`. That builds a
Ray dataset of them (one row per image: its index in the request, its name and its path) and runs
``map_batches(DescribeBatch, ...)`` on a fixed pool of ``executor.workers`` actors (``ActorPoolStrategy``), each
with one CPU and ``executor.gpus_per_worker`` GPUs assigned by Ray, each loading the model once. Every output row
carries the image's index, its decoding error (``""`` when usable) and its descriptor (empty when not), so the
driver applies ``on_error`` and records ``failed`` exactly as a local run does. The driver reads the results with
``iter_batches`` in the order of the request (``preserve_order``, so that ``on_error="fail"`` stops at the same
image, with the same batches written, as a local run; the index column maps each row back to its image and checks
that none is lost), in batches of ``batch_size``, and appends each one to the cache as it arrives: the file, its
fingerprint and its resumption image by image are those of a local run. The pool lives for one call (one split):
its start (worker processes, model loads) is the fixed cost of the Ray executor. The actors decode
the images themselves: the image paths must be readable on every node (a shared filesystem). Names and paths
travel as bytes, since Arrow strings must be valid UTF-8 and file names need not be.

When a worker process dies, Ray restarts its actor (``max_restarts=-1``) and reruns the batch it held, up to
:data:`TASK_RETRIES` times (``max_task_retries``); a batch that keeps killing its worker stops the run with
:class:`WorkerDiedError` instead of being retried for ever (Ray Data's default). The batches already written stay
in the cache, so a run that stops is resumed by running it again. While it runs, Ray Data's own progress bars and
execution logs are switched off (see :func:`quiet_data_context`): the caller's progress bar advances per written
batch.
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.executors import MAX_RETRIES

__all__ = ["TASK_RETRIES", "DescribeBatch", "WorkerDiedError", "quiet_data_context", "ray_described_batches"]

_Item = tuple[int, str, Path]
#: How many times Ray reruns a batch whose worker process died (on a restarted actor).
TASK_RETRIES = MAX_RETRIES
_NO_DESCRIPTOR = np.empty(0, dtype=np.float32)


class WorkerDiedError(RuntimeError):
    """A batch of images killed its Ray worker more often than :data:`TASK_RETRIES` allows."""


def _encode(text: str) -> bytes:
    # surrogatepass: every Python str (also names decoded with surrogateescape) comes back unchanged
    return text.encode("utf-8", "surrogatepass")


def _decode_text(data: Any) -> str:
    return bytes(data).decode("utf-8", "surrogatepass")


class DescribeBatch:
    """The callable class of ``map_batches``: a model loaded once per actor, applied to batches of image rows.

    Parameters
    ----------
    model : DescriptorModel or callable
        The loaded model (deserialised in the worker), or a function without arguments that loads it there (e.g. a
        ``functools.partial`` of :func:`vpr_uncertainty.stages.descriptors.model_of`).
    """

    def __init__(self, model: Any) -> None:
        from vpr_uncertainty.descriptors.models import DescriptorModel

        self.model = model if isinstance(model, DescriptorModel) else model()

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Decode the batch's images and run the model on the usable ones.

        Parameters
        ----------
        batch : dict of str to ndarray, each of length B
            ``index`` (int), ``name`` and ``path`` (UTF-8 bytes, surrogates passed through).

        Returns
        -------
        dict of str to ndarray, each of length B
            ``index``; ``error`` (str, ``""`` for a usable image); ``descriptor`` (float32 rows of length D, or of
            length 0 for an image that cannot be used).
        """
        from vpr_uncertainty.descriptors.extract import _decode, _forward
        from vpr_uncertainty.descriptors.images import ImageDecodeError

        items = [
            (int(index), _decode_text(name), Path(os.fsdecode(bytes(path))))
            for index, name, path in zip(batch["index"], batch["name"], batch["path"], strict=True)
        ]
        decoded = [_decode(item, self.model) for item in items]
        errors = [result.reason if isinstance(result, ImageDecodeError) else "" for _, result in decoded]
        images = [result for _, result in decoded if not isinstance(result, ImageDecodeError)]
        rows = iter(_forward(self.model, images) if images else ())
        descriptors = np.empty(len(items), dtype=object)
        for position, error in enumerate(errors):
            descriptors[position] = _NO_DESCRIPTOR if error else next(rows)
        return {"index": np.asarray(batch["index"]), "error": np.array(errors, dtype=object), "descriptor": descriptors}


def _import_ray_data() -> Any:
    try:
        import ray.data
    except ImportError as error:
        raise ImportError(
            "extraction with the ray executor needs Ray Data: pip install 'vpr-uncertainty[ray]' "
            "(or pip install 'ray[data]')"
        ) from error
    return ray.data


@contextlib.contextmanager
def quiet_data_context(ray_data: Any) -> Iterator[Any]:
    """Ray Data's current context set for one extraction, restored afterwards.

    No progress bars, no execution plan or statistics printed, only errors from the ``ray.data`` loggers on the
    console, results in the order of the input (``preserve_order``), and an exception raised by the model
    re-raised as itself (``raise_original_map_exception``, where this Ray version has it).
    """
    context = ray_data.DataContext.get_current()
    settings = {
        "enable_progress_bars": False,
        "enable_operator_progress_bars": False,
        "print_on_execution_start": False,
        "enable_auto_log_stats": False,
        "raise_original_map_exception": True,
    }
    settings = {key: value for key, value in settings.items() if hasattr(context, key)}
    saved = {key: getattr(context, key) for key in settings}
    saved_order = context.execution_options.preserve_order
    logger = logging.getLogger("ray.data")
    saved_level = logger.level
    try:
        for key, value in settings.items():
            setattr(context, key, value)
        context.execution_options.preserve_order = True
        logger.setLevel(logging.ERROR)
        yield context
    finally:
        for key, value in saved.items():
            setattr(context, key, value)
        context.execution_options.preserve_order = saved_order
        logger.setLevel(saved_level)


def _rows(todo: Sequence[_Item]) -> list[dict[str, Any]]:
    return [{"index": index, "name": _encode(name), "path": os.fsencode(path)} for index, name, path in todo]


def ray_described_batches(
    todo: Sequence[_Item],
    model: Any,
    executor: Any,
    *,
    batch_size: int,
    model_factory: Callable[[], Any] | None = None,
) -> Iterator[tuple[list[tuple[_Item, Any]], np.ndarray | None]]:
    """The images of ``todo`` in batches of ``batch_size``, decoded and described by Ray Data actors, in order.

    Parameters
    ----------
    todo : sequence of (index, name, path)
        The images to describe, indices unique.
    model : DescriptorModel
        The driver's model; sent to the actors when ``model_factory`` is None.
    executor : RayExecutor
        Gives the number of actors (``workers``, at most one per batch) and their GPUs (``gpus_per_worker``).
    batch_size : int
        Images per model call and per yielded batch.
    model_factory : callable, optional
        Loads the model in each actor instead of sending the driver's.

    Yields
    ------
    decoded : list of ((index, name, path), ImageDecodeError or None)
        The batch's images, in the order of ``todo``.
    descriptors : ndarray of shape (G, D) or None
        Those of the G usable images of the batch, in order (None when there are none).

    Raises
    ------
    WorkerDiedError
        When a batch killed its worker process more than :data:`TASK_RETRIES` times.
    """
    from vpr_uncertainty.descriptors.images import ImageDecodeError

    if not todo:
        return
    ray_data = _import_ray_data()
    ray = executor.ray
    items = {item[0]: item for item in todo}
    if len(items) != len(todo):
        raise ValueError("the indices of the images to describe must be unique")
    blocks = -(-len(todo) // batch_size)
    seen = 0
    with quiet_data_context(ray_data):
        with warnings.catch_warnings():
            # Ray 2.60 deprecates remote arguments passed to map_batches (max_restarts, max_task_retries have no
            # named parameter yet); without them a batch that kills its worker is retried for ever
            warnings.filterwarnings("ignore", message=".*ray_remote_args.* deprecated", category=DeprecationWarning)
            dataset = ray_data.from_items(_rows(todo), override_num_blocks=blocks).map_batches(
                DescribeBatch,
                fn_constructor_args=(model if model_factory is None else model_factory,),
                batch_size=batch_size,
                compute=ray_data.ActorPoolStrategy(size=max(1, min(executor.workers, blocks))),
                num_cpus=1,
                num_gpus=executor.gpus_per_worker,
                batch_format="numpy",
                max_restarts=-1,
                max_task_retries=TASK_RETRIES,
            )
        batches = iter(dataset.iter_batches(batch_size=batch_size, batch_format="numpy"))
        try:
            while True:
                try:
                    batch = next(batches)
                except StopIteration:
                    break
                except ray.exceptions.RayActorError as error:
                    raise WorkerDiedError(
                        f"a batch of images killed its Ray worker {TASK_RETRIES + 1} times ({seen} of {len(todo)} "
                        "images were described and written before); run again to resume"
                    ) from error
                decoded: list[tuple[_Item, Any]] = []
                good: list[np.ndarray] = []
                for index, reason, row in zip(batch["index"], batch["error"], batch["descriptor"], strict=True):
                    item = items.pop(int(index), None)
                    if item is None:
                        raise RuntimeError(f"Ray Data returned image index {int(index)} twice or unrequested")
                    decoded.append((item, ImageDecodeError(item[1], item[2], str(reason)) if reason else None))
                    if not reason:
                        good.append(np.asarray(row, dtype=np.float32))
                seen += len(decoded)
                yield decoded, (np.stack(good) if good else None)
        finally:
            close = getattr(batches, "close", None)
            if close is not None:
                close()
    if items:
        raise RuntimeError(f"Ray Data returned no result for {len(items)} of {len(todo)} images")
