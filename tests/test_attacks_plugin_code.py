"""Issue 42, row 10 and a message of its "Clear errors due", written as the attacks: a ``--plugin`` model whose
loader imports a helper by ``importlib.import_module`` gets stale descriptors from the cache when the helper is
edited (the code identity followed import statements only); a plugin file with a syntax error was an "internal
error ... please report it". Each test fails on the code before the fix.
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty import identity, plugins
from vpr_uncertainty.cache import CacheWarning
from vpr_uncertainty.cli import main

_MODEL_PLUGIN = """
import importlib
from vpr_uncertainty.descriptors import Preprocessing
from vpr_uncertainty.descriptors.models import DescriptorModel, ModelSpec, register_model

HELPER = "scaling"

def load(spec, *, device="cpu"):
    helper = importlib.import_module({name})  # lazily, in the loader: after the plugin was imported
    return DescriptorModel(spec.name, helper.network, spec.preprocessing, weights_id="fixed").to(device)

register_model(ModelSpec(name="dyn-stats", description="channel statistics", descriptor_dim=6, backbone="none",
                         preprocessing=Preprocessing(), loader=load, identify=lambda spec: "fixed"))
"""

_HELPER = """
import torch
SCALE = {scale}
def network(images):
    return torch.cat([images.mean(dim=(2, 3)), SCALE * images.std(dim=(2, 3))], dim=1)
"""


def _extract(folder: Path) -> tuple[subprocess.CompletedProcess, np.ndarray]:
    """``vpr-uncertainty --plugin dynmodel.py extract`` as a new process, as a user's rerun is; its descriptors."""
    import h5py

    command = [sys.executable, "-m", "vpr_uncertainty.cli", "--plugin", "dynmodel.py", "extract", "--dataset"]
    command += ["data", "--out", "d.h5", "--model", "dyn-stats", "--no-progress"]
    run = subprocess.run(command, cwd=folder, capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode == 0, run.stderr
    with h5py.File(folder / "d.h5", "r") as handle:
        return run, handle["database/descriptors"][()]


@pytest.mark.parametrize("name", ['"scaling"', "HELPER"], ids=["literal-name", "computed-name"])
def test_editing_a_helper_a_plugin_model_imports_by_name_changes_its_descriptors(tmp_path, name):
    pytest.importorskip("torch")
    image = pytest.importorskip("PIL.Image")
    rng = np.random.default_rng(0)
    for split in ("database", "queries"):
        (tmp_path / "data" / split).mkdir(parents=True)
        for index in range(3):
            pixels = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
            image.fromarray(pixels).save(tmp_path / "data" / split / f"img{index}.png")
    (tmp_path / "dynmodel.py").write_text(_MODEL_PLUGIN.format(name=name))
    (tmp_path / "scaling.py").write_text(_HELPER.format(scale="1.0"))
    _, before = _extract(tmp_path)
    (tmp_path / "scaling.py").write_text(_HELPER.format(scale="5.0"))
    second, after = _extract(tmp_path)
    assert not np.allclose(before, after, atol=1e-3)  # not last run's descriptors
    assert "changed: code" in second.stderr
    notice = f"warning: {tmp_path / 'dynmodel.py'}, line 9: imports or runs code by a name the cache cannot follow"
    assert (notice in second.stderr) == (name == "HELPER"), second.stderr


@pytest.fixture
def user_folder(tmp_path, monkeypatch):
    """``tmp_path`` on the Python path; what is imported from it and the memo of code identities undone after."""
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(identity, "_CLOSURES", {})
    monkeypatch.setattr(plugins, "_loaded", dict(plugins._loaded))
    before = set(sys.modules)
    yield tmp_path
    for name in set(sys.modules) - before:
        if str(getattr(sys.modules[name], "__file__", None)).startswith(str(tmp_path)):
            del sys.modules[name]


def _identity(folder: Path, module: str, source: str) -> tuple[str, list[str]]:
    (folder / f"{module}.py").write_text(source)
    identity._CLOSURES.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = identity.code_identity(module)
    return code, [str(w.message) for w in caught if w.category is CacheWarning]


@pytest.mark.parametrize(
    "call",
    [
        'importlib.import_module("helper_a")',
        '__import__("helper_a")',
        'import_module("helper_a")  # from importlib import import_module',
    ],
)
def test_a_helper_imported_by_a_literal_name_is_part_of_the_code_identity(user_folder, call):
    source = f"import importlib\nfrom importlib import import_module\n\ndef load():\n    return {call}\n"
    (user_folder / "helper_a.py").write_text("SCALE = 1.0\n")
    first, notices = _identity(user_folder, "plugin_a", source)
    assert not notices and "#run-" not in first
    (user_folder / "helper_a.py").write_text("SCALE = 5.0\n")
    assert _identity(user_folder, "plugin_a", source)[0] != first
    plain = "import torch\n\ndef load(net):\n    net.eval()\n    return importlib\n"  # .eval() is not eval()
    assert _identity(user_folder, "plugin_plain", plain) == (_identity(user_folder, "plugin_plain", plain)[0], [])


@pytest.mark.parametrize(
    ("source", "line"),
    [
        ("import importlib\nNAME = 'helper_b'\nhelper = importlib.import_module(NAME)\n", 3),
        ("from importlib import import_module as load\n\nload('helper_b')\n", 1),
        ("import importlib\n\ngetattr(importlib, 'import_module')('helper_b')\n", 3),
        ("import importlib\nhelper = importlib.import_module('.helper_b', 'pkg')\n", 2),
        ("\nexec(open('helper_b.py').read())\n", 2),
        ("import runpy\n\nrunpy.run_path('helper_b.py')\n", 3),
        ("import importlib.util\nimportlib.util.spec_from_file_location('h', 'helper_b.py')\n", 2),
    ],
)
def test_code_run_by_a_name_the_identity_cannot_follow_is_never_reused_in_another_run(user_folder, source, line):
    (user_folder / "helper_b.py").write_text("SCALE = 1.0\n")
    code, notices = _identity(user_folder, "plugin_b", source)
    assert notices == [
        f"{user_folder / 'plugin_b.py'}, line {line}: imports or runs code by a name the cache cannot follow, so what "
        "plugin_b computes is recomputed on every run (import it by a literal name to cache it)"
    ]
    # another process (another run) gets another identity: a cache keyed by it is never reused
    other = subprocess.run(
        [sys.executable, "-c", "from vpr_uncertainty.identity import code_identity; print(code_identity('plugin_b'))"],
        cwd=user_folder,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(user_folder), *sys.path])},
        capture_output=True,
        text=True,
        check=True,
    )
    assert other.stdout.strip() != code and other.stdout.partition("#run-")[0] == code.partition("#run-")[0]


