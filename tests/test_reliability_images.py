"""Issue 10, item 4: every image that cannot be used is skipped and counted (``skip``) or named (``fail``).

Each case is generated in ``tmp_path`` with PIL: a PNG whose header claims 100000 x 100000 pixels, a 10 x 10
image, a truncated JPEG, a zero-byte file, a file name that is not valid UTF-8, an unreadable sub-folder, a
broken symbolic link and a symbolic link loop. Plus the working-resolution cap: a 9000 x 9000 image reaches the
model at most ``max_side`` pixels wide.
"""

from __future__ import annotations

import json
import os
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
Image = pytest.importorskip("PIL.Image")

from vpr_uncertainty.data import images as listing_module  # noqa: E402
from vpr_uncertainty.data.images import ImageListingError, list_images, load_folder_dataset  # noqa: E402
from vpr_uncertainty.descriptors import (  # noqa: E402
    ImageDecodeError,
    Preprocessing,
    cache_info,
    extract_descriptors,
    load_image,
)
from vpr_uncertainty.descriptors.images import DEFAULT_MAX_SIDE, DEFAULT_MIN_SIDE, read_image_size  # noqa: E402
from vpr_uncertainty.descriptors.models import from_callable, get_model_spec  # noqa: E402

NOT_UTF8 = os.fsdecode(b"caf\xe9.png")  # Latin-1 bytes: Python's name for it holds a surrogate escape


class ShapeModel:
    """Mean of each channel (D = 3); records the shape of every batch it sees."""

    def __init__(self) -> None:
        self.shapes: list[tuple[int, ...]] = []

    def __call__(self, images: torch.Tensor) -> torch.Tensor:
        self.shapes.append(tuple(images.shape))
        return images.mean(dim=(2, 3))


def model(**preprocessing: object) -> tuple[ShapeModel, object]:
    network = ShapeModel()
    options = {"min_side": DEFAULT_MIN_SIDE, **preprocessing}
    # it records every batch's shape: a fixed key, or the cache would see a new model each time
    return network, from_callable(network, name="shape", preprocessing=Preprocessing(**options), weights_id="v1")


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def write_bomb(path: Path, side: int = 100_000) -> Path:
    """A 60-byte PNG whose header claims ``side`` x ``side`` RGB pixels (30 GB decoded)."""
    header = struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0)
    data = _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(b"\0" * 16)) + _chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + data)
    return path


def write_image(path: Path | bytes, size: tuple[int, int] = (48, 40), seed: int = 0) -> Path | bytes:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    rng = np.random.default_rng(seed)
    image = Image.fromarray(rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8))
    with open(path, "wb") as handle:
        image.save(handle, format="PNG" if str(os.fsdecode(path)).endswith(".png") else "JPEG")
    return path


def bad_files(folder: Path) -> dict[str, str]:
    """Write every kind of unusable image into ``folder``; returns file name -> expected reason (regex)."""
    folder.mkdir(parents=True, exist_ok=True)
    write_bomb(folder / "bomb.png")
    write_image(folder / "tiny.png", (10, 10))
    write_image(folder / "full.jpg", (64, 64))
    (folder / "truncated.jpg").write_bytes((folder / "full.jpg").read_bytes()[:300])
    (folder / "full.jpg").unlink()
    (folder / "zero.jpg").write_bytes(b"")
    write_image(os.fsencode(folder) + b"/caf\xe9.png")
    os.symlink("nowhere.jpg", folder / "dangling.jpg")
    os.symlink("loop.jpg", folder / "loop.jpg")
    return {
        "bomb.png": r"10,000,000,000 pixels, more than the limit .*decompression bomb",
        "tiny.png": r"10 x 10 pixels: the model needs at least 32 pixels",
        "truncated.jpg": r"cannot decode it",
        "zero.jpg": r"empty file \(0 bytes\)",
        NOT_UTF8: r"not valid UTF-8",
        "dangling.jpg": r"broken symbolic link to 'nowhere\.jpg'",
        "loop.jpg": r"symbolic link to 'loop\.jpg' that loops back on itself",
    }


CASES = ["bomb.png", "tiny.png", "truncated.jpg", "zero.jpg", NOT_UTF8, "dangling.jpg", "loop.jpg"]


