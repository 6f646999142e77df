"""Issue 10, items 5-7: method specs (SUE's published variant from the command line and the config), every need of
every grid cell checked before any work, and config errors that name the key, the value, the file and the line."""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty import evaluate
from vpr_uncertainty.cli import main
from vpr_uncertainty.methods import get_method, parse_method_spec, split_method_list
from vpr_uncertainty.pipeline import grid as reproduce_command
from vpr_uncertainty.pipeline.evaluate import method_list
from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_results
from vpr_uncertainty.retrieval import Retrieval, save_retrieval
from vpr_uncertainty.spatial import spatial_uncertainty


def _reproduce(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    reproduce_command.add_cli(parser.add_subparsers())
    args = parser.parse_args(["reproduce", *argv])
    return args.handler(args)


def _no_work(monkeypatch) -> None:
    import vpr_uncertainty.pipeline.grid as module

    def fail(*args, **kwargs):
        raise AssertionError("work started before the configuration was checked")

    monkeypatch.setattr(module, "run_cell", fail)


def _problems(config: Path) -> str:
    with pytest.raises(ValueError) as error:
        load_config(config)
    return str(error.value)


# --- method specs ---------------------------------------------------------------------------------------------


def test_method_spec_is_parsed_once_with_typed_values():
    assert parse_method_spec("SUE:clip=one-sided,slope=350") == ("SUE", {"clip": "one-sided", "slope": 350.0})
    assert parse_method_spec(" SU : alpha = 0.25 , k=5") == ("SU", {"alpha": 0.25, "k": 5})
    assert parse_method_spec("SUE") == ("SUE", {})
    variant = get_method("SUE:clip=one-sided, slope=300")
    assert variant.name == "SUE:clip=one-sided,slope=300" and variant.base == "SUE"
    assert variant.bound == {"clip": "one-sided", "slope": 300.0} and get_method("SUE").bound == {}
    assert split_method_list("SU,SUE:clip=one-sided,slope=300,SUE:slope=300,BM") == [
        "SU",
        "SUE:clip=one-sided,slope=300",
        "SUE:slope=300",
        "BM",
    ]


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("SUE:slop=300", "SUE has no option 'slop' (its options: clip, k, max_deviation, slope)"),
        ("BM:btl_haed=x", "BM has no option 'btl_haed' (its options: k)"),
        ("SUE:clip=both", "clip must be one of symmetric, one-sided, none, got 'both'"),
        ("SUE:slope=steep", "option 'slope' must be a finite number, got 'steep'"),
        ("SUE:slope=-1", "slope must be a finite number >= 0"),
        ("SU:alpha=1.5", "alpha must lie in [0, 1]"),
        ("SU:k=2.5", "option 'k' must be an integer, got '2.5'"),
        ("SUE:clip", "expected option=value after SUE:"),
        ("SUE:clip=one-sided,clip=none", "option 'clip' is given twice"),
        ("sue:clip=none", "did you mean 'SUE'"),
    ],
)
def test_bad_method_spec_is_one_clear_error(spec, message):
    with pytest.raises((ValueError, KeyError)) as error:
        get_method(spec)
    assert message in str(error.value.args[0])


def test_unknown_option_of_a_lazily_imported_method_is_an_error():
    """Regression: `btl_haed=` was dropped silently; options of a spec must be known to the method."""
    pytest.importorskip("torch")
    with pytest.raises(ValueError, match="BTL has no option 'btl_haed' \\(its options: allow_train_queries, btl_head"):
        get_method("BTL:btl_haed=head.pt")


def test_method_list_of_the_command_line_takes_specs():
    assert method_list("SU,SUE:clip=one-sided,slope=300") == ["SU", "SUE:clip=one-sided,slope=300"]
    with pytest.raises(argparse.ArgumentTypeError, match="SUE has no option 'clip_mode'"):
        method_list("SUE:clip_mode=one-sided")
    with pytest.raises(argparse.ArgumentTypeError, match="follows no method spec"):
        method_list("SU,slope=3")
    with pytest.raises(argparse.ArgumentTypeError, match="listed more than once: SU"):
        method_list("SU,BM,SU")


