"""Issue 20, row 13: grid cells on Ray never write the shared local-feature caches; a task's error is one line.

Two cells (NetVLAD and HOG on the corridor) share one dataset's images and GV-SIFT. Run as Ray tasks at once, both
used to open ``out/local_features/sift-*.h5`` for writing, and one in six runs died with ``BlockingIOError: unable
to lock file``, shown as a Ray traceback of thousands of characters. The module starts its own 2-CPU Ray cluster
whose workers refuse (and record) any opening of an HDF5 file under the grid's output folder for writing
(``worker_process_setup_hook``: a monkeypatch of the test process is not seen by the workers).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

pytest.importorskip("cv2")
ray = pytest.importorskip("ray")

from conftest import results_numbers  # noqa: E402
from vpr_uncertainty.executors import get_executor  # noqa: E402
from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_results  # noqa: E402

pytestmark = [pytest.mark.realdata, pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")]


@pytest.fixture(scope="module")
def guarded(tmp_path_factory):
    """A Ray cluster of 2 CPUs whose workers refuse to open an HDF5 file under ``shared`` for writing; each attempt
    leaves a file in ``log``."""
    shared = tmp_path_factory.mktemp("shared").resolve()
    log = tmp_path_factory.mktemp("writes_in_tasks").resolve()

    def forbid_writes() -> None:  # runs in every worker process; a local function, so Ray pickles it by value
        import h5py

        original = h5py.File

        class NoWrites(original):
            def __init__(self, name, mode="r", *args, **kwargs):
                if mode != "r" and isinstance(name, (str, os.PathLike)) and Path(name).resolve().is_relative_to(shared):
                    (log / f"{os.getpid()}-{len(list(log.iterdir()))}").write_text(f"{name} {mode}")
                    raise RuntimeError(f"a Ray task opened {name} for writing (mode {mode!r})")
                super().__init__(name, mode, *args, **kwargs)

        h5py.File = NoWrites

    os.environ["RAY_AUTH_MODE"] = "disabled"  # as conftest's ray_cluster: one authentication mode per session
    ray.init(
        address="local",
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        runtime_env={"worker_process_setup_hook": forbid_writes},
    )
    try:
        with get_executor("ray", workers=2) as executor:
            yield shared, log, executor
    finally:
        ray.shutdown()


def _grid(folder: Path, corridor_dir: Path, corridor_matches_dir: Path, scores: dict[str, Path] | None = None) -> Path:
    """Two cells on the corridor's images, with SU and GV-SIFT."""
    lines = ['out = "out"', 'methods = ["SU", "GV-SIFT"]', "alphas = []", "ks = []"]
    for method in ("NetVLAD", "HOG"):
        matrix = (scores or {}).get(method, corridor_matches_dir / method / "precomputed_data_corrected.npy")
        lines += [
            "[[inputs]]",
            f'vpr_method = "{method}"',
            'dataset = "corridor"',
            f'scores = "{matrix}"',
            f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"',
            f'images = "{corridor_dir}"',
        ]
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "grid.toml").write_text("\n".join(lines) + "\n")
    return folder / "grid.toml"


def _run(config_path: Path, executor=None) -> tuple[dict, list]:
    config = load_config(config_path)
    cells = run_grid(config, progress=False, executor=executor)
    return json.loads(write_results(cells, config)["results_json"].read_text()), cells


def _image_groups(handle: h5py.File) -> list[str]:
    """The names of the groups of an hloc-layout file that hold an image's features."""
    names: list[str] = []
    handle.visititems(
        lambda name, item: names.append(name) if isinstance(item, h5py.Group) and "keypoints" in item else None
    )
    return sorted(names)


def _cached_images(out: Path) -> dict[str, list[str]]:
    """The images of each local-feature cache file of a grid's output, by file name."""
    found = {}
    for path in sorted((out / "local_features").glob("*.h5")):
        with h5py.File(path, "r") as handle:
            found[path.name] = _image_groups(handle)
    return found


def test_the_workers_refuse_writes_under_the_shared_folder(guarded):
    _, _, executor = guarded

    def probe(_: int) -> str:
        import h5py

        return h5py.File.__name__

    assert executor.map(probe, [0, 1]) == ["NoWrites", "NoWrites"]  # the guard of the next test is armed


def test_gv_cells_on_ray_never_write_the_shared_feature_cache(guarded, tmp_path, corridor_dir, corridor_matches_dir):
    shared, log, executor = guarded
    remote, cells = _run(_grid(shared / "ray", corridor_dir, corridor_matches_dir), executor)
    assert not list(log.iterdir()), [path.read_text() for path in log.iterdir()]  # no task opened one for writing
    local, local_cells = _run(_grid(tmp_path / "local", corridor_dir, corridor_matches_dir))
    assert results_numbers(remote) == results_numbers(local)
    for cell, expected in zip(cells, local_cells, strict=True):  # −inliers are integers: exactly equal
        np.testing.assert_array_equal(cell.uncertainties()["GV-SIFT"], expected.uncertainties()["GV-SIFT"])
    assert cells[0].uncertainties()["GV-SIFT"].min() < 0  # some inliers were found
    # the driver wrote what the tasks extracted: the same cache as the local run's, which a rerun reads
    written = _cached_images(shared / "ray" / "out")
    assert written and written == _cached_images(tmp_path / "local" / "out")
    again, _ = _run(_grid(shared / "ray", corridor_dir, corridor_matches_dir), executor)
    assert results_numbers(again) == results_numbers(local) and not list(log.iterdir())


def test_a_cell_failing_in_a_ray_task_is_one_line(guarded, tmp_path, corridor_dir, corridor_matches_dir, capsys):
    from vpr_uncertainty.cli import main

    bad = tmp_path / "bad.npy"
    bad.write_bytes(b"not a similarity matrix\n" * 40)
    good = tmp_path / "HOG.npy"
    shutil.copy(corridor_matches_dir / "HOG" / "precomputed_data_corrected.npy", good)
    config = _grid(tmp_path, corridor_dir, corridor_matches_dir, {"NetVLAD": bad, "HOG": good})
    status = main(["reproduce", str(config), "--no-report", "--executor", "ray", "--workers", "2"])
    error = capsys.readouterr().err.strip()
    assert status == 2
    lines = [line for line in error.splitlines() if line.startswith("vpr-uncertainty")]
    assert len(lines) == 1 and "bad.npy" in lines[0] and len(lines[0]) < 400, error
    assert "Traceback" not in error and "ray::" not in error, error