@pytest.mark.parametrize("bad", CASES, ids=["bomb", "10x10", "truncated", "zero-byte", "not-utf8", "dangling", "loop"])
def test_fail_names_the_image_and_skip_counts_it(tmp_path, bad):
    reasons = bad_files(tmp_path / "bad")
    good = [write_image(tmp_path / f"good{i}.png", seed=i) for i in range(3)]
    paths = [good[0], tmp_path / "bad" / bad, *good[1:]]
    names = ["good0.png", bad, "good1.png", "good2.png"]
    shown = bad.replace(NOT_UTF8, "caf\\xe9.png")
    with pytest.raises(ImageDecodeError, match=rf"cannot use image '{re.escape(shown)}'.*{reasons[bad]}"):
        extract_descriptors(model()[1], paths, names, tmp_path / "fail.h5", "queries", progress=False)
    cache = tmp_path / "skip.h5"
    with pytest.warns(UserWarning, match=r"left out 1 of 4 'queries' images that cannot be used") as caught:
        kept, descriptors = extract_descriptors(
            model()[1], paths, names, cache, "queries", on_error="skip", progress=False
        )
    assert str(caught[0].message).encode("utf-8")  # printable: no surrogate escapes left in the message
    assert list(kept) == ["good0.png", "good1.png", "good2.png"] and descriptors.shape == (3, 3)
    [failed] = cache_info(cache)["queries"]["failed"]
    assert failed["name"] == bad
    assert re.search(reasons[bad], failed["error"])


def test_a_summary_names_the_first_few_and_counts_all(tmp_path):
    reasons = bad_files(tmp_path / "bad")
    paths = [tmp_path / "bad" / name for name in reasons] + [write_image(tmp_path / "good.png")]
    with pytest.warns(UserWarning) as caught:
        kept, _ = extract_descriptors(model()[1], paths, None, tmp_path / "d.h5", on_error="skip", progress=False)
    messages = [str(w.message) for w in caught if "left out" in str(w.message)]
    assert len(messages) == 1  # one line, not one per image
    assert messages[0].startswith("left out 7 of 8 'database' images that cannot be used: 'bomb.png' (")
    assert "; and 4 more; all of them are listed in" in messages[0]
    assert list(kept) == ["good.png"] and len(cache_info(tmp_path / "d.h5")["database"]["failed"]) == 7


def test_the_default_model_skips_tiny_images_instead_of_crashing(tmp_path):
    """Regression: a 10 x 10 image made EfficientNet-Lite0 raise a RuntimeError (kernel larger than input)."""
    pytest.importorskip("efficientnet_lite_pytorch")
    from vpr_uncertainty.descriptors import load_model

    assert get_model_spec("efficientnet-lite0-gem").preprocessing.min_side == DEFAULT_MIN_SIDE
    effnet = load_model("efficientnet-lite0-gem")
    paths = [write_image(tmp_path / "tiny.png", (10, 10)), write_image(tmp_path / "ok.png", (32, 32))]
    with pytest.warns(UserWarning, match=r"'tiny\.png' \(10 x 10 pixels: the model needs at least 32"):
        kept, descriptors = extract_descriptors(effnet, paths, None, on_error="skip", progress=False)
    assert list(kept) == ["ok.png"] and descriptors.shape == (1, 1280)


def test_a_decompression_bomb_is_refused_from_its_header(tmp_path):
    path = write_bomb(tmp_path / "bomb.png", side=20_000)  # 400 MP: between PIL's warning and its error
    with pytest.raises(ImageDecodeError, match=r"400,000,000 pixels, more than the limit of 89,478,485"):
        load_image(path, Preprocessing())
    with pytest.raises(ImageDecodeError, match=r"more than the limit"):
        read_image_size(path)


# -- listing -------------------------------------------------------------------------------------------------


