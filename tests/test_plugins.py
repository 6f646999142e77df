"""The one plugin mechanism (:mod:`vpr_uncertainty.plugins`) and its use for uncertainty methods."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from vpr_uncertainty.evaluation import evaluate
from vpr_uncertainty.methods import METHODS, available_methods, default_method_names, register_method
from vpr_uncertainty.plugins import Registry, load_plugins, load_target, merge_options
from vpr_uncertainty.retrieval import Retrieval


@dataclass(frozen=True)
class _Entry:
    name: str
    kind: str = "a"


def test_registry_lookup_suggests_and_lists_valid_names():
    registry: Registry[_Entry] = Registry("widget", normalise=str.lower)
    registry.register(_Entry("Alpha"), aliases=("first",))
    registry.register(_Entry("Beta", kind="b"))
    assert registry.get("alpha").name == "Alpha" and registry.get("FIRST").name == "Alpha"
    assert registry.names() == ["Alpha", "Beta"] and registry.names(kind="b") == ["Beta"]
    with pytest.raises(KeyError, match=r"unknown widget 'alpah'; did you mean 'Alpha'\? valid: Alpha, Beta"):
        registry.get("alpah")
    with pytest.raises(ValueError, match="already registered"):
        registry.register(_Entry("ALPHA"))
    registry.unregister("first")
    assert "alpha" not in registry and "first" not in registry and len(registry) == 1


def test_merge_options_rejects_unknown_names_listing_the_valid_ones():
    defaults = {"ratio": 0.8, "nested": {"a": 1, "b": 2}}
    assert merge_options(defaults, {"nested": {"b": 3}}, what="matcher") == {"ratio": 0.8, "nested": {"a": 1, "b": 3}}
    with pytest.raises(ValueError, match=r"matcher has no option 'ratoi' \(valid options: nested, ratio\)"):
        merge_options(defaults, {"ratoi": 0.9}, what="matcher")
    with pytest.raises(ValueError, match=r"matcher, nested has no option 'c' \(valid options: a, b\)"):
        merge_options(defaults, {"nested": {"c": 0}}, what="matcher")


def test_lazy_target_names_the_extra_when_its_module_is_missing():
    assert load_target("vpr_uncertainty.plugins:merge_options", what="x") is merge_options
    with pytest.raises(ImportError, match=r"thing needs a missing dependency \(no_such_module_xyz\); .*\[gv\]"):
        load_target("no_such_module_xyz:f", what="thing", extra="gv")


def test_method_kinds_replace_the_parallel_lists():
    assert available_methods(kind="score") == ["RS", "SD", "SU", "PA", "L2", "BM", "SU-adaptive", "margin"]
    assert available_methods(kind="geometric") == ["GV-SIFT", "GV-DISK-LG", "GV-XFEAT", "GV-SP-SG", "GV-SP-LG", "GV-H5"]
    assert default_method_names() == ["RS", "SD", "SU", "PA", "L2", "BM"]
    assert METHODS.get("BTL").kind == "learned" and METHODS.get("SUE").kind == "spatial"


def _retrieval() -> Retrieval:
    return Retrieval(
        scores=np.array([[0.9, 0.5], [0.8, 0.7], [0.6, 0.1]]),
        indices=np.array([[0, 1], [0, 1], [0, 1]]),
        positives=np.array([[True, False], [False, True], [True, False]]),
    )


def test_evaluate_rejects_an_option_no_selected_method_takes():
    # Before: evaluate(..., btl_haed=...) silently dropped the misspelt option.
    with pytest.raises(ValueError, match=r"no selected uncertainty method \(SU, BM\) takes the option 'btl_haed'"):
        evaluate(_retrieval(), ["SU", "BM"], btl_haed="head.pt")
    # Inputs a stage offers every method (image paths, a cache folder, a device) stay allowed.
    evaluate(_retrieval(), ["BM"], cache_dir="x", device="cpu", timing_repeats=1)


def test_evaluate_resolves_files_once_before_timing():
    calls = []

    def resolve(retrieval, options):  # reads a file when given a path; resolved inputs pass through
        if isinstance(options["source"], str):
            calls.append(options["source"])
            return {**options, "source": np.asarray([0.3, 0.1, 0.2])}
        return dict(options)

    def method(retrieval, *, source=None):
        return np.asarray(source, dtype=float)

    register_method("RESOLVE-TEST", method, description="test", resolve=resolve)
    try:
        result = evaluate(_retrieval(), ["RESOLVE-TEST"], source="file.npy", timing_repeats=3)
    finally:
        METHODS.unregister("RESOLVE-TEST")
    assert calls == ["file.npy"]  # read once; the timed calls received the array
    np.testing.assert_array_equal(result.methods["RESOLVE-TEST"].uncertainty, [0.3, 0.1, 0.2])


def test_descriptor_models_are_registry_entries():
    from vpr_uncertainty.descriptors.models import MODELS, available_models, get_model_spec

    spec = get_model_spec("EfficientNet_Lite0-GEM")  # case, "-" and "_" ignored
    assert spec.name == "efficientnet-lite0-gem" and spec.requires == ("images",) and spec.extra == "torch"
    assert available_models() == MODELS.names()
    with pytest.raises(KeyError, match=r"did you mean 'cosplace'\?.*or a TorchScript file"):
        get_model_spec("cosplac")


def test_a_default_plugin_method_runs_in_evaluate_without_a_method_list():
    # Before: evaluate()'s default list was frozen when evaluation was imported, so a plugin registered later with
    # default=True ran in `run` but not in `evaluate()`.
    register_method("LATE-DEFAULT", lambda retrieval: -retrieval.scores[:, 0], description="test", default=True)
    try:
        assert "LATE-DEFAULT" in evaluate(_retrieval(), timing_repeats=1).methods
    finally:
        METHODS.unregister("LATE-DEFAULT")


def test_suggestions_only_above_the_similarity_cutoff():
    with pytest.raises(KeyError) as error:
        METHODS.get("GPA")
    assert "did you mean" not in str(error.value)
    with pytest.raises(KeyError, match="did you mean 'GV-SIFT'"):
        METHODS.get("GV-SFIT")


def test_load_plugins_imports_a_module_that_registers_its_entries(tmp_path, monkeypatch):
    (tmp_path / "my_vpr_plugin.py").write_text(
        "from vpr_uncertainty.methods import register_method\n"
        "register_method('ENT-TEST', lambda retrieval: -retrieval.scores[:, 0], description='test')\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        load_plugins(["my_vpr_plugin"])
        assert "ENT-TEST" in available_methods()
    finally:
        METHODS.unregister("ENT-TEST")
    with pytest.raises(ImportError, match="plugin module 'no_such_plugin_xyz' not found"):
        load_plugins(["no_such_plugin_xyz"])


def test_the_package_registers_its_higher_layers_through_its_entry_points():
    from importlib import metadata

    groups = {entry.value for entry in metadata.entry_points(group="vpr_uncertainty.plugins")}
    assert {"vpr_uncertainty.geometric", "vpr_uncertainty.btl"} <= groups
    assert {"GV-SIFT", "BTL", "SUE", "CAL"} <= set(available_methods())


def test_a_plugin_module_named_on_the_command_line_gives_the_cli_its_method(tmp_path, monkeypatch, capsys):
    """Before: `evaluate --methods ENT` with a user's method needed a wrapper script around cli.main."""
    from vpr_uncertainty.cli import main

    (tmp_path / "entropy_plugin.py").write_text(
        "import numpy as np\n"
        "from vpr_uncertainty.methods import register_method\n"
        "def entropy(retrieval, *, k=10):\n"
        "    s = np.exp(retrieval.scores[:, :k]); p = s / s.sum(axis=1, keepdims=True)\n"
        "    return -(p * np.log(p)).sum(axis=1)\n"
        "register_method('ENT', entropy, description='entropy of the softmax of the top-k scores')\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    matrix = tmp_path / "sim.npy"
    rng = np.random.default_rng(0)
    np.save(matrix, rng.random((12, 15)).astype(np.float32))
    ground_truth = tmp_path / "gt.json"
    ground_truth.write_text("[" + ",".join(f"[{i}]" for i in range(12)) + "]")
    try:
        with pytest.raises(SystemExit) as exit_:  # a usage error
            main(["evaluate", str(matrix), "--gt", str(ground_truth), "--methods", "ENT,SU"])
        assert exit_.value.code == 2 and "unknown uncertainty method 'ENT'" in capsys.readouterr().err
        argv = ["--plugin", "entropy_plugin", "evaluate", str(matrix), "--gt", str(ground_truth), "--methods", "ENT,SU"]
        assert main(argv) == 0
        assert "ENT" in capsys.readouterr().out
    finally:
        METHODS.unregister("ENT")
    assert main(["--plugin", "no_such_plugin_xyz", "datasets"]) == 2
    assert "plugin module 'no_such_plugin_xyz' not found" in capsys.readouterr().err


def test_a_doubled_last_letter_gets_the_near_name():
    """Issue 45, item 7: ``--methods SUU`` listed the valid names without 'SU' (a prefix: one letter too many)."""
    with pytest.raises(KeyError, match="did you mean 'SU'"):
        METHODS.get("SUU")


def test_a_plugin_a_test_loads_is_forgotten_after_it_and_the_entry_points_stay(tmp_path, monkeypatch):
    """What the autouse fixture of conftest.py runs after every test."""
    from conftest import forget_user_plugins
    from vpr_uncertainty import plugins

    plugins.load_plugins()
    before = set(plugins._loaded)
    (tmp_path / "forgotten_plugin.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    load_plugins(["forgotten_plugin"])
    assert "forgotten_plugin" in [target for target, _, _ in plugins.loaded_plugins()]
    forget_user_plugins(before)
    shipped = [target for target, _, _ in plugins.loaded_plugins()]
    assert "forgotten_plugin" not in shipped and "vpr_uncertainty.geometric" in " ".join(shipped)