def test_a_ray_worker_accepts_the_code_of_a_plugin_that_runs_code_by_a_name(user_folder):
    """A Ray worker's identity of such a plugin has its own run part: the code is compared without it."""
    (user_folder / "plugin_c.py").write_text(
        "import importlib\n\ndef load(name):\n    return importlib.import_module(name)\n"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CacheWarning)
        plugins.load_plugins([str(user_folder / "plugin_c.py")])
        target, folder, code = plugins.loaded_plugins()[-1]
        assert code and "#run-" in code
        plugins.replay_plugins([(target, folder, code.partition("#run-")[0] + "#run-0123456789abcdef")])
        with pytest.raises(ImportError, match="is not the code this run loaded"):
            plugins.replay_plugins([(target, folder, "code:0123#run-0123456789abcdef")])


@pytest.mark.parametrize(
    ("source", "where", "message"),
    [
        ("x = 1\n\ndef f(:\n    pass\n", "bad_plugin.py", ", line 3: invalid syntax; correct it there"),
        ("def f():\nreturn 1\n", "bad_plugin.py", ", line 2: expected an indented block after function definition"),
        ("import bad_helper\n", "bad_helper.py", ", line 2: invalid syntax"),
        ("raise SyntaxError('a setting is wrong')\n", "bad_plugin.py", ": a setting is wrong; correct it there\n"),
    ],
)
def test_a_plugin_with_a_syntax_error_is_one_line_naming_the_file_and_line(user_folder, capsys, source, where, message):
    (user_folder / "bad_helper.py").write_text("\ndef (:\n")
    (user_folder / "bad_plugin.py").write_text(source)
    assert main(["--plugin", str(user_folder / "bad_plugin.py"), "datasets"]) == 2
    error = capsys.readouterr().err
    assert error.startswith(f"vpr-uncertainty: error: plugin {user_folder / where}{message}")
    assert error.count("\n") == 1 and "internal error" not in error and "Traceback" not in error
