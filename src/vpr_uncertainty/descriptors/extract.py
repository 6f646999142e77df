"""Batched descriptor extraction from image files into the HDF5 cache, in this process or on Ray Data actors; each
batch is appended to the cache before the next starts, so an interrupted run resumes where it stopped. How each
way runs, and how memory is bounded: see docs/explanation/descriptors.md.
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import content_key
from vpr_uncertainty.data.images import printable
from vpr_uncertainty.descriptors.cache import SPLITS, DescriptorCache, read_complete, read_descriptors
from vpr_uncertainty.descriptors.images import ImageDecodeError, load_image, to_model_input
from vpr_uncertainty.descriptors.models import DEFAULT_MODEL, DescriptorModel, load_model
from vpr_uncertainty.executors import MAX_RETRIES
from vpr_uncertainty.plugins import Travelling, import_or_explain
from vpr_uncertainty.progress import progress_bar
from vpr_uncertainty.retrieval.result import check_positive_int

ON_ERROR = ("fail", "skip")

_Item = tuple[int, str, Path]


def _validate(
    image_paths: Sequence[str | Path], names: Sequence[str] | None, split: str, batch_size: int, on_error: str
) -> tuple[list[Path], list[str]]:
    paths = [Path(path) for path in image_paths]
    if names is None:
        names = [path.name for path in paths]
        duplicated = len(set(names)) != len(names)
        hint = "; pass names= (e.g. paths relative to the dataset folder)" if duplicated else ""
    else:
        names = [str(name) for name in names]
        hint = ""
        if len(names) != len(paths):
            raise ValueError(f"got {len(paths)} image paths but {len(names)} names")
    if len(set(names)) != len(names):
        seen: set[str] = set()
        duplicates = sorted({name for name in names if name in seen or seen.add(name)})
        raise ValueError(f"image names must be unique, repeated: {', '.join(duplicates[:5])}{hint}")
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    check_positive_int(batch_size, "batch_size")
    if on_error not in ON_ERROR:
        raise ValueError(f"on_error must be one of {ON_ERROR}, got {on_error!r}")
    return paths, names


def describe_left_out(left_out: Sequence[dict[str, str]], total: int, what: str, *, shown: int = 3) -> str:
    """One line: how many of ``total`` images were left out, the first ``shown`` with their reasons.

    Examples
    --------
    >>> describe_left_out([{"name": "q/a.jpg", "error": "file not found"}], 10, "'queries' images")
    "left out 1 of 10 'queries' images that cannot be used: 'q/a.jpg' (file not found)"
    """
    listed = "; ".join(f"'{printable(entry['name'])}' ({entry['error']})" for entry in left_out[:shown])
    more = f"; and {len(left_out) - shown} more" if len(left_out) > shown else ""
    return f"left out {len(left_out)} of {total} {what} that cannot be used: {listed}{more}"


def _decode(item: _Item, model: DescriptorModel) -> tuple[_Item, np.ndarray | ImageDecodeError]:
    _, name, path = item
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        problem = "its name is not valid UTF-8 and cannot be stored in descriptor or retrieval files; rename the file"
        return item, ImageDecodeError(name, path, problem + " (e.g. with convmv)")
    try:
        return item, load_image(path, model.preprocessing, name=name)
    except ImageDecodeError as error:
        return item, error


def _decoded_batches(
    batches: Sequence[Sequence[_Item]], model: DescriptorModel, workers: int
) -> Iterator[list[tuple[_Item, np.ndarray | ImageDecodeError]]]:
    if workers <= 0:
        for batch in batches:
            yield [_decode(item, model) for item in batch]
        return
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="vpr-decode") as pool:
        pending = None
        for batch in batches:
            futures = [pool.submit(_decode, item, model) for item in batch]
            if pending is not None:
                yield [future.result() for future in pending]
            pending = futures
        if pending is not None:
            yield [future.result() for future in pending]


def _described_batches(
    batches: Sequence[Sequence[_Item]], model: DescriptorModel, workers: int
) -> Iterator[tuple[list[tuple[_Item, np.ndarray | ImageDecodeError]], np.ndarray | None]]:
    """Each decoded batch with the descriptors of its usable images (None when none is usable), in this process."""
    for decoded in _decoded_batches(batches, model, workers):
        images = [result for _, result in decoded if not isinstance(result, ImageDecodeError)]
        yield decoded, (_forward(model, images) if images else None)


def _described(
    todo: Sequence[_Item],
    model: DescriptorModel,
    batch_size: int,
    workers: int,
    executor: Any,
    model_factory: Callable[[], Any] | None,
) -> Iterator[tuple[list[tuple[_Item, np.ndarray | ImageDecodeError | None]], np.ndarray | None]]:
    """The batches of ``todo`` with their descriptors, in order: in this process, or on Ray Data actors."""
    if executor is not None and executor.name != "local":
        return ray_described_batches(todo, model, executor, batch_size=batch_size, model_factory=model_factory)
    batches = [todo[start : start + batch_size] for start in range(0, len(todo), batch_size)]
    return _described_batches(batches, model, workers)


def _content_key(path: Path) -> str:
    """The image's content key, or "" when it cannot be read (the decoder then reports why)."""
    try:
        return content_key(path)
    except OSError:
        return ""


