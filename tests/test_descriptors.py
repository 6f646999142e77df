"""Extraction and HDF5 cache: resuming, invalidation, decode errors, user models, the extract command.

These tests use small synthetic images and cheap models so that they run in seconds; the real corridor
images with the offline default model are in test_features_corridor.py.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import assert_close

torch = pytest.importorskip("torch")
Image = pytest.importorskip("PIL.Image")

from vpr_uncertainty.descriptors import (  # noqa: E402
    ImageDecodeError,
    Preprocessing,
    cache_info,
    extract_descriptors,
    load_model,
    read_descriptors,
)
from vpr_uncertainty.descriptors.models import from_callable  # noqa: E402
from vpr_uncertainty.pipeline import extract as extract_command  # noqa: E402


class CountingModel:
    """Mean and standard deviation of each channel (D = 6); counts forward calls; can fail after N calls."""

    def __init__(self, fail_after: int | None = None) -> None:
        self.calls = 0
        self.images = 0
        self.fail_after = fail_after

    def __call__(self, images: torch.Tensor) -> torch.Tensor:
        if self.fail_after is not None and self.calls >= self.fail_after:
            raise RuntimeError("simulated interruption")
        self.calls += 1
        self.images += images.shape[0]
        return torch.cat([images.mean(dim=(2, 3)), images.std(dim=(2, 3))], dim=1)


def counting(fail_after: int | None = None, **preprocessing: object) -> tuple[CountingModel, object]:
    network = CountingModel(fail_after)
    # its call counters change with every batch: a fixed key, or the cache would see a new model each time
    model = from_callable(network, name="counting", preprocessing=Preprocessing(**preprocessing), weights_id="v1")
    return network, model


@pytest.fixture
def images(tmp_path: Path) -> tuple[list[Path], list[str]]:
    """Ten small random RGB images."""
    rng = np.random.default_rng(0)
    folder = tmp_path / "images"
    folder.mkdir()
    paths = []
    for i in range(10):
        path = folder / f"img{i:02d}.png"
        Image.fromarray(rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)).save(path)
        paths.append(path)
    return paths, [path.name for path in paths]


def test_extract_in_memory_matches_cache(images, tmp_path):
    paths, names = images
    _network, model = counting()
    names_mem, descriptors_mem = extract_descriptors(model, paths, names, batch_size=4, progress=False)
    names_h5, descriptors_h5 = extract_descriptors(
        model, paths, names, tmp_path / "d.h5", "queries", batch_size=4, progress=False
    )
    assert list(names_mem) == names == list(names_h5)
    assert descriptors_mem.shape == (10, 6) and descriptors_mem.dtype == np.float32
    assert_close(descriptors_mem, descriptors_h5, atol=1e-6)
    assert_close(np.linalg.norm(descriptors_h5, axis=1), 1.0)
    read_names, read = read_descriptors(tmp_path / "d.h5", "queries")
    assert read_names.dtype.kind == "U" and list(read_names) == names
    np.testing.assert_array_equal(read, descriptors_h5)  # the stored array read back


def test_layout_contract(images, tmp_path):
    paths, names = images
    _, model = counting()
    path = tmp_path / "d.h5"
    extract_descriptors(model, paths[:4], names[:4], path, "database", batch_size=3, progress=False)
    extract_descriptors(model, paths[4:], names[4:], path, "queries", batch_size=3, progress=False)
    with h5py.File(path, "r") as handle:
        assert set(handle) == {"database", "queries"}
        assert handle["database/descriptors"].shape == (4, 6)
        assert handle["queries/descriptors"].shape == (6, 6)
        assert handle["database/descriptors"].dtype == np.float32
        assert list(handle["database/names"].asstr()[:]) == names[:4]
        assert h5py.check_string_dtype(handle["queries/names"].dtype).encoding == "utf-8"
        fingerprint = json.loads(handle.attrs["config"])
    assert fingerprint["model"] == "counting" and fingerprint["preprocessing"]["image_size"] is None
    info = cache_info(path)
    assert info["database"]["complete"] and info["queries"]["count"] == 6


def test_resume_after_interruption_does_not_recompute(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    network, model = counting(fail_after=2)
    with pytest.raises(RuntimeError, match="simulated interruption"):
        extract_descriptors(model, paths, names, path, "database", batch_size=3, workers=0, progress=False)
    assert network.images == 6  # two batches written before the failure
    with pytest.warns(UserWarning, match="incomplete"):
        partial_names, _ = read_descriptors(path, "database")
    assert list(partial_names) == names[:6]
    assert not cache_info(path)["database"]["complete"]

    network, model = counting()
    done, descriptors = extract_descriptors(model, paths, names, path, "database", batch_size=3, progress=False)
    assert (network.calls, network.images) == (2, 4)  # only the 4 missing images, in batches of 3 and 1
    assert list(done) == names
    _, expected = extract_descriptors(counting()[1], paths, names, progress=False)
    assert_close(descriptors, expected, atol=1e-6)  # other batch sizes


def test_resume_after_callback_interruption(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    seen: list[list[str]] = []

    def stop_after_first(batch_names: list[str]) -> None:
        seen.append(batch_names)
        raise KeyboardInterrupt

    _, model = counting()
    with pytest.raises(KeyboardInterrupt):
        extract_descriptors(model, paths, names, path, "queries", batch_size=4, on_batch=stop_after_first)
    assert seen == [names[:4]]
    network, model = counting()
    extract_descriptors(model, paths, names, path, "queries", batch_size=4, progress=False)
    assert network.images == 6


@pytest.mark.skipif(os.name != "posix", reason="needs SIGKILL")
def test_killed_process_loses_at_most_the_batch_in_flight(images, tmp_path):
    """SIGKILL in the middle of an extraction leaves a readable file that a rerun completes."""
    paths, names = images
    path = tmp_path / "d.h5"
    script = textwrap.dedent(
        f"""
        import os, signal, torch
        from vpr_uncertainty.descriptors import Preprocessing, extract_descriptors
        from vpr_uncertainty.descriptors.models import from_callable
        class CountingModel:  # same identity as the test's CountingModel, so the rerun resumes
            def __call__(self, images):
                return torch.cat([images.mean(dim=(2, 3)), images.std(dim=(2, 3))], dim=1)
        CountingModel.__module__, CountingModel.__qualname__ = {CountingModel.__module__!r}, "CountingModel"
        model = from_callable(CountingModel(), name="counting", preprocessing=Preprocessing(), weights_id="v1")
        batches = []
        def kill_after_third(names):
            batches.append(names)
            if len(batches) == 3:
                os.kill(os.getpid(), signal.SIGKILL)
        paths = {[str(p) for p in paths]!r}
        extract_descriptors(model, paths, None, {str(path)!r}, "database", batch_size=2,
                            progress=False, on_batch=kill_after_third)
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == -9, result.stderr
    with pytest.warns(UserWarning, match="incomplete"):
        written, _ = read_descriptors(path, "database")
    assert list(written) == names[:6]
    network, model = counting()
    done, _ = extract_descriptors(model, paths, names, path, "database", batch_size=2, progress=False)
    assert list(done) == names and network.images == 4


