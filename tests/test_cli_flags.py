"""The command line speaks one language: --version, shared flags, one default method list, one name per flag."""

from __future__ import annotations

import pytest

from vpr_uncertainty.cli import build_parser, main, package_version
from vpr_uncertainty.methods import default_method_names


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"vpr-uncertainty {package_version()}"


@pytest.mark.parametrize("command", ["run", "extract"])
def test_run_and_extract_share_the_image_options(command):
    required = ["--dataset", "d", "--out", "o.h5" if command == "extract" else "o"]
    args = build_parser().parse_args(
        [command, *required, "--image-size", "224", "--max-side", "480", "--workers", "0", "--threads", "1"]
    )
    assert (args.image_size, args.max_side, args.workers, args.threads) == (224, 480, 0, 1)


def test_run_passes_the_image_options_to_the_extraction(tmp_path, monkeypatch):
    seen = {}

    def fake_run(conf, dataset, out, executor=None):
        seen.update(
            image_size=conf.extract.image_size, max_side=conf.extract.max_side, num_workers=conf.extract.workers
        )
        raise KeyboardInterrupt

    monkeypatch.setattr("vpr_uncertainty.pipeline.run.run", fake_run)
    argv = ["run", "--dataset", "d", "--out", str(tmp_path), "--image-size", "200", "--workers", "2"]
    assert main(argv) == 130
    assert seen == {"image_size": 200, "max_side": None, "num_workers": 2}


def test_one_default_method_list():
    assert default_method_names(metric_positions=True) == [*default_method_names(), "SUE"]
    assert "margin" not in default_method_names()  # run used to add it; evaluate never did


def test_run_and_demo_help_state_the_evaluate_default(capsys):
    for command in ("run", "demo", "evaluate"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([command, "--help"])
        assert ",".join(default_method_names()) in " ".join(capsys.readouterr().out.split()), command


@pytest.mark.parametrize(
    ("argv", "dest", "value"),
    [
        (["run", "--dataset", "d", "--out", "o", "--positive_dist_threshold", "10"], "radius", 10.0),
        (
            ["retrieve", "--database", "a", "--queries", "b", "--out", "r.npz", "--positive_dist_threshold", "5"],
            "radius",
            5.0,
        ),
        (["evaluate", "s.npy", "--positive_dist_threshold", "15"], "radius", 15.0),
        (["extract", "--dataset", "d", "--out", "o.h5", "--batch_size", "8"], "batch_size", 8),
        (["run", "--dataset", "d", "--out", "o", "--num_workers", "3"], "workers", 3),
        (["extract", "--dataset", "d", "--out", "o.h5", "--image_size", "320"], "image_size", 320),
        (["evaluate", "s.npy", "--queries_folder", "q", "--database_folder", "db"], "query_images", "q"),
    ],
)
def test_other_tools_flag_names_are_refused(argv, dest, value, capsys):
    """VPR-methods-evaluation's flag names were hidden aliases; one name per concept now (the aliases had a release)."""
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(argv)
    assert exit_.value.code == 2 and "unrecognized arguments" in capsys.readouterr().err
