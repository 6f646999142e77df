"""The nine torch.hub models of the registry, checked without any download (torch.hub.load is replaced)."""

from __future__ import annotations

import urllib.error
from pathlib import Path

import pytest

from conftest import assert_close

torch = pytest.importorskip("torch")

from vpr_uncertainty.descriptors import (  # noqa: E402
    ModelUnavailableError,
    available_models,
    get_model_spec,
    load_model,
)
from vpr_uncertainty.descriptors.models import HUB_MODELS, torchscript_cache_path  # noqa: E402

IMAGENET = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))

#: name -> (torch.hub repo, entry point, keyword arguments, descriptor size, backbone, image_size, multiple_of)
EXPECTED = {
    "eigenplaces": (
        "gmberton/eigenplaces",
        "get_trained_model",
        {"backbone": "ResNet50", "fc_output_dim": 512},
        512,
        "ResNet-50",
        None,
        1,
    ),
    "cosplace": (
        "gmberton/cosplace",
        "get_trained_model",
        {"backbone": "ResNet50", "fc_output_dim": 512},
        512,
        "ResNet-50",
        None,
        1,
    ),
    "convap": (None, None, {}, 512, "ResNet-50", (320, 320), 1),
    "mixvpr": ("jarvisyjw/MixVPR", "get_trained_model", {"pretrained": True}, 4096, "ResNet-50", (320, 320), 1),
    "apgem": (None, None, {}, 2048, "ResNet-101", None, 1),
    "salad": ("serizba/salad", "dinov2_salad", {}, 8448, "DINOv2 ViT-B/14", None, 14),
    "anyloc": (
        "AnyLoc/DINO",
        "get_vlad_model",
        {"backbone": "DINOv2", "domain": "urban"},
        49152,
        "DINOv2 ViT-G/14",
        None,
        14,
    ),
    "cricavpr": ("Lu-Feng/CricaVPR", "trained_model", {}, 10752, "DINOv2 ViT-B/14", (224, 224), 1),
    "netvlad": ("yxgeee/OpenIBL", "vgg16_netvlad", {"pretrained": True}, 4096, "VGG-16", None, 1),
}
HUB_NAMES = [name for name, entry in EXPECTED.items() if entry[0] is not None]
EXPORT_NAMES = [name for name, entry in EXPECTED.items() if entry[0] is None]


class FakeHub:
    """Stands in for torch.hub.load: records the call, returns a network producing descriptors of size D."""

    def __init__(self, dim: int) -> None:
        self.dim = dim
        self.calls: list[tuple[tuple, dict]] = []

    def __call__(self, *args, **kwargs):
        self.calls.append((args, kwargs))
        dim = self.dim

        class Network(torch.nn.Module):
            def forward(self, images):
                return torch.ones(images.shape[0], dim)

        return Network()


@pytest.fixture
def hub_dir(tmp_path, monkeypatch) -> Path:
    """An empty torch.hub cache, so that nothing of the real one is used."""
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    return tmp_path / "hub"


def test_registry_holds_the_nine_methods_after_the_default():
    assert available_models() == ["efficientnet-lite0-gem", *EXPECTED]
    assert [spec.name for spec in HUB_MODELS] == list(EXPECTED)


@pytest.mark.parametrize("name", list(EXPECTED))
def test_entry_metadata(name):
    repo, entrypoint, kwargs, dim, backbone, image_size, multiple_of = EXPECTED[name]
    spec = get_model_spec(name)
    assert spec.name == name
    assert (spec.hub_repo, spec.hub_entrypoint, dict(spec.hub_kwargs)) == (repo, entrypoint, kwargs)
    assert spec.descriptor_dim == dim and spec.backbone == backbone
    assert spec.preprocessing.image_size == image_size
    assert spec.preprocessing.multiple_of == multiple_of
    if name != "netvlad":
        assert (spec.preprocessing.mean, spec.preprocessing.std) == IMAGENET
    assert spec.description and spec.source


def test_netvlad_uses_openibl_pixel_range():
    spec = get_model_spec("netvlad")
    assert_close(spec.preprocessing.std, (1 / 255,) * 3)
    assert_close(spec.preprocessing.mean, (0.48502, 0.45796, 0.40760), atol=1e-5)


