"""Issue 42, rows 14-15: a BTL head is matched to its training images by what survives re-extraction.

Real corridor images (30 queries, 30 references) through the offline model ``efficientnet-lite0-gem``, extracted
at their native size (a.h5, the head's training data) and again at ``image_size=96`` (b.h5, another
``--image-size``): the descriptors of the same images then lie far beyond the sketch tolerance, but the content
digests of the image files, recorded by the descriptor cache and by ``train-btl``, are the same.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("efficientnet_lite_pytorch")

from vpr_uncertainty.btl import train_btl_head  # noqa: E402
from vpr_uncertainty.btl.model import SKETCH_TOLERANCE, load_btl_head, row_sketches, save_btl_head  # noqa: E402
from vpr_uncertainty.cli import main  # noqa: E402
from vpr_uncertainty.data import positives_within_frames  # noqa: E402
from vpr_uncertainty.data.dataset import attach_ground_truth  # noqa: E402
from vpr_uncertainty.descriptors import extract_descriptors, load_model  # noqa: E402
from vpr_uncertainty.descriptors.images import Preprocessing  # noqa: E402
from vpr_uncertainty.evaluation import evaluate  # noqa: E402
from vpr_uncertainty.retrieval import retrieve, save_retrieval  # noqa: E402

pytestmark = pytest.mark.realdata

N = 30
QUICK = ["--embedding-dim", "32", "--hidden-dim", "16", "--epochs", "2", "--negatives", "3", "--no-progress"]


def _extract(model, queries: list[Path], database: list[Path], path: Path) -> dict:
    found: dict = {"h5": path}
    for split, paths in (("queries", queries), ("database", database)):
        found[f"{split}_names"], found[split] = extract_descriptors(model, paths, None, path, split, progress=False)
    positives = positives_within_frames(np.arange(len(queries)), np.arange(len(database)), tolerance=2)
    retrieval = attach_ground_truth(
        retrieve(found["database"], found["queries"], top_k=10),
        positives=positives,
        database_names=found["database_names"],
        query_names=found["queries_names"],
    )
    found["retrieval"] = retrieval
    found["npz"] = save_retrieval(retrieval, path.with_suffix(".npz"))
    found["paths"] = [str(p) for p in queries]
    return found


@pytest.fixture(scope="module")
def corridor(corridor_dir: Path, tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("leakage")
    torch.set_num_threads(1)
    queries = sorted((corridor_dir / "query").glob("*.jpg"))
    database = sorted((corridor_dir / "ref").glob("*.jpg"))[:N]
    native, small = (
        load_model("efficientnet-lite0-gem"),
        load_model("efficientnet-lite0-gem", preprocessing=Preprocessing(image_size=96)),
    )
    copied = folder / "copy"  # the training images copied elsewhere: other paths and times, the same contents
    copied.mkdir()
    for path in queries[:N]:
        shutil.copy(path, copied / path.name)
    data = {
        "a": _extract(native, queries[:N], database, folder / "a.h5"),
        "b": _extract(small, sorted(copied.iterdir()), database, folder / "b.h5"),
        "other": _extract(native, queries[N : 2 * N], database, folder / "other.h5"),
    }
    np.save(folder / "gt.npy", data["a"]["retrieval"].positives.toarray())
    head = folder / "head.pt"
    argv = ["train-btl", "--descriptors", str(data["a"]["h5"]), "--gt", str(folder / "gt.npy"), "--out", str(head)]
    assert main([*argv, *QUICK]) == 0
    data.update(head=head, folder=folder, database_paths=database)
    return data


def _options(corridor: dict, split: str = "b", head: object = None) -> dict:
    h5 = str(corridor[split]["h5"])
    return {"btl_head": head or corridor["head"], "query_descriptors": h5, "database_descriptors": h5}


def _btl_notes(evaluation) -> list[str]:
    return [note for note in evaluation.notes if note.startswith("BTL: ")]


def test_the_re_extracted_queries_lie_beyond_the_sketch_tolerance(corridor):
    """The premise of row 14: another --image-size moves every sketch far beyond the tolerance."""
    distances = np.linalg.norm(row_sketches(corridor["a"]["queries"]) - row_sketches(corridor["b"]["queries"]), axis=1)
    assert distances.min() > 20 * SKETCH_TOLERANCE
    anchors = load_btl_head(corridor["head"]).metadata["anchors"]
    assert anchors["names"] == list(corridor["a"]["queries_names"]) and len(anchors["contents"]) == N
    assert all(len(content) == 32 for content in anchors["contents"])  # the BLAKE2b digest of each image file


def test_row_14_queries_extracted_at_another_image_size_are_the_training_images(corridor, capsys):
    argv = ["evaluate", str(corridor["b"]["npz"]), "--methods", "BTL,SU", "--btl-head", str(corridor["head"])]
    argv += ["--descriptors", str(corridor["b"]["h5"])]
    assert main(argv) == 2
    assert f"was trained on {N} of these {N} queries" in capsys.readouterr().err
    assert main([*argv, "--allow-train-queries"]) == 0
    out = capsys.readouterr().out
    assert "BTL‡" in out and "BTL*" not in out and f"BTL was trained on {N} of these {N} queries" in out


def test_row_14_through_the_image_files_as_run_gives_them(corridor):
    """`run` hands BTL descriptor arrays and the query image paths, not the cache: the files are hashed."""
    b = corridor["b"]
    options = {"btl_head": corridor["head"], "query_descriptors": b["queries"], "database_descriptors": b["database"]}
    with pytest.raises(ValueError, match=f"was trained on {N} of these {N} queries"):
        evaluate(b["retrieval"], ["BTL", "SU"], **options, query_paths=b["paths"])
    evaluation = evaluate(b["retrieval"], ["BTL", "SU"], **options)  # no image files, no cache: says so
    assert evaluation.methods["BTL"].trained_on_queries == 0
    assert _btl_notes(evaluation) == [
        f"BTL: {corridor['head']} cannot be matched to these queries' image files (give the descriptor cache): "
        "checked by descriptors only, its training images extracted again would pass unseen"
    ]


@pytest.mark.parametrize("strip", ["deleted", "emptied"])
def test_row_15_a_head_that_does_not_say_what_it_was_trained_on_gets_a_notice(corridor, strip, capsys):
    state = torch.load(corridor["head"], weights_only=True)
    if strip == "deleted":
        del state["metadata"]["anchors"]
    else:
        state["metadata"]["anchors"] = {}
    stripped = corridor["folder"] / f"{strip}.pt"
    torch.save(state, stripped)
    evaluation = evaluate(corridor["a"]["retrieval"], ["BTL", "SU"], **_options(corridor, "a", stripped))
    assert _btl_notes(evaluation) == [
        f"BTL: {stripped} does not record its training images (metadata 'anchors'), so these queries may be among them"
    ]
    argv = ["evaluate", str(corridor["a"]["npz"]), "--methods", "BTL,SU", "--btl-head", str(stripped)]
    assert main([*argv, "--descriptors", str(corridor["a"]["h5"])]) == 0
    out = capsys.readouterr().out
    assert f"note: BTL: {stripped} does not record its training images" in out
    assert "BTL‡?" in out and "BTL*" not in out  # unverifiable: marked, and never best
    assert evaluation.methods["BTL"].never_best and not evaluation.methods["SU"].never_best


@pytest.mark.parametrize("field", ["digests", "sketches", "count"])
def test_a_head_with_part_of_its_anchors_removed_is_still_caught_or_noted(corridor, field):
    state = torch.load(corridor["head"], weights_only=True)
    state["metadata"]["anchors"][field] = [] if field != "count" else 3
    stripped = corridor["folder"] / f"no-{field}.pt"
    torch.save(state, stripped)
    with pytest.raises(ValueError, match=f"was trained on {N} of these {N} queries"):  # the contents still match
        evaluate(corridor["b"]["retrieval"], ["BTL"], **_options(corridor, "b", stripped))
    state["metadata"]["anchors"]["contents"] = []
    torch.save(state, stripped)
    evaluation = evaluate(corridor["b"]["retrieval"], ["BTL"], **_options(corridor, "b", stripped))
    assert len(_btl_notes(evaluation)) == 1  # nothing matches what survives re-extraction: unverified, not clean


def test_other_queries_are_neither_refused_nor_noted(corridor):
    """The control: the next 30 corridor queries (other files, other names) pass the check silently."""
    other = corridor["other"]
    evaluation = evaluate(other["retrieval"], ["BTL", "SU"], **_options(corridor, "other"))
    assert evaluation.methods["BTL"].trained_on_queries == 0 and _btl_notes(evaluation) == []


def test_same_names_with_other_contents_are_noted(corridor, tmp_path):
    """Re-encoded copies of the training images under their names: other contents, other descriptors: a notice."""
    from PIL import Image

    for path in corridor["a"]["paths"]:
        Image.open(path).save(tmp_path / Path(path).name, quality=60)
    native = load_model("efficientnet-lite0-gem")
    copies = _extract(native, sorted(tmp_path.glob("*.jpg")), corridor["database_paths"], tmp_path / "re.h5")
    distances = np.linalg.norm(row_sketches(corridor["a"]["queries"]) - row_sketches(copies["queries"]), axis=1)
    assert distances.min() > SKETCH_TOLERANCE
    h5 = str(copies["h5"])
    options = {"btl_head": corridor["head"], "query_descriptors": h5, "database_descriptors": h5}
    evaluation = evaluate(copies["retrieval"], ["BTL"], **options)
    assert _btl_notes(evaluation) == [
        f"BTL: {corridor['head']} was trained on other files of the names of {N} of these queries: the same images "
        "re-encoded?"
    ]


def test_a_head_trained_from_arrays_says_it_is_checked_by_descriptors_only(corridor):
    a = corridor["a"]
    head, _ = train_btl_head(
        a["database"], a["retrieval"].positives, query_descriptors=a["queries"], epochs=1, progress=False
    )
    path = save_btl_head(head, corridor["folder"] / "arrays.pt", metadata=head.metadata)
    evaluation = evaluate(corridor["b"]["retrieval"], ["BTL"], **_options(corridor, "b", path))
    assert _btl_notes(evaluation) == [
        f"BTL: {path} records no image contents (train it from a .h5): checked by descriptors only, its training "
        "images extracted again would pass unseen"
    ]


@pytest.mark.parametrize("keys", ["abc", ["x"] * 3])
def test_query_keys_that_are_not_one_per_query_are_refused(corridor, keys):
    with pytest.raises(ValueError, match=f"query_keys must hold one content key per query \\({N}\\)"):
        evaluate(corridor["b"]["retrieval"], ["BTL"], **_options(corridor), query_keys=keys)
