"""`import vpr_uncertainty` is light: the public names load their modules when first used (PEP 562)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

import vpr_uncertainty

# VPR_UNCERTAINTY_NUMBA=1 (a debugging switch) makes every score call load numba: the children run without it.
ENVIRONMENT = {key: value for key, value in os.environ.items() if key != "VPR_UNCERTAINTY_NUMBA"}


def _run(script: str) -> str:
    """The standard output of a fresh interpreter that runs ``script``."""
    command = [sys.executable, "-c", script]
    return subprocess.run(command, capture_output=True, text=True, check=True, env=ENVIRONMENT).stdout


HEAVY = ("scipy", "sklearn", "matplotlib", "h5py", "faiss", "torch", "pandas", "cv2", "numba")


def test_importing_the_package_and_scoring_loads_no_heavy_library():
    # Before: `import vpr_uncertainty` imported calibration, evaluation and data (scipy, scikit-learn, pandas...),
    # about 1.6-3 s on the development VM; a robot that needs SU paid for all of it.
    script = (
        "import sys, numpy as np, vpr_uncertainty as v\n"
        "v.statistical_uncertainty(np.array([[0.9, 0.5, 0.4]]), k=3)\n"
        f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    loaded = _run(script)
    assert loaded.strip() == ""


@pytest.mark.parametrize("name", vpr_uncertainty.__all__)
def test_every_public_name_resolves(name):
    assert getattr(vpr_uncertainty, name) is not None
    assert name in dir(vpr_uncertainty)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="has no attribute 'statistical_uncertanty'"):
        vpr_uncertainty.statistical_uncertanty  # noqa: B018


def test_a_saved_gate_loads_and_decides_without_a_heavy_library(tmp_path):
    """The robot's path: import, Gate.load, one call per query (the issue's light-import target)."""
    import numpy as np

    from vpr_uncertainty import Retrieval, calibrate

    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((300, 10)), axis=1)
    positives = rng.random((300, 10)) < scores  # a higher score is more often right
    retrieval = Retrieval(scores=scores, indices=np.tile(np.arange(10), (300, 1)), positives=positives)
    path = calibrate(retrieval).save(tmp_path / "gate.json")
    script = (
        "import sys, vpr_uncertainty as v\n"
        f"gate = v.Gate.load({str(path)!r})\n"
        "print(gate([0.9, 0.5, 0.4, 0.3, 0.3, 0.2, 0.2, 0.1, 0.1, 0.1]) in (True, False))\n"
        f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    printed = _run(script)
    assert printed.split("\n")[:2] == ["True", ""]


def test_the_evaluate_command_loads_only_what_it_computes_with(data_dir):
    """`vpr-uncertainty evaluate` on a matrix: numpy and scipy.sparse (the ground truth), not scikit-learn (whose
    import pulled pandas and pyarrow: 1-2 s), scipy.stats (the gate's guarantee, via the CAL plugin) or
    scipy.spatial (positives from positions); the command line also builds only the evaluate parser."""
    root = data_dir / "vprbench"
    matrix = root / "precomputed_matches" / "corridor" / "NetVLAD" / "precomputed_data_corrected.npy"
    script = (
        "import sys\n"
        "from vpr_uncertainty.cli import main\n"
        f"status = main(['evaluate', {str(matrix)!r}, '--gt', {str(root / 'corridor' / 'ground_truth_new.npy')!r}])\n"
        "heavy = ('sklearn', 'scipy.stats', 'scipy.spatial', 'pandas', 'pyarrow', 'matplotlib', 'h5py', 'faiss',\n"
        "         'torch', 'cv2', 'numba', 'PIL')\n"
        "print(status, ' '.join(m for m in heavy if m in sys.modules))\n"
    )
    printed = _run(script)
    assert printed.splitlines()[-1].strip() == "0"