@pytest.mark.parametrize("alias", ["Conv-AP", "AP-GeM", "EigenPlaces", "SALAD", "cric_avpr"])
def test_names_ignore_case_and_separators(alias):
    assert get_model_spec(alias).name == alias.lower().replace("-", "").replace("_", "")


@pytest.mark.parametrize("name", HUB_NAMES)
def test_hub_loader_signature(name, monkeypatch, hub_dir):
    repo, entrypoint, kwargs, dim, *_ = EXPECTED[name]
    fake = FakeHub(dim)
    monkeypatch.setattr(torch.hub, "load", fake)
    model = load_model(name)
    ((args, call_kwargs),) = fake.calls
    assert args == (repo, entrypoint)
    expected_kwargs = {**kwargs, "trust_repo": True}
    if name == "anyloc":
        expected_kwargs["device"] = "cpu"
    assert call_kwargs == expected_kwargs
    assert model.name == name and model.descriptor_dim == dim
    assert model.weights_id.startswith(f"torch.hub:{repo}:{entrypoint}:")
    assert model.fingerprint["preprocessing"] == get_model_spec(name).preprocessing.to_dict()
    descriptors = model(torch.zeros(2, 3, 28, 28))
    assert descriptors.shape == (2, dim)


def test_hub_options_override_entry_point_arguments(monkeypatch, hub_dir):
    fake = FakeHub(2048)
    monkeypatch.setattr(torch.hub, "load", fake)
    model = load_model("cosplace", fc_output_dim=2048)
    assert fake.calls[0][1]["fc_output_dim"] == 2048
    assert model.descriptor_dim == 2048
    assert model.weights_id != load_model("cosplace").weights_id


def no_dns(*args, **kwargs):
    raise urllib.error.URLError("[Errno -2] Name or service not known")


def no_repo_in_cache(*args, **kwargs):
    """What torch.hub.load raises offline when the repository is not cached."""
    try:
        no_dns()
    except urllib.error.URLError as error:
        raise RuntimeError("It looks like there is no internet connection and the repo could not be found") from error


@pytest.mark.parametrize("offline", [no_dns, no_repo_in_cache])
@pytest.mark.parametrize("name", HUB_NAMES)
def test_offline_error_names_model_and_cache(name, offline, monkeypatch, hub_dir):

    monkeypatch.setattr(torch.hub, "load", offline)
    with pytest.raises(ModelUnavailableError) as caught:
        load_model(name)
    message = str(caught.value)
    assert f"cannot load model {name!r}" in message
    assert str(hub_dir) in message and EXPECTED[name][0] in message
    assert isinstance(caught.value, FileNotFoundError)  # the CLI reports it as a one-line error


def test_other_hub_errors_are_not_disguised_as_offline(monkeypatch, hub_dir):
    def broken(*args, **kwargs):
        raise RuntimeError("Error(s) in loading state_dict")

    monkeypatch.setattr(torch.hub, "load", broken)
    with pytest.raises(RuntimeError, match="state_dict"):
        load_model("salad")


@pytest.mark.parametrize("name", EXPORT_NAMES)
def test_models_without_hub_entry_use_a_torchscript_export(name, monkeypatch, hub_dir):
    monkeypatch.setattr(torch.hub, "load", FakeHub(1))  # must not be called
    target = torchscript_cache_path(name)
    assert target == hub_dir / "vpr_uncertainty" / f"{name}.pt"
    with pytest.raises(ModelUnavailableError, match=rf"{name!r} has no published torch.hub entry point.*{target}"):
        load_model(name)
    dim = EXPECTED[name][3]
    target.parent.mkdir(parents=True)
    network = torch.nn.Sequential(torch.nn.AdaptiveAvgPool2d(1), torch.nn.Flatten(), torch.nn.Linear(3, dim))
    torch.jit.trace(network, torch.zeros(1, 3, 8, 8)).save(str(target))
    model = load_model(name)
    assert model.name == name and model.preprocessing == get_model_spec(name).preprocessing
    assert model(torch.zeros(2, 3, 8, 8)).shape == (2, dim)