def test_unchanged_cache_is_reused(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    extract_descriptors(counting()[1], paths, names, path, "database", progress=False)
    network, model = counting()
    extract_descriptors(model, paths, names, path, "database", progress=False)
    assert network.calls == 0


def test_changed_preprocessing_invalidates_cache(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    _, model = counting()
    _, before = extract_descriptors(model, paths, names, path, "database", progress=False)
    extract_descriptors(model, paths[:2], names[:2], path, "queries", progress=False)
    network, resized = counting(image_size=8)
    with pytest.warns(UserWarning, match=r"another model or preprocessing \(changed: preprocessing\)"):
        _, after = extract_descriptors(resized, paths, names, path, "database", progress=False)
    assert network.images == 10
    assert not np.allclose(before, after)
    assert json.loads(h5py.File(path, "r").attrs["config"])["preprocessing"]["image_size"] == 8
    assert "queries" not in h5py.File(path, "r")  # stale descriptors of the other split are gone too


def test_changed_model_invalidates_cache(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    extract_descriptors(counting()[1], paths, names, path, "database", progress=False)
    other = from_callable(lambda x: x.amax(dim=(2, 3)), name="max", weights_id="max-v1")
    with pytest.warns(UserWarning, match=r"changed: model, weights"):
        extract_descriptors(other, paths, names, path, "database", progress=False)
    assert cache_info(path)["model"] == "max"


def test_half_storage(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    _, full = extract_descriptors(counting()[1], paths, names, progress=False)
    _, half = extract_descriptors(counting()[1], paths, names, path, "database", half=True, progress=False)
    assert half.dtype == np.float32
    assert h5py.File(path, "r")["database/descriptors"].dtype == np.float16
    assert_close(half, full, rtol=1e-3, atol=2e-3)  # float16 storage of unit-norm rows
    network, model = counting()
    with pytest.warns(UserWarning, match="changed: dtype"):
        extract_descriptors(model, paths, names, path, "database", progress=False)
    assert network.images == 10


def corrupt_files(folder: Path) -> list[Path]:
    garbage = folder / "garbage.jpg"
    garbage.write_bytes(b"this is not an image")
    buffer = folder / "full.jpg"
    Image.fromarray(np.full((64, 64, 3), 120, np.uint8)).save(buffer, quality=95)
    truncated = folder / "truncated.jpg"
    truncated.write_bytes(buffer.read_bytes()[:200])
    return [garbage, truncated]


def test_corrupt_image_fails_with_its_name(images, tmp_path):
    paths, _names = images
    garbage, truncated = corrupt_files(tmp_path)
    path = tmp_path / "d.h5"
    all_paths = [*paths[:4], garbage, *paths[4:]]
    with pytest.raises(ImageDecodeError, match=r"cannot use image 'garbage\.jpg'.*not a recognised image"):
        extract_descriptors(counting()[1], all_paths, None, path, "database", batch_size=4, progress=False)
    assert cache_info(path)["database"]["count"] == 4  # the batch before the bad image was kept
    with pytest.raises(ImageDecodeError, match=r"truncated\.jpg"):
        extract_descriptors(counting()[1], [truncated], None, progress=False)
    with pytest.raises(ImageDecodeError, match=r"'missing\.jpg'.*file not found"):
        extract_descriptors(counting()[1], [tmp_path / "missing.jpg"], None, progress=False)


def test_corrupt_image_skipped_on_request(images, tmp_path):
    paths, names = images
    garbage, truncated = corrupt_files(tmp_path)
    path = tmp_path / "d.h5"
    all_paths = [garbage, *paths, truncated]
    with pytest.warns(UserWarning, match=r"left out 2 of 12 'database' images that cannot be used: 'garbage\.jpg'"):
        kept, descriptors = extract_descriptors(
            counting()[1], all_paths, None, path, "database", batch_size=4, on_error="skip", progress=False
        )
    assert list(kept) == names and descriptors.shape == (10, 6)
    failed = cache_info(path)["database"]["failed"]
    assert [entry["name"] for entry in failed] == ["garbage.jpg", "truncated.jpg"]
    assert list(read_descriptors(path, "database")[0]) == names


def test_rows_follow_the_requested_order(images, tmp_path):
    paths, names = images
    path = tmp_path / "d.h5"
    extract_descriptors(counting()[1], paths, names, path, "database", progress=False)
    order = [7, 2, 5]
    network, model = counting()
    kept, descriptors = extract_descriptors(
        model, [paths[i] for i in order], [names[i] for i in order], path, "database", progress=False
    )
    assert network.calls == 0 and list(kept) == [names[i] for i in order]
    assert list(read_descriptors(path, "database")[0]) == [names[i] for i in order]
    _picked_names, picked = read_descriptors(path, "database", names=[names[5], names[7]])
    np.testing.assert_array_equal(picked, descriptors[[2, 0]])
    with pytest.raises(KeyError, match=r"no 'database' descriptors for 1 image\(s\): img00\.png"):
        read_descriptors(path, "database", names=["img00.png"])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"names": ["a", "a"]}, "image names must be unique, repeated: a"),
        ({"names": ["a"]}, "got 2 image paths but 1 names"),
        ({"split": "train"}, "split must be one of"),
        ({"batch_size": 0}, "batch_size must be a positive integer"),
        ({"on_error": "ignore"}, "on_error must be one of"),
    ],
)
def test_invalid_arguments(images, kwargs, message):
    paths, _ = images
    with pytest.raises(ValueError, match=message):
        extract_descriptors(counting()[1], paths[:2], **{"names": None, **kwargs})


