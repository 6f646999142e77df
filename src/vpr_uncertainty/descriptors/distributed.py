"""Descriptor extraction on a pool of Ray actors (``--executor ray``): one model load per actor, the driver writes.

The driver (:func:`~vpr_uncertainty.descriptors.extract.extract_descriptors`) keeps the HDF5 cache: it decides which
images are missing or changed (content keys), sends only those, batch by batch, to a pool of
:class:`DescriptorActor` (``executor.workers`` of them, each with ``executor.gpus_per_worker`` GPUs assigned by Ray)
and appends each batch that comes back, so the file, its fingerprint and its resumption are those of a local run.
The actors decode the images themselves: the image paths must be readable on every node (a shared filesystem).

This uses plain Ray actors (a pool kept here) rather than Ray Data ``map_batches``: the batches are small
lists of paths whose results must reach one writer in this process, which an actor pool does without a dataset
pipeline, and it keeps the extra at plain ``ray``. A batch whose actor dies is sent again to another actor once;
the batches already written stay in the cache, so a run that stops is resumed by running it again.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["DescriptorActor", "ray_described_batches"]

_Item = tuple[int, str, Path]
#: How many times one batch is resent after its actor died.
BATCH_RETRIES = 1


class DescriptorActor:
    """A model loaded once in a Ray worker; :meth:`describe` decodes a batch of images and runs the model.

    Parameters
    ----------
    model : DescriptorModel or callable
        The loaded model (deserialised in the worker), or a function without arguments that loads it there (e.g. a
        ``functools.partial`` of :func:`vpr_uncertainty.stages.descriptors.model_of`).
    """

    def __init__(self, model: Any) -> None:
        from vpr_uncertainty.descriptors.models import DescriptorModel

        self.model = model if isinstance(model, DescriptorModel) else model()

    def describe(self, batch: Sequence[_Item]) -> tuple[list[str | None], np.ndarray | None]:
        """``(errors, descriptors)``: the decoding error of each image (None when usable) and the (G, D) float32
        descriptors of the G usable ones, in the batch's order (None when there are none)."""
        from vpr_uncertainty.descriptors.extract import _decode, _forward
        from vpr_uncertainty.descriptors.images import ImageDecodeError

        decoded = [_decode(item, self.model) for item in batch]
        errors = [result.reason if isinstance(result, ImageDecodeError) else None for _, result in decoded]
        images = [result for _, result in decoded if not isinstance(result, ImageDecodeError)]
        return errors, (_forward(self.model, images) if images else None)

    def pid(self) -> int:
        """The worker's process id (for tests that kill a worker)."""
        import os

        return os.getpid()


def ray_described_batches(
    batches: Sequence[Sequence[_Item]], model: Any, executor: Any, *, model_factory: Callable[[], Any] | None = None
) -> Iterator[tuple[list[tuple[_Item, Any]], np.ndarray | None]]:
    """Each batch with its decoding results and descriptors, computed by a pool of actors (completion order).

    Parameters
    ----------
    batches : sequence of sequences of (index, name, path)
    model : DescriptorModel
        The driver's model; sent to the actors when ``model_factory`` is None.
    executor : RayExecutor
        Gives the number of actors (``workers``) and their GPUs (``gpus_per_worker``).
    model_factory : callable, optional
        Loads the model in each actor instead of sending the driver's.

    Yields
    ------
    decoded : list of ((index, name, path), ImageDecodeError or None)
    descriptors : ndarray of shape (G, D) or None
        Those of the usable images of the batch, in order.
    """
    from vpr_uncertainty.descriptors.images import ImageDecodeError

    if not batches:
        return
    ray = executor.ray
    actor_class = ray.remote(DescriptorActor).options(num_cpus=1, num_gpus=executor.gpus_per_worker)
    source = ray.put(model if model_factory is None else model_factory)
    count = max(1, min(executor.workers, len(batches)))
    actors = [actor_class.remote(source) for _ in range(count)]
    queue = list(range(len(batches)))[::-1]
    retries = dict.fromkeys(range(len(batches)), BATCH_RETRIES)
    pending: dict[Any, tuple[int, Any]] = {}

    def submit(actor: Any) -> None:
        if queue:
            position = queue.pop()
            pending[actor.describe.remote(batches[position])] = (position, actor)

    try:
        for actor in actors:
            submit(actor)
        while pending:
            (done,), _ = ray.wait(list(pending), num_returns=1)
            position, actor = pending.pop(done)
            try:
                errors, descriptors = ray.get(done)
            except ray.exceptions.RayActorError:
                if not retries[position]:
                    raise
                retries[position] -= 1
                queue.append(position)
                actors.remove(actor)
                actor = actor_class.remote(source)  # a fresh actor in place of the dead one
                actors.append(actor)
                submit(actor)
                continue
            except ray.exceptions.RayTaskError as error:
                raise error.as_instanceof_cause() from None
            submit(actor)
            decoded = [
                (item, None if reason is None else ImageDecodeError(item[1], item[2], reason))
                for item, reason in zip(batches[position], errors, strict=True)
            ]
            yield decoded, descriptors
    finally:
        for actor in actors:
            ray.kill(actor)