def _forward(model: DescriptorModel, images: list[np.ndarray]) -> np.ndarray:
    """Descriptors (B, D) float32 of decoded images; images of different sizes run in separate sub-batches."""
    groups: dict[tuple[int, ...], list[int]] = {}
    for position, image in enumerate(images):
        groups.setdefault(image.shape, []).append(position)
    output: np.ndarray | None = None
    for positions in groups.values():
        batch = to_model_input([images[p] for p in positions], model.preprocessing, model.device)
        descriptors = model(batch).cpu().numpy()
        if output is None:
            output = np.empty((len(images), descriptors.shape[1]), dtype=np.float32)
        output[positions] = descriptors
    assert output is not None
    return output  # checked by the caller, which knows the images and the cache (_finite_rows)


#: The reason recorded (``on_error="skip"``) for an image whose descriptor holds NaN or infinite values.
NON_FINITE = "the model produced NaN or infinite descriptor values for it"


def _finite_rows(
    model: DescriptorModel,
    good: list[tuple[str, Path]],
    descriptors: np.ndarray,
    cache_path: str | Path | None,
    on_error: str,
    failed: list[dict[str, str]],
) -> tuple[list[str], np.ndarray]:
    """The names and rows of ``good`` images whose descriptors are finite; the others stop the extraction
    (``on_error="fail"``: ValueError naming them and the cache, which never receives them) or are left out."""
    bad = ~np.isfinite(descriptors).all(axis=1)
    if not bad.any():
        return [name for name, _ in good], descriptors
    left_out = [(name, path) for (name, path), is_bad in zip(good, bad, strict=True) if is_bad]
    if on_error == "fail":
        shown = ", ".join(f"'{printable(name)}'" for name, _ in left_out[:3])
        where = f"; none of them was written to {printable(cache_path)}" if cache_path is not None else ""
        raise ValueError(
            f"model {model.name!r} produced NaN or infinite descriptors for {len(left_out)} image(s): {shown}"
            f"{where}; check the model, or leave such images out (on_error='skip', --on-error skip)"
        )
    failed.extend({"name": name, "path": str(path), "error": NON_FINITE} for name, path in left_out)
    return [name for (name, _), is_bad in zip(good, bad, strict=True) if not is_bad], descriptors[~bad]


def cached_descriptors(
    config: dict[str, Any],
    image_paths: Sequence[str | Path],
    names: Sequence[str] | None,
    cache_path: str | Path,
    split: str = "database",
    *,
    half: bool = False,
) -> tuple[np.ndarray, np.ndarray] | None:
    """What :func:`extract_descriptors` would return without computing anything, found without a model; else None.

    ``config`` is the fingerprint of the model that :func:`extract_descriptors` would be given
    (:attr:`~vpr_uncertainty.descriptors.models.DescriptorModel.fingerprint`, known before loading it from
    :func:`~vpr_uncertainty.descriptors.models.model_identity`). Returns ``(names, descriptors)`` when the cache
    holds every image, unchanged (same content key), for this model and dtype (see
    :func:`~vpr_uncertainty.descriptors.cache.read_complete`); None when any image must be computed, or the cache
    must be repaired or rebuilt: the caller then loads the model and runs :func:`extract_descriptors`.
    """
    paths = [Path(path) for path in image_paths]
    names = [path.name for path in paths] if names is None else [str(name) for name in names]
    if len(names) != len(paths) or len(set(names)) != len(names):
        return None  # extract_descriptors says what is wrong
    keys = [_content_key(path) for path in paths]
    return read_complete(cache_path, config, split, names, keys, dtype="float16" if half else "float32")


