"""``--workers N``: one name for "how many parallel workers" on run, extract, reproduce and evaluate.

With ``--executor ray`` it is the number of Ray workers given to the executor; with ``--executor local`` it keeps
its local meaning (image decoding threads of run/extract) or is refused (reproduce, evaluate). ``--ray-workers``,
its former name, is refused. No Ray cluster is started here: ``get_executor`` is replaced by a recorder.
"""

from __future__ import annotations

import pytest

from vpr_uncertainty.cli import build_parser, main
from vpr_uncertainty.pipeline.options import executor_options, local_workers, ray_log_file

_REQUIRED = {
    "run": ["--dataset", "d", "--out", "o"],
    "extract": ["--dataset", "d", "--out", "o.h5"],
    "reproduce": ["grid.toml"],
    "evaluate": ["s.npy"],
}
_COMMANDS = list(_REQUIRED)


def _parse(command: str, *flags: str):
    return build_parser().parse_args([command, *_REQUIRED[command], *flags])


class _Recorder:
    """Stands in for an executor: records the options ``get_executor`` was called with."""

    def __init__(self, seen: dict, name: str, **options) -> None:
        seen.update(name=name, **options)
        self.name = name

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


@pytest.fixture
def seen(monkeypatch):
    recorded: dict = {}
    monkeypatch.setattr(
        "vpr_uncertainty.executors.get_executor", lambda name, **options: _Recorder(recorded, name, **options)
    )
    return recorded


@pytest.mark.parametrize("command", _COMMANDS)
def test_workers_is_the_number_of_ray_workers_under_ray(command):
    args = _parse(command, "--executor", "ray", "--workers", "3")
    assert executor_options(args) == {
        "name": "ray",
        "address": None,
        "workers": 3,
        "gpus_per_worker": 0.0,
        "connect_timeout": 30.0,
        "log_file": ray_log_file(),
    }
    assert local_workers(args) is None  # the Ray actors decode their own images


@pytest.mark.parametrize("command", _COMMANDS)
def test_ray_workers_default_to_the_clusters_cpus(command):
    assert executor_options(_parse(command, "--executor", "ray"))["workers"] is None


@pytest.mark.parametrize("command", ["run", "extract"])
def test_workers_stay_the_decoding_threads_with_the_local_executor(command):
    args = _parse(command, "--workers", "0")
    assert executor_options(args) == {"name": "local"}
    assert local_workers(args) == 0
    assert local_workers(_parse(command)) is None  # default min(4, CPUs), chosen by the extraction


def test_run_gives_the_workers_to_ray_and_no_decoding_threads(tmp_path, monkeypatch, seen):
    configs = []

    def fake_run(conf, dataset, out, executor=None):
        configs.append((conf.extract.workers, executor.name))
        raise KeyboardInterrupt

    monkeypatch.setattr("vpr_uncertainty.pipeline.run.run", fake_run)
    assert main(["run", "--dataset", "d", "--out", str(tmp_path), "--executor", "ray", "--workers", "2"]) == 130
    assert seen == {
        "name": "ray",
        "address": None,
        "workers": 2,
        "gpus_per_worker": 0.0,
        "connect_timeout": 30.0,
        "log_file": ray_log_file(),
    }
    assert configs == [(None, "ray")]


def test_run_keeps_the_decoding_threads_with_the_local_executor(tmp_path, monkeypatch, seen):
    configs = []

    def fake_run(conf, dataset, out, executor=None):
        configs.append(conf.extract.workers)
        raise KeyboardInterrupt

    monkeypatch.setattr("vpr_uncertainty.pipeline.run.run", fake_run)
    assert main(["run", "--dataset", "d", "--out", str(tmp_path), "--workers", "2"]) == 130
    assert seen == {"name": "local"}
    assert configs == [2]


@pytest.mark.parametrize("command", _COMMANDS)
def test_the_former_ray_workers_flag_is_refused(command, capsys):
    with pytest.raises(SystemExit) as exit_:
        _parse(command, "--executor", "ray", "--ray-workers", "3")
    assert exit_.value.code == 2 and "unrecognized arguments: --ray-workers" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["reproduce", "evaluate"])
def test_workers_without_a_local_meaning_are_refused_with_the_local_executor(command):
    with pytest.raises(ValueError, match="--workers: only with --executor ray"):
        executor_options(_parse(command, "--workers", "2"))


@pytest.mark.parametrize("command", _COMMANDS)
def test_the_ray_only_options_are_refused_with_the_local_executor(command):
    with pytest.raises(ValueError, match="--address, --gpus-per-worker: only with --executor ray"):
        executor_options(_parse(command, "--address", "auto", "--gpus-per-worker", "1"))


@pytest.mark.parametrize("command", _COMMANDS)
def test_zero_ray_workers_are_refused(command):
    with pytest.raises(ValueError, match="--workers 0: --executor ray needs at least 1 worker"):
        executor_options(_parse(command, "--executor", "ray", "--workers", "0"))


@pytest.mark.parametrize("command", _COMMANDS)
def test_help_explains_both_meanings(command, capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--workers N how many parallel workers. With --executor ray:" in text
    assert "With --executor local:" in text
    local = "image decoding threads" if command in ("run", "extract") else "it is refused"
    assert local in text.split("With --executor local:")[1].split("--gpus-per-worker")[0]


def test_evaluate_on_ray_without_geometric_verification_is_refused_before_ray_starts(
    corridor_matches_dir, corridor_dir, capsys, seen
):
    matrix = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    argv = ["evaluate", str(matrix), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--methods", "SU,BM"]
    assert main([*argv, "--executor", "ray", "--workers", "2"]) == 2
    assert "evaluate runs only geometric verification (GV-*, SCORE+GV) on Ray" in capsys.readouterr().err
    assert not seen
