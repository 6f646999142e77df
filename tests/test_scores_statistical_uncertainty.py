"""``StatisticalUncertainty`` (vpr_uncertainty.scores) takes one query's scores in the forms users have: a list, a
(k,) or (1, k) array (Faiss's ``index.search`` for one query), a torch tensor; returns a Python float; has a repr."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty import StatisticalUncertainty, statistical_uncertainty

ROW = [0.91, 0.52, 0.50, 0.47, 0.40]


class FakeTensor:
    """What the scorer may use of a torch tensor (duck-typed): detach, cpu, shape, tolist; never numpy()."""

    def __init__(self, values):
        self._values = np.asarray(values, dtype=np.float32)
        self.shape = self._values.shape
        self.calls = []

    def detach(self):
        self.calls.append("detach")
        return self

    def cpu(self):
        self.calls.append("cpu")
        return self

    def tolist(self):
        return self._values.tolist()

    def numpy(self):  # pragma: no cover - must not be needed
        raise AssertionError("numpy() called: it fails for CUDA, grad and bfloat16 tensors")


def _expected(k=4, alpha=0.5):
    return float(statistical_uncertainty(np.array([ROW]), k=k, alpha=alpha)[0])


@pytest.mark.parametrize(
    "scores",
    [ROW, tuple(ROW), np.array(ROW), np.array([ROW]), np.array(ROW, np.float32), np.array([ROW], np.float32), [ROW]],
    ids=["list", "tuple", "(k,)", "(1, k)", "(k,) float32", "(1, k) float32 (Faiss)", "[[...]]"],
)
def test_every_one_query_form_gives_a_python_float(scores):
    """Regression: a (1, k) array, as Faiss returns for one query, raised 'scores must be 1-D'."""
    value = StatisticalUncertainty(k=4)(scores)
    assert type(value) is float
    assert value == pytest.approx(_expected(), rel=1e-6)  # float32 inputs round at 1e-7


def test_a_list_of_numpy_scalars_still_gives_a_python_float():
    value = StatisticalUncertainty(k=4)(list(np.array(ROW, np.float32)))
    assert type(value) is float


@pytest.mark.parametrize("shape", [(5,), (1, 5)])
def test_a_tensor_is_read_without_torch_or_numpy(shape):
    tensor = FakeTensor(np.reshape(ROW, shape))
    value = StatisticalUncertainty(k=4)(tensor)
    assert type(value) is float and value == pytest.approx(_expected(), rel=1e-6)
    assert tensor.calls == ["detach", "cpu"]


def test_a_real_torch_tensor_when_torch_is_installed():
    torch = pytest.importorskip("torch")
    scorer = StatisticalUncertainty(k=4)
    for tensor in (torch.tensor(ROW), torch.tensor([ROW], requires_grad=True), torch.tensor(ROW, dtype=torch.float64)):
        value = scorer(tensor)
        assert type(value) is float and value == pytest.approx(_expected(), rel=1e-6)


@pytest.mark.parametrize(
    ("scores", "error", "message"),
    [
        (np.array([ROW, ROW]), ValueError, r"one query's top-k, of shape \(k,\) or \(1, k\), got shape \(2, 5\)"),
        (FakeTensor([ROW, ROW]), ValueError, r"got shape \(2, 5\)"),
        (np.float64(0.9), ValueError, r"got shape \(\)"),
        ("0.9 0.5", TypeError, "scores must be a sequence of similarities, got str"),
        ([0.9], ValueError, "at least 2 finite candidates, got 1"),
        ([0.5, 0.9], ValueError, "sorted in descending order"),
        (np.array([True, False]), TypeError, "must be numbers, got an array of dtype bool"),
        (np.array(["0.9", "0.5"]), TypeError, "must be numbers, got an array of dtype <U3"),
    ],
    ids=["two queries", "two-query tensor", "scalar", "string", "one candidate", "unsorted", "bools", "strings"],
)
def test_bad_input_is_named(scores, error, message):
    with pytest.raises(error, match=message):
        StatisticalUncertainty(k=4)(scores)


def test_the_callers_list_is_not_changed():
    scores = [0.9, 0.5, 0.4, -np.inf]
    StatisticalUncertainty(k=10)(scores)
    assert scores == [0.9, 0.5, 0.4, -np.inf]


def test_repr_shows_the_options():
    assert repr(StatisticalUncertainty()) == "StatisticalUncertainty(k=10, alpha=0.5)"
    assert repr(StatisticalUncertainty(k=5, alpha=0.25)) == "StatisticalUncertainty(k=5, alpha=0.25)"
    raising = StatisticalUncertainty(on_nonpositive="raise")
    assert repr(raising) == "StatisticalUncertainty(k=10, alpha=0.5, on_nonpositive='raise')"
    assert (raising.k, raising.alpha) == (10, 0.5)


def test_a_nested_list_of_several_queries_is_refused():
    with pytest.raises(ValueError, match=r"\(k,\) or \(1, k\), got 2 rows; use batch\(\)"):
        StatisticalUncertainty(k=4)([ROW, ROW])