def extract_descriptors(
    model: Any,
    image_paths: Sequence[str | Path],
    names: Sequence[str] | None = None,
    cache_path: str | Path | None = None,
    split: str = "database",
    *,
    batch_size: int = 16,
    device: Any = "cpu",
    half: bool = False,
    on_error: str = "fail",
    workers: int | None = None,
    overwrite: bool = False,
    progress: bool | None = None,
    on_batch: Callable[[list[str]], None] | None = None,
    failed: list[dict[str, str]] | None = None,
    executor: Any = None,
    model_factory: Callable[[], Any] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Global descriptors of images, cached in an HDF5 file by image name and content key.

    Parameters
    ----------
    model : str, Path, DescriptorModel or callable
        Anything :func:`~vpr_uncertainty.descriptors.models.load_model` takes (None: the default model).
    image_paths : sequence of str or Path, length N
    names : sequence of str, length N, optional
        Unique key of each image in the cache (default: the file names, which must then be unique).
    cache_path : str or Path, optional
        HDF5 file to read from and write to; None computes everything in memory.
    split : {"database", "queries"}
    batch_size : int
        Images per forward pass (and per flush of the cache).
    device : str or torch.device
    half : bool
        Store float16 instead of float32 (the model still computes in float32).
    on_error : {"fail", "skip"}
        An image that cannot be used raises :class:`~vpr_uncertainty.descriptors.images.ImageDecodeError`, or is
        left out (one warning per call; the cache's ``failed`` attribute lists them with their reasons).
    workers : int, optional
        Threads that decode images ahead of the model (default: min(4, CPU count); 0 decodes in this thread).
    overwrite : bool
        Recompute everything even if the cache holds descriptors of the same model and preprocessing.
    progress : bool, optional
        Show a progress bar on stderr (default: when stderr is a terminal).
    on_batch : callable, optional
        Called with the names of each batch after it has been written to the cache.
    failed : list, optional
        Receives ``{"name", "path", "error"}`` of each image left out (``on_error="skip"``).
    executor : LocalExecutor or RayExecutor, optional
        Where the model runs (:func:`vpr_uncertainty.executors.get_executor`; default this process); with Ray,
        on a pool of model actors (docs/explanation/descriptors.md), this process writing the same cache.
    model_factory : callable, optional
        With Ray: loads the model in each actor (default: the loaded ``model`` is sent to them).

    Returns
    -------
    names : ndarray of shape (M,), str
        The requested names in the requested order, without the skipped ones (M = N unless images were skipped).
    descriptors : ndarray of shape (M, D), float32
        L2-normalised rows (rounded to float16 precision when ``half``).

    Examples
    --------
    >>> def tiny(images):  # any callable: (B, 3, H, W) -> (B, D)
    ...     return images.mean(dim=(2, 3))
    >>> import tempfile, numpy as np
    >>> from PIL import Image
    >>> folder = Path(tempfile.mkdtemp())
    >>> Image.fromarray(np.full((8, 8, 3), 200, np.uint8)).save(folder / "a.png")
    >>> names, descriptors = extract_descriptors(tiny, [folder / "a.png"], progress=False)
    >>> names, descriptors.shape
    (array(['a.png'], dtype='<U5'), (1, 3))
    """
    paths, names = _validate(image_paths, names, split, batch_size, on_error)
    if not isinstance(model, DescriptorModel):
        model = load_model(model if model is not None else DEFAULT_MODEL, device=device)
    else:
        model.to(device)
    workers = min(4, os.cpu_count() or 1) if workers is None else int(workers)
    dtype = "float16" if half else "float32"

    cache = None
    if cache_path is not None:
        cache = DescriptorCache(
            cache_path, model.fingerprint, dtype=dtype, model_name=model.name, overwrite=overwrite, verify=(split,)
        )
    memory: dict[str, np.ndarray] = {}
    failed = [] if failed is None else failed
    try:
        keys: dict[str, str] = {}
        done: set[str] = set()
        if cache is not None:
            cache.open()
            stored = cache.keys(split)
            keys = {name: _content_key(path) for name, path in zip(names, paths, strict=True)}
            done = {name for name in names if keys[name] and stored.get(name) == keys[name]}
        todo = [(i, name, path) for i, (name, path) in enumerate(zip(names, paths, strict=True)) if name not in done]
        with (
            progress_bar(
                total=len(names),
                initial=len(names) - len(todo),
                desc=f"{model.name} {split}",
                unit="img",
                enabled=progress,
            ) as bar,
            contextlib.closing(_described(todo, model, batch_size, workers, executor, model_factory)) as described,
        ):
            for decoded, descriptors in described:
                good: list[tuple[str, Path]] = []
                for (_, name, path), result in decoded:
                    if isinstance(result, ImageDecodeError):
                        if on_error == "fail":
                            raise result
                        failed.append({"name": name, "path": str(path), "error": result.reason})
                        continue
                    good.append((name, path))
                good_names = [name for name, _ in good]
                if descriptors is not None:
                    good_names, descriptors = _finite_rows(model, good, descriptors, cache_path, on_error, failed)
                    if cache is not None:
                        cache.append(split, good_names, descriptors, [keys[name] for name in good_names])
                    else:
                        memory.update(zip(good_names, descriptors.astype(dtype), strict=True))
                bar.update(len(decoded))
                if on_batch is not None:
                    on_batch(good_names)
        failed_names = {entry["name"] for entry in failed}
        kept = [name for name in names if name not in failed_names]
        if failed:
            where = f"; all of them are listed in {printable(cache.path)} (attribute 'failed')" if cache else ""
            warnings.warn(describe_left_out(failed, len(names), f"{split!r} images") + where, stacklevel=2)
        if cache is not None:
            cache.finalize(split, kept, failed)
            cache.close()
            # verified when the cache was opened, or sealed by finalize: not hashed a second time
            return read_descriptors(cache_path, split, verify=False)  # type: ignore[arg-type]
        dim = next(iter(memory.values())).shape[0] if memory else 0
        stacked = np.stack([memory[name] for name in kept]) if kept else np.empty((0, dim))
        return np.array(kept, dtype=str), stacked.astype(np.float32)
    finally:
        if cache is not None:
            cache.close()


#: How many times Ray reruns a batch whose worker process died (on a restarted actor).
TASK_RETRIES = MAX_RETRIES

_NO_DESCRIPTOR = np.empty(0, dtype=np.float32)


class WorkerDiedError(RuntimeError):
    """A batch of images killed its Ray worker more often than :data:`TASK_RETRIES` allows."""


class DescribeBatch:
    """The callable class of ``map_batches``: ``model`` (a DescriptorModel, or a function without arguments that
    loads one in the actor), applied to batches of image rows."""

    def __init__(self, model: Any) -> None:
        self.model = model if isinstance(model, DescriptorModel) else model()

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``{index, name, path}`` (B rows; name and path as UTF-8 bytes) -> ``{index, error, descriptor}``
        (``error`` "" for a usable image; ``descriptor`` a float32 row of length D, or of length 0)."""
        items = [
            (int(index), bytes(name).decode("utf-8", "surrogatepass"), Path(os.fsdecode(bytes(path))))
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
    return import_or_explain(
        "ray.data",
        "extraction with the ray executor needs Ray Data: pip install 'vpr-uncertainty[ray]' (or pip install "
        "'ray[data]')",
    )


@contextlib.contextmanager
def quiet_data_context(ray_data: Any) -> Iterator[Any]:
    """Ray Data's context for one extraction (restored afterwards): no progress bars, plans or statistics, only
    errors from the ``ray.data`` loggers, results in input order, a model's exception re-raised as itself."""
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
    # surrogatepass: every Python str (also names decoded with surrogateescape) comes back unchanged
    return [
        {"index": index, "name": name.encode("utf-8", "surrogatepass"), "path": os.fsencode(path)}
        for index, name, path in todo
    ]


def ray_described_batches(
    todo: Sequence[_Item], model: Any, executor: Any, *, batch_size: int, model_factory: Callable[[], Any] | None = None
) -> Iterator[tuple[list[tuple[_Item, Any]], np.ndarray | None]]:
    """The images of ``todo`` in batches of ``batch_size``, decoded and described by Ray Data actors, in order.

    ``todo``: (index, name, path) with unique indices; ``executor`` gives the actors (``workers``, at most one
    per batch) and their GPUs (``gpus_per_worker``); ``model_factory`` loads the model in each actor instead of
    sending ``model``.

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
                fn_constructor_args=(Travelling(model if model_factory is None else model_factory),),
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
                    if getattr(error, "actor_init_failed", False):  # e.g. a plugin it cannot import: last line
                        cause = str(error).strip().splitlines()[-1]
                        raise RuntimeError(f"the model could not be set up on a Ray worker: {cause}") from error
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
