"""``vpr-uncertainty subset`` (a labelled split or an unlabelled pool as a retrieval file) and the argument order of
``save_retrieval``."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, load_retrieval, save_retrieval
from vpr_uncertainty.cli import main


def _retrieval(n_queries: int = 7) -> Retrieval:
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((n_queries, 4)).astype(np.float32), axis=1)
    indices = np.argsort(rng.random((n_queries, 9)), axis=1)[:, :4]
    mask = np.zeros((n_queries, 9), dtype=bool)
    mask[np.arange(n_queries), indices[:, 0]] = np.arange(n_queries) % 2 == 0
    names = np.array([f"q{i}" for i in range(n_queries)])
    return Retrieval(scores=scores, indices=indices, positives=mask, query_names=names)


@pytest.mark.parametrize(
    ("queries", "expected"), [("0:3", [0, 1, 2]), ("5:", [5, 6]), ("-2:", [5, 6]), (":", range(7))]
)
def test_subset_writes_the_queries_it_names(queries, expected, tmp_path, capsys):
    retrieval = _retrieval()
    source = save_retrieval(retrieval, tmp_path / "all.npz")
    assert main(["subset", str(source), f"--queries={queries}", "--out", str(tmp_path / "part.npz")]) == 0
    part, reference = load_retrieval(tmp_path / "part.npz"), retrieval.subset_queries(np.array(list(expected)))
    np.testing.assert_array_equal(part.scores, reference.scores)  # the same float32 values, copied
    np.testing.assert_array_equal(part.indices, reference.indices)
    np.testing.assert_array_equal(part.query_names, reference.query_names)
    assert (part.positives != reference.positives).nnz == 0 and part.n_database == 9
    assert f"({len(expected)} of 7)" in capsys.readouterr().out


@pytest.mark.parametrize("queries", ["0:8", "3", "a:b", "1:5:2", "4:2"])
def test_subset_refuses_rows_it_cannot_take(queries, tmp_path, capsys):
    source = save_retrieval(_retrieval(), tmp_path / "all.npz")
    assert main(["subset", str(source), f"--queries={queries}", "--out", str(tmp_path / "part.npz")]) == 2
    assert "expected START:STOP within the 7 queries" in capsys.readouterr().err
    assert not (tmp_path / "part.npz").exists()


def test_save_retrieval_in_numpys_order_names_the_order(tmp_path):
    retrieval = _retrieval()
    with pytest.raises(TypeError, match=r"save_retrieval\(retrieval, path\): the Retrieval comes first, got str"):
        save_retrieval(str(tmp_path / "r.npz"), retrieval)
    with pytest.raises(TypeError, match=r"comes first, got (Posix|Windows)Path"):
        save_retrieval(tmp_path / "r.npz", retrieval)
    assert not (tmp_path / "r.npz").exists()