def test_duplicate_file_names_need_names(tmp_path, images):
    paths, _ = images
    (tmp_path / "other").mkdir()
    copy = tmp_path / "other" / paths[0].name
    copy.write_bytes(paths[0].read_bytes())
    with pytest.raises(ValueError, match="pass names="):
        extract_descriptors(counting()[1], [paths[0], copy], progress=False)


def test_read_descriptors_errors(tmp_path, images):
    with pytest.raises(FileNotFoundError):
        read_descriptors(tmp_path / "none.h5", "database")
    with pytest.raises(ValueError, match="split must be one of"):
        read_descriptors(tmp_path / "none.h5", "db")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as handle:
        handle["x"] = np.zeros(3)
    with pytest.raises(ValueError, match="not a vpr-uncertainty descriptor file"):
        read_descriptors(other, "database")
    paths, names = images
    with pytest.raises(ValueError, match="not a vpr-uncertainty descriptor file; choose another path"):
        extract_descriptors(counting()[1], paths, names, other, "database", progress=False)
    text = tmp_path / "notes.h5"
    text.write_text("hello")
    with pytest.raises(ValueError, match="not an HDF5 file"):
        extract_descriptors(counting()[1], paths, names, text, "database", progress=False)
    path = tmp_path / "d.h5"
    extract_descriptors(counting()[1], paths, names, path, "database", progress=False)
    with pytest.raises(KeyError, match="holds no 'queries' descriptors"):
        read_descriptors(path, "queries")


