"""Plugins as users type them (issue 30, deliverable 5): ``--plugin path/to/file.py``, ``--plugin my_unc`` from the
folder holding ``my_unc.py``, and the global options after the command name.

Before: ``--plugin ./my_unc.py`` failed with "the 'package' argument is required to perform a relative import";
``--plugin my_unc`` from its folder was "not found" without ``PYTHONPATH=.``; ``--plugin``, ``--debug`` after the
command were "unrecognized arguments"; a plugin file could not reach a Ray worker as a file.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from vpr_uncertainty import identity, plugins
from vpr_uncertainty.cli import main
from vpr_uncertainty.methods import METHODS

_PLUGIN = """
import numpy as np
from vpr_uncertainty.methods import register_method
from helper_beside_it import GAP_WEIGHT

def entropy(retrieval, *, k=10):
    scores = np.asarray(retrieval.scores, dtype=np.float64)[:, :k] * GAP_WEIGHT
    p = np.exp(scores - scores.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    return -(p * np.log(p)).sum(axis=1)

register_method("ENT", entropy, description="entropy of the softmax of the top-k scores")
"""


@pytest.fixture
def isolated(tmp_path, monkeypatch):
    """A folder holding ``my_unc.py`` (and the helper it imports), not on the Python path; what loading it
    registers, imports and adds to the path is undone after."""
    plugins.load_plugins()  # the entry points first, so that the snapshot holds them
    monkeypatch.setattr(plugins, "_loaded", dict(plugins._loaded))
    monkeypatch.setattr(METHODS, "_entries", dict(METHODS._entries))
    monkeypatch.setattr(METHODS, "_aliases", dict(METHODS._aliases))
    monkeypatch.setattr(sys, "path", [entry for entry in sys.path if entry not in ("", ".")])
    # code identities are cached by module name: my_unc of an earlier test is another file
    monkeypatch.setattr(identity, "_CLOSURES", {})
    folder = tmp_path / "user"
    folder.mkdir()
    (folder / "my_unc.py").write_text(_PLUGIN)
    (folder / "helper_beside_it.py").write_text("GAP_WEIGHT = 10.0\n")
    before = set(sys.modules)
    yield folder
    for name in set(sys.modules) - before:
        if str(getattr(sys.modules[name], "__file__", None)).startswith(str(tmp_path)):
            del sys.modules[name]


@pytest.fixture
def corridor_netvlad(corridor_dir, corridor_matches_dir):
    matrix = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    return [str(matrix), "--gt", str(corridor_dir / "ground_truth_new.npy")]


def _evaluated(capsys) -> dict[str, float]:
    """AUC-PR by method, from the table ``evaluate`` printed."""
    rows = [line.split() for line in capsys.readouterr().out.splitlines()]
    return {row[0].rstrip("*"): float(row[1]) for row in rows if len(row) == 8 and row[0] != "method"}


@pytest.mark.parametrize(
    "argv",
    [
        ["--plugin", "./my_unc.py", "evaluate"],  # the relative path, before the command
        ["evaluate", "--plugin", "my_unc.py"],  # after it
        ["--plugin", "my_unc", "evaluate"],  # a module in the current folder, without PYTHONPATH=.
        ["evaluate", "--plugin", "my_unc", "--no-progress"],
    ],
    ids=["dot-slash-file", "file-after-command", "module-in-folder", "module-after-command"],
)
def test_a_plugin_from_its_own_folder_gives_evaluate_its_method(argv, isolated, corridor_netvlad, monkeypatch, capsys):
    monkeypatch.chdir(isolated)
    command = argv.index("evaluate")
    assert main([*argv[: command + 1], *corridor_netvlad, "--methods", "ENT,SU", *argv[command + 1 :]]) == 0
    auc_pr = _evaluated(capsys)
    assert set(auc_pr) == {"ENT", "SU"} and auc_pr["SU"] == 0.8471  # the SU on NetVLAD


def test_a_plugin_file_loads_from_any_folder_and_a_missing_one_is_one_line(
    isolated, corridor_netvlad, tmp_path, monkeypatch, capsys
):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main(["evaluate", *corridor_netvlad, "--methods", "ENT", "--plugin", "../user/my_unc.py"]) == 0
    assert set(_evaluated(capsys)) == {"ENT"}
    assert main(["evaluate", *corridor_netvlad, "--plugin", "../user/nothing_here.py"]) == 2
    error = capsys.readouterr().err.strip()
    assert error == f"vpr-uncertainty: error: plugin file {tmp_path / 'user' / 'nothing_here.py'}: not found"
    assert main(["--plugin", "no_unc_here", "datasets"]) == 2  # not in this folder, nor on the path
    assert "plugin module 'no_unc_here' not found (on the Python path, or in this folder as no_unc_here.py)" in (
        capsys.readouterr().err
    )


def test_a_plugin_file_is_refused_when_its_name_is_another_module(isolated, tmp_path, monkeypatch, capsys):
    (tmp_path / "json.py").write_text("raise RuntimeError('never run')\n")
    assert main(["--plugin", str(tmp_path / "json.py"), "datasets"]) == 2
    assert "the module 'json' is already imported" in capsys.readouterr().err


def test_a_plugin_file_travels_to_a_worker_as_its_path(isolated, tmp_path, monkeypatch):
    """What a Ray worker does (:func:`plugins.replay_plugins`), in this process: another folder, another Python
    path, the module not imported; the same code by its absolute path, checked by its digest."""
    monkeypatch.chdir(isolated)
    plugins.load_plugins(["./my_unc.py"])
    (target, folder, code) = plugins.loaded_plugins()[-1]
    assert target == str(isolated / "my_unc.py") and folder == str(isolated) and code
    for name in ("my_unc", "helper_beside_it"):
        del sys.modules[name]
    METHODS.unregister("ENT")
    plugins._loaded.pop(target)
    sys.path.remove(str(isolated))
    monkeypatch.chdir(tmp_path)
    plugins.replay_plugins([(target, folder, code)])
    assert "ENT" in METHODS and sys.modules["my_unc"].__file__ == target
    (isolated / "helper_beside_it.py").write_text("GAP_WEIGHT = 200.0\n")  # edited since the run loaded it
    del sys.modules["my_unc"], sys.modules["helper_beside_it"]
    METHODS.unregister("ENT")
    plugins._loaded.pop(target)
    with pytest.raises(ImportError, match="is not the code this run loaded"):
        plugins.replay_plugins([(target, folder, code)])


def test_debug_after_the_command_shows_the_traceback(tmp_path, capsys):
    missing = tmp_path / "missing.npy"
    assert main(["evaluate", str(missing), "--gt", str(missing), "--debug"]) == 2
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and err.strip().splitlines()[-1].startswith(
        "vpr-uncertainty evaluate: error: "
    )
    assert main(["evaluate", str(missing), "--gt", str(missing)]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_debug_after_the_command_shows_the_traceback_of_a_plugin_that_fails_to_load(isolated, capsys):
    (isolated / "broken.py").write_text("raise ValueError('a setting of this plugin is wrong')\n")
    argv = ["datasets", "--plugin", str(isolated / "broken.py")]
    assert main(argv) == 2
    assert capsys.readouterr().err == "vpr-uncertainty: error: a setting of this plugin is wrong\n"
    assert main([*argv, "--debug"]) == 2
    assert "Traceback (most recent call last)" in capsys.readouterr().err


def test_global_options_after_the_command_keep_those_before_it(isolated):
    from vpr_uncertainty.cli import build_parser

    args = build_parser().parse_args(["--debug", "--no-progress", "datasets"])
    assert (args.debug, args.progress, args.plugin) == (True, False, [])
    args = build_parser().parse_args(["datasets", "--debug", "--progress", "--plugin", "x.py"])
    assert (args.debug, args.progress, args.plugin) == (True, True, ["x.py"])
    assert np.isin(["--plugin", "--debug", "--progress"], build_parser().format_help().split()).all()
