"""Training the BTL head on frozen descriptors: triplet mining, early stopping, the training curve; deterministic for a
``seed`` on CPU. The procedure, step by step: see docs/explanation/btl.md.
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy import sparse

from vpr_uncertainty._validation import check_count
from vpr_uncertainty.btl.model import (
    DEFAULT_KL_WEIGHT,
    DEFAULT_MARGIN,
    DEFAULT_PRIOR_VARIANCE,
    BTLHead,
    bayesian_triplet_loss,
    row_digests,
    row_sketches,
)
from vpr_uncertainty.cache import write_figure, write_json
from vpr_uncertainty.descriptors.images import torch_device
from vpr_uncertainty.progress import progress_bar


@dataclass(frozen=True)
class Triplets:
    """Index triplets: ``anchor`` indexes the anchor descriptors, ``positive`` and ``negative`` the database.

    Attributes
    ----------
    anchor, positive, negative : ndarray of shape (T,), int64
    """

    anchor: np.ndarray
    positive: np.ndarray
    negative: np.ndarray

    def __len__(self) -> int:
        return int(self.anchor.size)

    @property
    def n_anchors(self) -> int:
        """Number of distinct anchors with at least one triplet."""
        return int(np.unique(self.anchor).size)


def _unit_rows(values: object, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float32)
    if array.ndim != 2:
        raise ValueError(f"{name} must be 2-D (n_images, dimension), got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} contain NaN or inf")
    norms = np.linalg.norm(array, axis=1, keepdims=True)
    if (norms == 0).any():
        raise ValueError(f"{name} row {int(np.flatnonzero(norms[:, 0] == 0)[0])} is all zeros")
    return array / norms


def _checked_positives(
    queries: np.ndarray, database: np.ndarray, positives: object, anchors: str, what: str
) -> sparse.csr_array:
    """``positives`` as a sparse bool array, after checking it against the descriptors (named ``anchors``)."""
    if queries.shape[1] != database.shape[1]:
        raise ValueError(
            f"{anchors} and database descriptors must have the same dimension, got {queries.shape[1]} and "
            f"{database.shape[1]}"
        )
    positives = sparse.csr_array(positives, dtype=bool)
    if positives.shape != (len(queries), len(database)):
        raise ValueError(f"positives must have shape ({len(queries)}, {len(database)}) ({what}), got {positives.shape}")
    return positives


def mine_triplets(
    anchor_descriptors: object,
    database_descriptors: object,
    positives: object,
    *,
    anchors: object = None,
    n_negatives: int = 10,
    max_positives: int = 10,
    same_set: bool = False,
    block_size: int = 1024,
) -> Triplets:
    """Triplets of (anchor, positive, hard negative) indices.

    Parameters
    ----------
    anchor_descriptors : array-like of shape (Q, dim)
        Descriptors of the anchors (queries).
    database_descriptors : array-like of shape (D, dim)
        Descriptors of the images positives and negatives are taken from.
    positives : sparse or dense bool matrix of shape (Q, D)
        Ground truth of each anchor.
    anchors : array-like of int, optional
        Rows of ``anchor_descriptors`` to mine for (e.g. the training split); default all.
    n_negatives : int, default 10
        Hard negatives per anchor: its most similar non-positive database images.
    max_positives : int, default 10
        Positives per anchor: its most similar positives.
    same_set : bool, default False
        The anchors are the database images themselves (Q == D, row i is database image i): an image is never
        its own positive or negative.
    block_size : int, default 1024
        Anchors whose similarities are computed at once (bounds memory to block_size × D floats).

    Returns
    -------
    Triplets
        Ordered by anchor, then positive (most similar first), then negative (most similar first).

    Examples
    --------
    >>> database = np.array([[1.0, 0.0], [0.0, 1.0], [0.7, 0.7], [-1.0, 0.0]])
    >>> query = np.array([[0.9, 0.1]])
    >>> t = mine_triplets(query, database, np.array([[True, False, False, False]]), n_negatives=2)
    >>> t.anchor.tolist(), t.positive.tolist(), t.negative.tolist()
    ([0, 0], [0, 0], [2, 1])
    """
    queries = _unit_rows(anchor_descriptors, "anchor descriptors")
    database = _unit_rows(database_descriptors, "database descriptors")
    positives = _checked_positives(queries, database, positives, "anchor", "anchors × database")
    if same_set and len(queries) != len(database):
        raise ValueError("same_set=True needs the anchors to be the database images (as many rows)")
    for name, value in (("n_negatives", n_negatives), ("max_positives", max_positives), ("block_size", block_size)):
        check_count(value, name, 1)
    rows = np.arange(len(queries)) if anchors is None else np.asarray(anchors, dtype=np.int64).ravel()
    if rows.size and (rows.min() < 0 or rows.max() >= len(queries)):
        raise ValueError(f"anchors must index the {len(queries)} anchor descriptors")

    parts: tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]] = ([], [], [])
    for start in range(0, rows.size, block_size):
        block = rows[start : start + block_size]
        similarity = queries[block] @ database.T  # (B, D)
        for row, anchor in zip(similarity, block, strict=True):
            own = positives.indices[positives.indptr[anchor] : positives.indptr[anchor + 1]]
            if same_set:
                own = own[own != anchor]
            if own.size == 0:
                continue
            positive = own[np.lexsort((own, -row[own]))[:max_positives]]
            candidates = row.copy()
            candidates[own] = -np.inf
            if same_set:
                candidates[anchor] = -np.inf
            count = min(n_negatives, int(np.isfinite(candidates).sum()))
            if count == 0:
                continue
            nearest = np.argpartition(-candidates, count - 1)[:count]
            negative = nearest[np.lexsort((nearest, -candidates[nearest]))]
            parts[0].append(np.full(positive.size * negative.size, anchor, dtype=np.int64))
            parts[1].append(np.repeat(positive, negative.size).astype(np.int64))
            parts[2].append(np.tile(negative, positive.size).astype(np.int64))
    if not parts[0]:
        empty = np.empty(0, dtype=np.int64)
        return Triplets(empty, empty.copy(), empty.copy())
    return Triplets(*(np.concatenate(part) for part in parts))


@dataclass
class BTLTrainingConfig:
    """Settings of :func:`train_btl_head` (all stored in the head file's metadata).

    ``embedding_dim=None`` means min(descriptor dimension, 2048): up to 2048-D descriptors the head starts as a
    rotation and retrieves exactly like the descriptors before training.
    """

    embedding_dim: int | None = None
    hidden_dim: int = 256
    margin: float = DEFAULT_MARGIN
    kl_weight: float = DEFAULT_KL_WEIGHT
    prior_variance: float = DEFAULT_PRIOR_VARIANCE
    n_negatives: int = 10
    max_positives: int = 10
    epochs: int = 100
    batch_size: int = 256
    learning_rate: float = 3e-4
    weight_decay: float = 1e-4
    val_fraction: float = 0.2
    patience: int = 10
    min_delta: float = 1e-4
    seed: int = 0
    device: str = "cpu"

    def __post_init__(self) -> None:
        for name in ("embedding_dim", "hidden_dim", "n_negatives", "max_positives", "epochs", "batch_size", "patience"):
            if name != "embedding_dim" or self.embedding_dim is not None:  # None: min(dimension, 2048)
                check_count(getattr(self, name), name, 1)
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(
                f"val_fraction must lie in (0, 1): early stopping needs a validation split, got {self.val_fraction}"
            )
        for name in ("learning_rate", "prior_variance"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("kl_weight", "weight_decay", "min_delta"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not math.isfinite(self.margin):
            raise ValueError(f"margin must be finite, got {self.margin}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class TrainingHistory:
    """Training curve: one entry per epoch, epoch 0 being the untrained head.

    ``train_loss`` of epoch e ≥ 1 is the mean over that epoch's mini-batches (in train mode, while the head
    changes); ``val_loss`` is measured after the epoch. Losses include the weighted KL term; ``*_nll`` are the
    −log P parts alone.
    """

    epoch: list[int] = field(default_factory=list)
    train_loss: list[float] = field(default_factory=list)
    train_nll: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    val_nll: list[float] = field(default_factory=list)
    best_epoch: int = 0
    stopped_early: bool = False
    n_train_anchors: int = 0
    n_val_anchors: int = 0
    n_train_triplets: int = 0
    n_val_triplets: int = 0

    @property
    def initial_val_loss(self) -> float:
        return self.val_loss[0]

    @property
    def best_val_loss(self) -> float:
        return self.val_loss[self.epoch.index(self.best_epoch)]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> dict[str, Any]:
        """The numbers worth keeping in the head file."""
        counts = ("n_train_anchors", "n_val_anchors", "n_train_triplets", "n_val_triplets")
        return {
            "best_epoch": self.best_epoch,
            "epochs_run": self.epoch[-1],
            "stopped_early": self.stopped_early,
            "initial_val_loss": self.initial_val_loss,
            "best_val_loss": self.best_val_loss,
            **{name: getattr(self, name) for name in counts},
        }


def resolve_device(device: str | torch.device) -> torch.device:
    """A torch device for the head, the CPU or a CUDA GPU, with a clear error when the GPU is not there."""
    return torch_device(device, types=("cpu", "cuda"))


def _as_descriptors(values: object, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float32)
    if array.ndim != 2 or array.shape[0] == 0 or array.shape[1] == 0:
        raise ValueError(f"{name} must be a non-empty 2-D array (n_images, dimension), got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} contain NaN or inf")
    return np.ascontiguousarray(array)


def _split_anchors(positives: sparse.csr_array, same_set: bool, fraction: float, seed: int) -> tuple[np.ndarray, ...]:
    counts = np.diff(positives.indptr)
    if same_set:  # an image is not its own positive
        counts = counts - positives.diagonal().astype(np.int64)
    usable = np.flatnonzero(counts > 0)
    if usable.size < 2:
        raise ValueError(
            f"only {usable.size} anchor(s) have a positive; training needs at least 2 (one for validation). "
            "Check the positions / positive radius or the positive lists."
        )
    order = np.random.default_rng(seed).permutation(usable)
    n_val = min(max(1, round(fraction * usable.size)), usable.size - 1)
    return np.sort(order[n_val:]), np.sort(order[:n_val])


def _batches(triplets: Triplets, batch_size: int, generator: torch.Generator | None) -> list[np.ndarray]:
    n = len(triplets)
    order = np.arange(n) if generator is None else torch.randperm(n, generator=generator).numpy()
    return [order[start : start + batch_size] for start in range(0, len(order), batch_size)]


class _TripletLoss:
    """Loss of index triplets, with the descriptors on the training device."""

    def __init__(self, anchors: torch.Tensor, database: torch.Tensor, config: BTLTrainingConfig) -> None:
        self.anchors = anchors
        self.database = database
        self.options = {"margin": config.margin, "kl_weight": config.kl_weight, "prior_variance": config.prior_variance}

    def __call__(self, head: BTLHead, triplets: Triplets, rows: np.ndarray) -> Any:
        # Each image goes through the head once per batch, however many triplets it is part of.
        device = self.anchors.device
        anchors, anchor_of = np.unique(triplets.anchor[rows], return_inverse=True)
        images, image_of = np.unique(
            np.concatenate([triplets.positive[rows], triplets.negative[rows]]), return_inverse=True
        )
        mean_q, var_q = head(self.anchors[torch.as_tensor(anchors, device=device)])
        mean_d, var_d = head(self.database[torch.as_tensor(images, device=device)])
        a = torch.as_tensor(anchor_of, device=device)
        p = torch.as_tensor(image_of[: rows.size], device=device)
        n = torch.as_tensor(image_of[rows.size :], device=device)
        return bayesian_triplet_loss(mean_q[a], var_q[a], mean_d[p], var_d[p], mean_d[n], var_d[n], **self.options)

    @torch.no_grad()
    def evaluate(self, head: BTLHead, triplets: Triplets) -> tuple[float, float]:
        """Mean loss and NLL over all the triplets, in eval mode."""
        head.eval()
        total = nll = 0.0
        for rows in _batches(triplets, 4096, None):
            terms = self(head, triplets, rows)
            total += float(terms.loss) * rows.size
            nll += float(terms.nll) * rows.size
        return total / len(triplets), nll / len(triplets)


def train_btl_head(
    database_descriptors: object,
    positives: object,
    *,
    query_descriptors: object = None,
    config: BTLTrainingConfig | None = None,
    progress: bool | None = None,
    **settings: Any,
) -> tuple[BTLHead, TrainingHistory]:
    """Train a BTL head on frozen descriptors with early stopping on a validation split of the anchors.

    Parameters
    ----------
    database_descriptors : array-like of shape (D, dim)
        Descriptors of the database images (positives and negatives are taken from them).
    positives : sparse or dense bool matrix of shape (Q, D)
        Positives of each query; with no ``query_descriptors``, shape (D, D): the positives of each database
        image among the others (its own entry is ignored).
    query_descriptors : array-like of shape (Q, dim), optional
        Descriptors of the anchors (training queries). Default: the database images are the anchors.
    config : BTLTrainingConfig, optional
        Training settings; ``**settings`` override single fields (``epochs=20``, ``device="cuda"``, ...).
    progress : bool, optional
        Show a progress bar over the epochs with the current losses (default: when stderr is a terminal).

    Returns
    -------
    head : BTLHead
        The head of the epoch with the lowest validation loss, in eval mode, on the training device.
    history : TrainingHistory
        The training curve; ``head.metadata`` holds the config and a summary.
    """
    config = replace(config or BTLTrainingConfig(), **settings)
    device = resolve_device(config.device)
    database = _as_descriptors(database_descriptors, "database descriptors")
    same_set = query_descriptors is None
    queries = database if same_set else _as_descriptors(query_descriptors, "query descriptors")
    what = "database × database" if same_set else "queries × database"
    positives = _checked_positives(queries, database, positives, "query", what)

    train_anchors, val_anchors = _split_anchors(positives, same_set, config.val_fraction, config.seed)
    mining = {"n_negatives": config.n_negatives, "max_positives": config.max_positives, "same_set": same_set}
    train_triplets = mine_triplets(queries, database, positives, anchors=train_anchors, **mining)
    val_triplets = mine_triplets(queries, database, positives, anchors=val_anchors, **mining)
    if len(train_triplets) == 0 or len(val_triplets) == 0:
        raise ValueError("no triplet could be mined (every anchor lacks a positive or a negative)")

    torch.manual_seed(config.seed)
    head = BTLHead(database.shape[1], config.embedding_dim, config.hidden_dim).to(device)
    config = replace(config, embedding_dim=head.embedding_dim)
    anchors_on_device = torch.from_numpy(queries).to(device)
    database_on_device = anchors_on_device if same_set else torch.from_numpy(database).to(device)
    loss = _TripletLoss(anchors_on_device, database_on_device, config)
    optimiser = torch.optim.AdamW(head.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    generator = torch.Generator().manual_seed(config.seed)

    history = TrainingHistory(
        n_train_anchors=train_triplets.n_anchors,
        n_val_anchors=val_triplets.n_anchors,
        n_train_triplets=len(train_triplets),
        n_val_triplets=len(val_triplets),
    )

    def record(epoch: int, train: tuple[float, float]) -> float:
        val = loss.evaluate(head, val_triplets)
        columns = ("epoch", "train_loss", "train_nll", "val_loss", "val_nll")
        for name, value in zip(columns, (epoch, *train, *val), strict=True):
            getattr(history, name).append(value)
        return val[0]

    best = record(0, loss.evaluate(head, train_triplets))
    best_state = copy.deepcopy(head.state_dict())
    waited = 0
    with progress_bar(range(1, config.epochs + 1), desc="train BTL head", unit="epoch", enabled=progress) as bar:
        for epoch in bar:
            head.train()
            total = nll = 0.0
            for rows in _batches(train_triplets, config.batch_size, generator):
                terms = loss(head, train_triplets, rows)
                if not torch.isfinite(terms.loss):
                    raise FloatingPointError(
                        f"the BTL loss became {float(terms.loss)} at epoch {epoch}; lower the learning rate "
                        "(argument learning_rate) or check the inputs"
                    )
                optimiser.zero_grad(set_to_none=True)
                terms.loss.backward()
                optimiser.step()
                total += float(terms.loss.detach()) * rows.size
                nll += float(terms.nll.detach()) * rows.size
            val_loss = record(epoch, (total / len(train_triplets), nll / len(train_triplets)))
            bar.set_postfix(train=f"{history.train_loss[-1]:.4f}", val=f"{val_loss:.4f}", best=history.best_epoch)
            if val_loss < best - config.min_delta:
                best, waited = val_loss, 0
                history.best_epoch = epoch
                best_state = copy.deepcopy(head.state_dict())
            else:
                waited += 1
                if waited >= config.patience:
                    history.stopped_early = epoch < config.epochs
                    break
    head.load_state_dict(best_state)
    head.eval()
    head.metadata = {
        "training": config.to_dict(),
        "history": history.summary(),
        "anchors": {
            "source": "database" if same_set else "queries",
            "count": len(queries),
            "digests": row_digests(queries),
            "sketches": row_sketches(queries).tolist(),
        },
    }
    return head, history


def save_training_curve(history: TrainingHistory, json_path: str | Path, png_path: str | Path | None = None) -> None:
    """Write the training curve as JSON (every epoch's losses) and, optionally, as a PNG plot."""
    write_json(json_path, history.to_dict())
    if png_path is None:
        return
    from matplotlib.figure import Figure  # no pyplot: no GUI backend, no global state

    figure = Figure(figsize=(6, 4), layout="constrained")
    axes = figure.add_subplot()
    axes.plot(history.epoch[1:], history.train_loss[1:], label="training (mean over the epoch)")
    axes.plot(history.epoch, history.val_loss, label="validation", marker=".")
    best = f"best epoch {history.best_epoch}"
    axes.axvline(history.best_epoch, color="grey", linestyle="--", linewidth=1, label=best)
    axes.set(xlabel="epoch", ylabel="Bayesian triplet loss", title="BTL head training")
    axes.legend()
    write_figure(figure, png_path, dpi=120)