def test_torchscript_model(images, tmp_path):
    class Pool(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.proj = torch.nn.Linear(3, 4)

        def forward(self, images: torch.Tensor) -> torch.Tensor:
            return self.proj(images.mean(dim=(2, 3)))

    torch.manual_seed(0)
    file = tmp_path / "pool.pt"
    torch.jit.script(Pool()).save(str(file))
    model = load_model(file, preprocessing=Preprocessing(image_size=8))
    assert model.name == "pool" and model.weights_id.startswith("torchscript-sha256:")
    paths, names = images
    _kept, descriptors = extract_descriptors(model, paths, names, progress=False)
    assert descriptors.shape == (10, 4)
    assert_close(np.linalg.norm(descriptors, axis=1), 1.0)
    not_script = tmp_path / "plain.pt"
    torch.save({"a": 1}, not_script)
    with pytest.raises(ValueError, match="not a TorchScript file"):
        load_model(not_script)
    with pytest.raises(FileNotFoundError):
        load_model(tmp_path / "absent.pt")


def test_module_model_identity_follows_weights():
    first = torch.nn.Linear(3, 2)
    second = torch.nn.Linear(3, 2)
    assert load_model(first).weights_id != load_model(second).weights_id
    assert load_model(first).weights_id == load_model(first).weights_id


def test_model_errors():
    with pytest.raises(KeyError, match="unknown model 'nope'; available: efficientnet-lite0-gem"):
        load_model("nope")
    with pytest.raises(TypeError):
        load_model(42)
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="CUDA is not available"):
            load_model(lambda x: x.mean(dim=(2, 3)), device="cuda")


def test_wrong_descriptor_size_is_reported(images):
    paths, names = images
    model = from_callable(lambda x: x.mean(dim=(2, 3)), name="three", weights_id="v1")
    model.descriptor_dim = 5
    with pytest.raises(ValueError, match="returned descriptors of size 3, expected 5"):
        extract_descriptors(model, paths, names, progress=False)