def _unreadable(folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Make ``folder`` unreadable: chmod 000, or, as root (where chmod stops nothing), a failing os.scandir."""
    folder.chmod(0)
    if not os.access(folder, os.R_OK):
        return
    real_scandir = os.scandir

    def scandir(path):
        if Path(path) == folder:
            raise PermissionError(13, "Permission denied", str(path))
        return real_scandir(path)

    monkeypatch.setattr(listing_module.os, "scandir", scandir)


def test_listing_keeps_broken_links_and_odd_names_and_reports_unreadable_folders(tmp_path, monkeypatch):
    """Regression: rglob + is_file() silently dropped broken links, loops and the images of unreadable folders."""
    root = tmp_path / "images"
    reasons = bad_files(root)
    write_image(root / "sub" / "deep.png")
    write_image(root / "locked" / "hidden.png")
    os.symlink("..", root / "sub" / "up")  # a folder loop: followed once, never forever
    os.symlink("/nonexistent/folder", root / "lost")  # broken link that may have been a folder
    _unreadable(root / "locked", monkeypatch)
    try:
        problems: list[dict[str, str]] = []
        paths = list_images(root, problems=problems)
        names = sorted(path.relative_to(root).as_posix() for path in paths)
        assert names == sorted([*reasons, "sub/deep.png"])
        assert [Path(item["path"]).name for item in problems] == ["locked", "lost"]
        assert "cannot read the folder: Permission denied" in problems[0]["error"]
        with pytest.raises(ImageListingError, match=r"cannot list every image under .*locked \(cannot read"):
            list_images(root)
    finally:
        (root / "locked").chmod(0o755)


def _folder_dataset(root: Path) -> Path:
    for i in range(4):
        write_image(root / "database" / f"@{100 * i}@0@@@@@@@@@@@@@@.png", seed=i)
    for i in range(3):
        write_image(root / "queries" / f"@{100 * i + 1}@0@@@@@@@@@@@@@@.png", seed=10 + i)
    write_image(root / "queries" / "locked" / "@301@0@@@@@@@@@@@@@@.png")
    write_bomb(root / "queries" / "@5@0@@@@@@@@@@@@@@.png")
    os.symlink("gone.png", root / "queries" / "@15@0@@@@@@@@@@@@@@.png")
    return root


@pytest.mark.filterwarnings("ignore:AUC-PR and AP are undefined")
def test_run_skip_reports_every_image_left_out_and_fail_names_it(tmp_path, monkeypatch):
    """Regression: an unreadable sub-folder silently dropped its queries and `run` exited 0 under fail."""
    from vpr_uncertainty import descriptors
    from vpr_uncertainty.pipeline.evaluate import EvaluateConf
    from vpr_uncertainty.pipeline.extract import ExtractConf
    from vpr_uncertainty.pipeline.run import RunConf, run

    root = _folder_dataset(tmp_path / "dataset")
    _unreadable(root / "queries" / "locked", monkeypatch)
    monkeypatch.setattr(descriptors, "load_model", lambda name, device: model()[1])
    try:
        dataset = load_folder_dataset(root)
        assert dataset.n_queries == 5 and [Path(item["path"]).name for item in dataset.unlisted] == ["locked"]
        with pytest.raises(ImageListingError, match=r"locked \(cannot read the folder"):
            run(RunConf(evaluate=EvaluateConf(methods=["SU"], k=2)), root, tmp_path / "fail")
        with pytest.warns(UserWarning) as caught:
            run(
                RunConf(extract=ExtractConf(on_error="skip"), evaluate=EvaluateConf(methods=["SU"], k=2)),
                root,
                tmp_path / "run",
            )
    finally:
        (root / "queries" / "locked").chmod(0o755)
    messages = " | ".join(str(w.message) for w in caught)
    assert "left out the images under 1 path(s)" in messages and "locked (cannot read the folder" in messages
    assert "left out 2 of 5 'queries' images that cannot be used" in messages
    results = json.loads((tmp_path / "run" / "results.json").read_text())
    left_out = results["dataset"]["images_left_out"]
    assert left_out["count"] == 2 and left_out["database"] == []
    names = [entry["name"] for entry in left_out["queries"]]
    assert names == ["queries/@15@0@@@@@@@@@@@@@@.png", "queries/@5@0@@@@@@@@@@@@@@.png"]
    assert "broken symbolic link" in left_out["queries"][0]["error"]
    assert "decompression bombs" in left_out["queries"][1]["error"]
    assert results["dataset"]["unlisted"][0]["path"].endswith("locked")
    assert results["n_queries"] == 3


# -- bounded working resolution ------------------------------------------------------------------------------


def test_a_9000_pixel_image_reaches_the_model_at_the_cap(tmp_path):
    """Regression: a 9000 x 9000 PNG went to the model at full size (> 8 GB); now at most max_side pixels."""
    path = tmp_path / "huge.png"
    Image.new("L", (9000, 6000), 128).save(path)
    network, capped = model()
    assert capped.preprocessing.max_side == DEFAULT_MAX_SIDE == 640
    extract_descriptors(capped, [path], None, progress=False)
    assert network.shapes == [(1, 3, 427, 640)]  # aspect ratio kept
    network, smaller = model(max_side=256)
    extract_descriptors(smaller, [path], None, progress=False)
    assert network.shapes == [(1, 3, 171, 256)]


def test_a_large_jpeg_is_decoded_at_reduced_size_close_to_a_full_decode(tmp_path):
    path = tmp_path / "photo.jpg"
    x, y = np.meshgrid(np.linspace(0, 1, 4000), np.linspace(0, 1, 3000))
    smooth = (np.stack([x, y, x * y], axis=2) * 255).astype(np.uint8)
    Image.fromarray(smooth).save(path, quality=95)
    reduced = load_image(path, Preprocessing())
    assert reduced.shape == (480, 640, 3)
    with Image.open(path) as image:  # reference: full decode, then the same resize
        full = np.asarray(image.convert("RGB").resize((640, 480), Image.Resampling.BILINEAR))
    assert np.abs(reduced.astype(int) - full.astype(int)).mean() < 1.0


def test_normal_images_are_processed_exactly_as_before(tmp_path):
    """The corridor's 160 x 120 images (and anything under the cap) are neither drafted nor resized."""
    path = write_image(tmp_path / "corridor.jpg", (160, 120))
    with Image.open(path) as image:
        reference = np.asarray(image.convert("RGB"))
    np.testing.assert_array_equal(load_image(path, Preprocessing()), reference)
    np.testing.assert_array_equal(load_image(path, Preprocessing(max_side=None)), reference)


def test_preprocessing_cap_validation_and_fingerprint():
    assert Preprocessing().to_dict()["max_side"] == 640  # a changed cap invalidates descriptor caches
    assert Preprocessing(multiple_of=14).output_size(4000, 3000) == (630, 476)  # multiples of 14 below the cap
    assert Preprocessing(image_size=224).output_size(4000, 400) == (640, 64)  # a panorama: longer side capped
    assert Preprocessing(image_size=(320, 320)).output_size(4000, 3000) == (320, 320)
    assert Preprocessing(max_side=None).output_size(9000, 9000) == (9000, 9000)
    with pytest.raises(ValueError, match=r"image_size 800 exceeds max_side 640; raise max_side"):
        Preprocessing(image_size=800)
    with pytest.raises(ValueError, match=r"max_side must be an integer >= 32"):
        Preprocessing(max_side=16, min_side=32)


# -- geometric verification and the extract command ----------------------------------------------------------


def test_geometric_loader_refuses_bombs_and_reads_any_file_name(tmp_path):
    """Regression: OpenCV raised cv2.error on the bomb header and crashed (SIGSEGV) on a non-UTF-8 path."""
    pytest.importorskip("cv2")
    from vpr_uncertainty.geometric.local_features import load_image as load_local

    with pytest.raises(ValueError, match=r"cannot read image .*bomb\.png: 10,000,000,000 pixels, more than"):
        load_local(write_bomb(tmp_path / "bomb.png"), max_side=640, grayscale=True)
    os.symlink("nowhere.jpg", tmp_path / "dangling.jpg")
    with pytest.raises(ValueError, match=r"dangling\.jpg: broken symbolic link to 'nowhere\.jpg'"):
        load_local(tmp_path / "dangling.jpg", max_side=640, grayscale=True)
    odd = os.fsencode(tmp_path) + b"/caf\xe9.png"
    write_image(odd, (64, 48))
    image, size = load_local(Path(os.fsdecode(odd)), max_side=32, grayscale=False)
    assert size == (64, 48) and image.shape == (24, 32, 3)


def test_extract_command_skips_and_reports_or_fails_naming_the_image(tmp_path, monkeypatch, capsys):
    from vpr_uncertainty import cli
    from vpr_uncertainty.descriptors import models

    root = tmp_path / "dataset"
    for split in ("database", "queries"):
        for i in range(2):
            write_image(root / split / f"{i}.png", seed=i)
    reasons = bad_files(root / "queries" / "bad")
    monkeypatch.setattr(models, "load_model", lambda name, device: model()[1])
    out = tmp_path / "d.h5"
    common = ["extract", "--dataset", str(root), "--out", str(out), "--no-progress"]
    assert cli.main(common) != 0
    assert "cannot use image 'queries/bad/" in capsys.readouterr().err
    with pytest.warns(UserWarning, match=r"left out 7 of 9 'queries' images that cannot be used"):
        assert cli.main([*common, "--on-error", "skip"]) == 0
    assert "queries: 2 descriptors of size 3, 7 skipped" in capsys.readouterr().out
    assert len(cache_info(out)["queries"]["failed"]) == len(reasons)