def _retrieval_from_positions(
    path: Path, n_queries: int = 300, k: int = 10
) -> tuple[Retrieval, np.ndarray, np.ndarray]:
    """A retrieval built from real camera positions: per query its 6 nearest database images and, at ranks 2 and
    8-10, images among the 200 farthest from it (deviations of hundreds of metres on both sides), close scores;
    every third query has the far image first (a wrong answer)."""
    poses = np.load(path)
    queries, database = poses["utmQ"][:n_queries].astype(np.float64), poses["utmDb"].astype(np.float64)
    rng = np.random.default_rng(0)
    squared = ((queries[:, None, :] - database[None, :, :]) ** 2).sum(axis=2)
    nearest = np.argsort(squared, axis=1)[:, :6]
    farthest = np.argpartition(-squared, 200, axis=1)[:, :200]
    picks = rng.permuted(np.tile(np.arange(200), (n_queries, 1)), axis=1)[:, :4]  # 4 distinct far images
    far = np.take_along_axis(farthest, picks, axis=1)
    indices = np.concatenate([nearest[:, :1], far[:, :1], nearest[:, 1:], far[:, 1:]], axis=1).astype(np.int64)
    indices[::3, :2] = indices[::3, 1::-1]  # every third answer wrong: a far image first
    scores = (0.9 - 0.002 * np.arange(k) - rng.uniform(0, 0.001, (n_queries, 1))).astype(np.float32)
    distances = np.maximum(2.0 - 2.0 * scores.astype(np.float64), 0.0).astype(np.float32)
    retrieval = Retrieval(
        scores=scores,
        indices=indices,
        positives=sparse.csr_array(squared <= 25.0**2),
        distances=distances,
        database_positions=database,
        config={"position_kind": "metres"},
    )
    return retrieval, indices, distances