def test_preprocessing_validation_and_sizes():
    assert Preprocessing(image_size=(20, 30)).output_size(100, 50) == (30, 20)
    assert Preprocessing(image_size=10, multiple_of=14).output_size(100, 50) == (14, 14)
    assert Preprocessing(multiple_of=14).output_size(100, 50) == (98, 56)
    with pytest.raises(ValueError, match="image_size"):
        Preprocessing(image_size=0)
    with pytest.raises(ValueError, match="std must be positive"):
        Preprocessing(std=(1, 0, 1))
    with pytest.raises(ValueError, match="interpolation"):
        Preprocessing(interpolation="lanczos5")


def test_package_import_does_not_import_torch():
    code = (
        "import sys, vpr_uncertainty.descriptors, vpr_uncertainty.pipeline.extract\n"
        "vpr_uncertainty.descriptors.available_models()\n"
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_missing_torch_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(ImportError, match=r"pip install 'vpr-uncertainty\[torch\]'"):
        load_model("efficientnet-lite0-gem")


def make_dataset(root: Path, database: str, queries: str, images: list[Path]) -> None:
    for folder, chosen in ((database, images[:6]), (queries, images[6:])):
        (root / folder).mkdir(parents=True)
        for path in chosen:
            (root / folder / path.name).write_bytes(path.read_bytes())


def run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="vpr-uncertainty")
    extract_command.add_cli(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.handler(args)


def test_extract_command(images, tmp_path, capsys):
    paths, names = images
    threads = torch.get_num_threads()
    dataset = tmp_path / "dataset"
    make_dataset(dataset, "ref", "query", paths)
    (dataset / "query" / "broken.jpg").write_bytes(b"broken")
    model_file = tmp_path / "mean.pt"
    torch.jit.script(torch.nn.Sequential(torch.nn.AdaptiveAvgPool2d(1), torch.nn.Flatten())).save(str(model_file))
    out = tmp_path / "run" / "descriptors.h5"
    argv = ["extract", "--dataset", str(dataset), "--model", str(model_file), "--out", str(out), "--no-progress"]
    with pytest.raises(ImageDecodeError, match=r"'query/broken\.jpg'"):
        run_cli(argv)
    with pytest.warns(UserWarning, match=r"broken\.jpg"):
        assert run_cli([*argv, "--on-error", "skip", "--half", "--batch-size", "2", "--threads", str(threads)]) == 0
    printed = capsys.readouterr().out
    assert "database: 6 descriptors of size 3" in printed
    assert "queries: 4 descriptors of size 3, 1 skipped" in printed
    assert list(read_descriptors(out, "database")[0]) == [f"ref/{name}" for name in names[:6]]
    assert list(read_descriptors(out, "queries")[0]) == [f"query/{name}" for name in names[6:]]
    assert cache_info(out)["dtype"] == "float16"


def test_dataset_images_layouts(images, tmp_path):
    paths, names = images
    make_dataset(tmp_path / "a", "database", "queries", paths)
    splits = extract_command.dataset_images(tmp_path / "a")
    assert splits["database"][1] == [f"database/{name}" for name in names[:6]]
    assert splits["queries"][1] == [f"queries/{name}" for name in names[6:]]
    (tmp_path / "b").mkdir()
    with pytest.raises((FileNotFoundError, ValueError)):
        extract_command.dataset_images(tmp_path / "b")
    with pytest.raises(FileNotFoundError):
        extract_command.dataset_images(tmp_path / "c")


def test_dataset_images_uses_the_dataset_readers(corridor_dir):
    splits = extract_command.dataset_images(corridor_dir)
    assert splits["database"][1][:2] == ["ref/0000000.jpg", "ref/0000001.jpg"]
    assert len(splits["queries"][0]) == 111 and splits["queries"][0][0] == corridor_dir / "query" / "0000000.jpg"


def test_images_of_different_sizes_share_a_batch(images, tmp_path):
    paths, _names = images
    tall = tmp_path / "tall.png"
    Image.fromarray(np.full((20, 10, 3), 90, np.uint8)).save(tall)
    mixed = [paths[0], tall, paths[1]]
    network, model = counting()
    _, together = extract_descriptors(model, mixed, None, batch_size=3, progress=False)
    assert network.calls == 2  # one forward per image size
    _, alone = extract_descriptors(counting()[1], mixed, None, batch_size=1, progress=False)
    assert_close(together, alone, atol=1e-6)  # batches of 2 and 1: other kernels


def test_decode_threads_keep_order(images):
    paths, names = images
    for workers in (0, 1, 3):
        kept, descriptors = extract_descriptors(
            counting()[1], paths, names, batch_size=3, workers=workers, progress=False
        )
        assert list(kept) == names
        if workers == 0:
            reference = descriptors
        np.testing.assert_array_equal(descriptors, reference)  # same batches; only decoding threads differ


def test_cache_in_use_by_another_process_is_not_clobbered(images, tmp_path, monkeypatch):
    """HDF5 refuses to open a file another process writes (file lock): the cache must say so, not recreate it."""
    paths, names = images
    path = tmp_path / "d.h5"
    extract_descriptors(counting()[1], paths[:2], names[:2], path, "database", progress=False)
    real_file = h5py.File

    def locked(name, mode="r", *args, **kwargs):
        if mode == "r":
            raise OSError("Unable to synchronously open file (unable to lock file, errno = 11)")
        return real_file(name, mode, *args, **kwargs)

    monkeypatch.setattr(h5py, "File", locked)
    with pytest.raises(ValueError, match="open for writing in another process"):
        extract_descriptors(counting()[1], paths, names, path, "database", progress=False)
    monkeypatch.undo()
    assert cache_info(path)["database"]["count"] == 2


class GeM(torch.nn.Module):
    """Generalised-mean pooling with a plain-float exponent, after a 1x1 convolution (D = 4)."""

    def __init__(self, p: float = 3.0) -> None:
        super().__init__()
        self.conv = torch.nn.Conv2d(3, 4, 1)
        self.p = p

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        features = self.conv(images).clamp(min=1e-6)
        return features.pow(self.p).mean(dim=(2, 3)).pow(1.0 / self.p)


def test_the_cache_key_covers_code_parameters_buffers_and_plain_attributes(images, tmp_path):
    """Changing GeM's plain p, a weight, or a function's code reused the old descriptors (issue 20, row 6)."""
    from vpr_uncertainty.identity import UnfingerprintableModel, callable_identity

    paths, names = images
    path = tmp_path / "d.h5"
    torch.manual_seed(0)
    network = GeM()
    _, first = extract_descriptors(network, paths, names, path, "database", progress=False)
    _, again = extract_descriptors(network, paths, names, path, "database", progress=False)
    np.testing.assert_array_equal(first, again)  # unchanged: reused
    network.p = 1.0  # a plain attribute, set after the model was first used
    with pytest.warns(UserWarning, match="changed: weights"):
        _, changed = extract_descriptors(network, paths, names, path, "database", progress=False)
    _, fresh = extract_descriptors(network, paths, names, progress=False)
    assert_close(changed, fresh, rtol=1e-5) and not np.allclose(changed, first)
    before = callable_identity(network)
    with torch.no_grad():
        network.conv.weight[0, 0] += 1.0
    assert callable_identity(network) != before  # a parameter
    network.register_buffer("scale", torch.ones(1))
    with_buffer = callable_identity(network)
    network.scale += 1
    assert callable_identity(network) != with_buffer  # a buffer
    assert callable_identity(lambda x: x.mean(dim=(2, 3))) != callable_identity(lambda x: x.amax(dim=(2, 3)))
    exponent = 2.0
    assert callable_identity(lambda x: x.pow(exponent)) == callable_identity(lambda x: x.pow(exponent))

    class Holder:
        def __init__(self) -> None:
            self.handle = open(os.devnull)  # state that no digest describes

        def __call__(self, images):
            return images.mean(dim=(2, 3))

    holder = Holder()
    try:
        with pytest.raises(UnfingerprintableModel, match="weights_id"):
            extract_descriptors(holder, paths, names, path, "queries", progress=False)
        model = from_callable(holder, weights_id="holder-v1")  # the caller names it: accepted
        assert model.fingerprint["weights"] == "holder-v1"
    finally:
        holder.handle.close()