@pytest.mark.realdata
def test_sue_one_sided_spec_reproduces_the_published_variant(data_dir, tmp_path, capsys):
    """`SUE:clip=one-sided` (the published code's min(500, Δ)) is the direct call, on real Pittsburgh30k and Tokyo
    24/7 positions; Pittsburgh30k's test area (540 m x 460 m) is too small for the 500 m clip to matter, so a
    smaller max_deviation shows there that the option reaches the function."""
    retrieval, indices, distances = _retrieval_from_positions(data_dir / "poses" / "pitts30k_test.npz")
    database = retrieval.database_positions
    published = spatial_uncertainty(indices, distances, database, clip="one-sided")
    np.testing.assert_allclose(get_method("SUE:clip=one-sided")(retrieval), published, rtol=1e-12)
    short = spatial_uncertainty(indices, distances, database, clip="one-sided", max_deviation=200, slope=300)
    assert (np.abs(short - spatial_uncertainty(indices, distances, database, max_deviation=200, slope=300)) > 1).any()
    np.testing.assert_allclose(
        get_method("SUE:clip=one-sided,max_deviation=200,slope=300")(retrieval), short, rtol=1e-12
    )
    tokyo, tokyo_indices, tokyo_distances = _retrieval_from_positions(data_dir / "poses" / "tokyo247.npz", 100)
    tokyo_published = spatial_uncertainty(tokyo_indices, tokyo_distances, tokyo.database_positions, clip="one-sided")
    tokyo_symmetric = spatial_uncertainty(tokyo_indices, tokyo_distances, tokyo.database_positions)
    assert (np.abs(tokyo_published - tokyo_symmetric) > 1.0).sum() > 10  # the 500 m clips differ here
    np.testing.assert_allclose(get_method("SUE:clip=one-sided")(tokyo), tokyo_published, rtol=1e-12)
    np.testing.assert_allclose(get_method("SUE")(tokyo), tokyo_symmetric, rtol=1e-12)

    # Side by side in one evaluation, under their specs; the spec's options win over the ones passed to all.
    evaluation = evaluate(retrieval, ["SUE", "SUE:clip=one-sided"], k=10, clip="none")
    np.testing.assert_allclose(evaluation.methods["SUE:clip=one-sided"].uncertainty, published, rtol=1e-12)
    unclipped = spatial_uncertainty(indices, distances, database, clip="none")
    np.testing.assert_allclose(evaluation.methods["SUE"].uncertainty, unclipped, rtol=1e-12)

    # The command line: `evaluate retrieval.npz --methods SUE,SUE:clip=one-sided`.
    path = tmp_path / "pitts.npz"
    save_retrieval(retrieval, path)
    out = tmp_path / "results.json"
    assert main(["evaluate", str(path), "--methods", "SUE,SUE:clip=one-sided", "--json", str(out)]) == 0
    methods = json.loads(out.read_text())["methods"]
    assert set(methods) == {"SUE", "SUE:clip=one-sided"} and methods["SUE:clip=one-sided"]["auc_pr"] > 0.5
    assert methods["SUE:clip=one-sided"]["auc_pr"] == pytest.approx(evaluation.methods["SUE:clip=one-sided"].auc_pr)
    assert "SUE:clip=one-sided" in capsys.readouterr().out

    # The config of `reproduce`: both variants in one cell, in results.csv, and read back from the cell cache.
    config_path = tmp_path / "grid.toml"
    config_path.write_text(
        f'out = "{tmp_path / "out"}"\nmethods = ["SUE", "SUE:clip=one-sided"]\nalphas = []\nks = []\n'
        f'[[inputs]]\nvpr_method = "toy"\ndataset = "pitts30k"\nscores = "{path}"\n'
    )
    for _ in range(2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            config = load_config(config_path)
            (cell,) = run_grid(config, progress=False)
        np.testing.assert_allclose(cell.evaluation.methods["SUE:clip=one-sided"].uncertainty, published, rtol=1e-12)
    assert cell.cached
    write_results([cell], config)
    assert "SUE:clip=one-sided" in (tmp_path / "out" / "results.csv").read_text()


# --- needs of every cell --------------------------------------------------------------------------------------


@pytest.mark.realdata
@pytest.mark.parametrize("check", [True, False])
def test_every_unmet_need_of_every_cell_is_listed_before_any_work(
    check, tmp_path, corridor_matches_dir, corridor_dir, monkeypatch
):
    """Regression: `--check` said OK for SUE without positions; GV-* and BTL failed only in their cell, one by one."""
    _no_work(monkeypatch)
    config = tmp_path / "grid.toml"
    config.write_text(
        f'out = "{tmp_path / "out"}"\nmethods = ["SU", "SUE", "GV-SIFT", "BTL", "SUE:clip=one-sided"]\n'
        f'[[inputs]]\nprecomputed_matches = "{corridor_matches_dir}"\n'
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\nvpr_methods = ["NetVLAD", "HOG"]\n'
    )
    with pytest.raises(ValueError) as error:
        _reproduce([str(config), *(["--check"] if check else [])])
    message = str(error.value)
    assert "10 problem(s)" in message
    for cell in ("NetVLAD", "HOG"):
        assert f"cell {cell} / corridor: SUE needs database_positions" in message
        assert f"cell {cell} / corridor: SUE:clip=one-sided needs database_positions" in message
        assert f"cell {cell} / corridor: GV-SIFT needs the query and database image files" in message
        assert f"cell {cell} / corridor: BTL needs a trained BTL head" in message
        assert f"cell {cell} / corridor: BTL needs the frozen descriptors" in message
    assert "SU needs" not in message
    assert not (tmp_path / "out").exists()


@pytest.mark.realdata
def test_needs_met_by_the_config_pass_the_check(tmp_path, data_dir, corridor_matches_dir, corridor_dir, capsys):
    """Images meet GV-*, options in the method name meet BTL, a retrieval file with positions meets SUE."""
    retrieval, _, _ = _retrieval_from_positions(data_dir / "poses" / "pitts30k_test.npz", n_queries=20)
    save_retrieval(retrieval, tmp_path / "pitts.npz")
    config = tmp_path / "grid.toml"
    config.write_text(
        f'out = "{tmp_path / "out"}"\nmethods = ["SU", "GV-SIFT"]\n'
        f'[[inputs]]\nprecomputed_matches = "{corridor_matches_dir}"\n'
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\nimages = "{corridor_dir}"\n'
    )
    assert _reproduce([str(config), "--check"]) == 0
    assert "10 cells x 2 uncertainty methods" in capsys.readouterr().out
    config.write_text(
        f'methods = ["SUE:clip=one-sided", "BTL:btl_head=h.pt,query_descriptors=d.h5,database_descriptors=d.h5"]\n'
        f'[[inputs]]\nvpr_method = "toy"\ndataset = "pitts30k"\nscores = "{tmp_path / "pitts.npz"}"\n'
    )
    if _btl_importable():
        assert _reproduce([str(config), "--check"]) == 0


def _btl_importable() -> bool:
    try:
        get_method("BTL").option_defaults()
    except ImportError:
        return False
    return True


def test_run_lists_every_unmet_need_before_extraction(tmp_path, corridor_dir, capsys, monkeypatch):
    import vpr_uncertainty.descriptors as features

    monkeypatch.setattr(features, "extract_descriptors", lambda *a, **k: pytest.fail("extraction started"))
    argv = ["run", "--dataset", str(corridor_dir), "--out", str(tmp_path / "run"), "--methods", "SUE,BTL,GV-H5"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "'SUE' needs database_positions, which dataset 'corridor' lacks" in err
    assert "'BTL' needs a trained BTL head" in err and "'GV-H5' needs precomputed local features" in err


# --- qualitative and config errors ----------------------------------------------------------------------------


@pytest.mark.realdata
def test_qualitative_typo_is_an_error_not_an_empty_figure(tmp_path, corridor_matches_dir, corridor_dir):
    base = (
        f'out = "{tmp_path / "out"}"\nmethods = ["SU"]\n'
        f'[[inputs]]\nprecomputed_matches = "{corridor_matches_dir}"\n'
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\n'
    )
    config = tmp_path / "grid.toml"
    config.write_text('qualitative = ["netvlad"]\n' + base + f'images = "{corridor_dir}"\n')
    assert "qualitative names 'netvlad', which is no VPR method of the grid; did you mean 'NetVLAD'?" in _problems(
        config
    )
    config.write_text('qualitative = "NetVLAD"\n' + base + f'images = "{corridor_dir}"\n')
    assert load_config(config).qualitative == ["NetVLAD"]  # one name, not its letters
    config.write_text('qualitative = ["NetVLAD"]\n' + base)
    assert "qualitative names 'NetVLAD', but no input of that VPR method has images" in _problems(config)


@pytest.mark.realdata
def test_single_inputs_table_and_unknown_vpr_methods_are_explained(tmp_path, corridor_matches_dir, corridor_dir):
    config = tmp_path / "grid.toml"
    config.write_text(
        f'[inputs]\nprecomputed_matches = "{corridor_matches_dir}"\n'
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\nvpr_methods = ["netvlad", "HOG", "Nope"]\n'
    )
    message = _problems(config)
    assert "inputs is a single table: write [[inputs]] (two brackets" in message
    assert "expected a table, got" not in message
    assert "vpr_methods has 'netvlad', which is not a folder of" in message
    assert "did you mean 'NetVLAD'? Folders there: AMOSNet, AlexNet_VPR, CALC" in message
    assert "vpr_methods has 'Nope'" in message and "'HOG'" not in message.split("Folders there")[0]


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ('alphas = ["x"]', "alphas must be a list of numbers, got 'x'"),
        ("alphas = 0.5", "alphas must be a list of numbers, got 0.5"),
        ("ks = [2.5, 5]", "ks must be a list of integers, got 2.5"),
        ('alpha = "half"', "alpha must be a real number in [0, 1], got 'half'"),
        ("alphas = [0.5, 1.5]", "alphas[1] must lie in [0, 1], got 1.5"),
        ("methods = 3", "methods must be a list of method names"),
        ('methods = ["SU", "SUE:clip=both"]', "clip must be one of symmetric, one-sided, none, got 'both'"),
        ('methods = ["SU", "SU"]', "method 'SU' is listed more than once"),
    ],
)
def test_bad_config_values_name_the_key_and_the_value(tmp_path, line, message):
    config = tmp_path / "grid.toml"
    config.write_text(f'{line}\n[[inputs]]\nvpr_method = "x"\ndataset = "d"\nscores = "missing.npz"\n')
    problems = _problems(config)
    assert message in problems and "scores file not found" in problems  # collected together


def test_toml_syntax_error_is_one_line_naming_file_and_line(tmp_path):
    config = tmp_path / "grid.toml"
    config.write_text('k = 10\nmethods = ["SU"\n[[inputs]]\n')
    with pytest.raises(ValueError) as error:
        load_config(config)
    assert str(error.value).startswith(f"{config}: invalid TOML:") and "line 3" in str(error.value)
    assert "\n" not in str(error.value)


def test_yaml_syntax_error_is_one_line_naming_file_and_line(tmp_path, capsys):
    pytest.importorskip("yaml")
    config = tmp_path / "grid.yaml"
    config.write_text("k: 10\nmethods: [SU\ninputs:\n  - scores: x.npz\n")
    assert main(["reproduce", str(config), "--check"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"vpr-uncertainty reproduce: error: {config}, line 3, column ") and "invalid YAML" in err
    assert "\n" not in err and "Traceback" not in err
