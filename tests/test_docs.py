"""The documentation site builds (``mkdocs build --strict``) and its examples run as written.

Every fenced Python block of ``docs/`` runs in an empty folder, and every ``bash`` block of the tutorials from an
empty folder of the development layout. A block that reads the real data takes its path from
``VPR_UNCERTAINTY_DATA`` (skipped without it, a failure under ``CI=true``, as the other real-data tests). A block
that cannot run here (a GPU, the internet, a cluster) must say so on the line before it, visibly:
``<!-- not run: REASON -->``; the test then reports it as skipped with that reason. A ``print(...)  # EXPECTED``
line must print EXPECTED. The examples of "Extend the toolkit" and "Architecture" have their own tests below.
"""

from __future__ import annotations

import ast
import importlib.util
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
EXTEND = DOCS / "how-to" / "extend.md"
ARCHITECTURE = DOCS / "explanation" / "architecture.md"
BLOCK = re.compile(r"(?:<!-- not run: (?P<reason>[^>]*?) -->\n)?```python\n(?P<code>.*?)```", re.S)


def _blocks(page: Path) -> list[tuple[str | None, str]]:
    """``(reason not run or None, code)`` of each fenced Python block of a page."""
    return [(match["reason"], match["code"]) for match in BLOCK.finditer(page.read_text(encoding="utf-8"))]


def _generic_blocks() -> list:
    """Every docs Python block except those with a dedicated test below."""
    params = []
    for page in sorted(DOCS.rglob("*.md")):
        if page in (EXTEND, ARCHITECTURE):
            continue
        for number, (reason, code) in enumerate(_blocks(page)):
            params.append(pytest.param(page, reason, code, id=f"{page.relative_to(DOCS)}:{number + 1}"))
    return params


def _ci() -> bool:
    return os.environ.get("CI", "").lower() in {"1", "true", "yes"}


# --- the site builds --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """``mkdocs build --strict`` (warnings are errors) into a temporary folder, offline; the built site."""
    needed = ("mkdocs", "material", "mkdocstrings_handlers")
    missing = [name for name in needed if importlib.util.find_spec(name) is None]
    if missing:
        message = f"the docs extra is not installed ({', '.join(missing)}): pip install -e '.[docs]'"
        if _ci():
            pytest.fail(message)
        pytest.skip(message)
    site = tmp_path_factory.mktemp("docs") / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"), "-d", str(site)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    return site


def test_docs_build_strict(site):
    home = (site / "index.html").read_text(encoding="utf-8")
    assert "Two commands" in home  # the front page is the README
    config_page = (site / "reference" / "reproduce-config.html").read_text(encoding="utf-8")
    assert "verify_fraction" in config_page and "precomputed_matches" in config_page
    api = (site / "api" / "scores.html").read_text(encoding="utf-8")
    assert "statistical_uncertainty" in api
    assert (site / "search" / "search_index.js").is_file()  # search from file:// (the offline plugin)


def test_site_navigates_from_the_file_system(site):
    """Every internal ``href``/``src`` of every page names an existing file (a folder would need a web server to
    show its index.html) and, with a ``#fragment``, an element with that id. The 404 page is left out: only a web
    server shows it, and its links are absolute on purpose."""
    pages = sorted(page for page in site.rglob("*.html") if page.name != "404.html")
    ids = {page: set(re.findall(r'\sid="([^"]*)"', page.read_text(encoding="utf-8"))) for page in pages}
    broken, checked = [], 0
    for page in pages:
        for link in re.findall(r'\s(?:href|src)="([^"]*)"', page.read_text(encoding="utf-8")):
            parts = urlsplit(link)
            if parts.scheme or parts.netloc:
                continue
            checked += 1
            target = (page.parent / unquote(parts.path)).resolve() if parts.path else page
            if not target.is_file():
                broken.append(f"{page.relative_to(site)}: {link} (no such file)")
            elif parts.fragment and target.suffix == ".html" and unquote(parts.fragment) not in ids[target]:
                broken.append(f"{page.relative_to(site)}: {link} (no such anchor)")
    assert checked > 1000 and not broken, broken[:20]


def test_api_pages_render_roles_and_lists(site):
    """The docstrings' Sphinx roles become links or code (docs/hooks/docstrings.py), none is left raw, and the
    numpydoc lists that follow their introducing line render as lists, reST tables as tables."""
    api = "".join(page.read_text(encoding="utf-8") for page in sorted((site / "api").glob("*.html")))
    raw = re.findall(r":(?:func|class|meth|data|attr|mod|exc|obj):[`<]", api)
    assert not raw, f"{len(raw)} raw roles"
    assert api.count("autorefs-internal") > 300  # the roles that name an API object link to it
    paragraphs = re.findall(r"<p>(.*?)</p>", api, re.S)
    assert not [text for text in paragraphs if re.search(r"\n\s*(?:[*-]|\d+\.) ", text)]
    assert not [text for text in paragraphs if "=====" in text]  # reST tables became tables
    assert "<td><code>descriptors.h5</code></td>" in api  # the table of pipeline.run's docstring
    scores = (site / "api" / "scores.html").read_text(encoding="utf-8")
    assert re.search(r'<li><a class="autorefs[^>]*href="#vpr_uncertainty.scores.ratio_spread"', scores)


def test_config_reference_is_generated_from_the_schema():
    """Every GridConfig field, every input key and every calibration key has a row, with the code's defaults."""
    import dataclasses

    spec = importlib.util.spec_from_file_location("config_reference", DOCS / "hooks" / "config_reference.py")
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    from vpr_uncertainty.pipeline.grid_config import CALIBRATION_DEFAULTS, GridConfig

    page = hook.render()
    for field in dataclasses.fields(GridConfig):
        assert f"| `{field.name}` |" in page, field.name
    assert "| `k` | `int` | `10` |" in page and "| `alpha` | `float` | `0.5` |" in page
    assert '`["RS", "SD", "SU", "PA", "L2", "BM"]`' in page  # methods: default_method_names()
    for key, default in CALIBRATION_DEFAULTS.items():
        assert f"| `{key}` | `{default}` |" in page


# --- the examples run -------------------------------------------------------------------------------------------


def _run(code: str, where: str, namespace: dict | None = None) -> dict:
    namespace = {"__name__": "docs"} if namespace is None else namespace
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exec(compile(code, where, "exec"), namespace)
    return namespace


def _expected_prints(code: str) -> list[str] | None:
    """The EXPECTED of each ``print(...)  # EXPECTED`` statement, when every print of the block has one."""
    lines = [line for line in code.splitlines() if line.startswith("print(")]
    expected = [re.search(r"\)\s+# (.+)$", line) for line in lines]
    return [match.group(1).strip() for match in expected] if lines and all(expected) else None


@pytest.mark.parametrize(("page", "reason", "code"), _generic_blocks())
def test_docs_python_block_runs(page, reason, code, request, tmp_path, monkeypatch, capsys):
    if reason is not None:
        pytest.skip(f"not run ({page.relative_to(DOCS)}): {reason}")
    if "VPR_UNCERTAINTY_DATA" in code:
        request.getfixturevalue("data_dir")  # skipped without the real data, a failure under CI
    monkeypatch.chdir(tmp_path)
    _run(code, str(page))
    expected = _expected_prints(code)
    if expected is not None:
        assert capsys.readouterr().out.splitlines() == expected


def test_docs_have_python_examples():
    """The generic test above has blocks to run (a regex that matched nothing would pass silently)."""
    assert _generic_blocks()


# --- "Extend the toolkit": one example per extension point, each checks itself ------------------------------------


def _registries() -> dict:
    from vpr_uncertainty.data import DATASET_FORMAT_REGISTRY
    from vpr_uncertainty.descriptors.models import MODELS, available_models
    from vpr_uncertainty.methods import METHODS
    from vpr_uncertainty.reports import REPORT_FIGURES

    available_models()  # the built-in models are registered on first use
    return {"method": METHODS, "model": MODELS, "dataset format": DATASET_FORMAT_REGISTRY, "figure": REPORT_FIGURES}


def test_extending_page_has_one_example_per_extension_point():
    registrations = [re.findall(r"^(register_\w+)\(", code, re.M) for _, code in _blocks(EXTEND)]
    assert registrations == [["register_method"], ["register_model"], ["register_format"], ["register_report_figure"]]


@pytest.mark.parametrize("number", range(4), ids=["method", "model", "dataset_format", "report_figure"])
def test_extending_example_runs(number, tmp_path, monkeypatch):
    """Each example runs in an empty folder, checks its own result, and imports from public modules only;
    what it registers is unregistered afterwards."""
    _, block = _blocks(EXTEND)[number]
    for node in ast.walk(ast.parse(block)):
        if isinstance(node, ast.ImportFrom) and node.module.startswith("vpr_uncertainty"):
            assert not any(part.startswith("_") for part in node.module.split(".")), node.module
            assert not any(alias.name.startswith("_") for alias in node.names), ast.unparse(node)
    registries = _registries()
    before = {kind: set(registry.names()) for kind, registry in registries.items()}
    monkeypatch.chdir(tmp_path)
    try:
        _run(block, f"{EXTEND} (example {number + 1})")
    finally:
        added = {kind: set(registry.names()) - before[kind] for kind, registry in registries.items()}
        for kind, names in added.items():
            for name in names:
                registries[kind].unregister(name)
    assert sum(len(names) for names in added.values()) == 1, added
    assert all(set(registry.names()) == before[kind] for kind, registry in registries.items())


def test_architecture_stage_example_runs(tmp_path, monkeypatch, capsys):
    """The example of running two stage modules from Python prints what its comment says and writes its files."""
    ((_, block),) = _blocks(ARCHITECTURE)
    monkeypatch.chdir(tmp_path)
    _run(block, str(ARCHITECTURE))
    path, auc_pr = capsys.readouterr().out.split()
    assert path == "runs/stages/retrieval.npz" and abs(float(auc_pr) - 0.956) <= 0.002  # another BLAS may round apart
    assert (tmp_path / "runs" / "stages" / "uncertainties.npz").is_file()


# --- the tutorials' shell blocks run as written -------------------------------------------------------------------

SHELL_BLOCK = re.compile(r"(?:<!-- not run: (?P<reason>[^>]*?) -->\n)?```bash\n(?P<code>.*?)```", re.S)
TUTORIALS = DOCS / "tutorials"


def _shell_blocks() -> list:
    params = []
    for page in sorted(TUTORIALS.glob("*.md")):
        for number, match in enumerate(SHELL_BLOCK.finditer(page.read_text(encoding="utf-8"))):
            params.append(pytest.param(page, match["reason"], match["code"], id=f"{page.name}:{number + 1}"))
    return params


def _expected_numbers(code: str) -> list[str]:
    """The numbers of a block's output comments (``#   ...``, three spaces): the output must hold each."""
    output = "\n".join(line for line in code.splitlines() if line.startswith("#   "))
    return re.findall(r"\d+(?:\.\d+)?", output)


@pytest.mark.parametrize(("page", "reason", "code"), _shell_blocks())
def test_tutorial_shell_block_runs(page, reason, code, request, tmp_path):
    """Each ``bash`` block of a tutorial runs with ``bash -e`` from an empty folder, as the tutorials say, in the
    development layout (``../shared/data`` is the real data, ``VPR_UNCERTAINTY_DATA`` points to it), with this
    checkout's ``vpr-uncertainty``; the page's first TOML block is there as ``reproduce.toml`` (the config its
    commands name). The numbers of its output comments appear in what it prints. A block that cannot run here says
    so on the line before it: ``<!-- not run: REASON -->``."""
    if reason is not None:
        pytest.skip(f"not run ({page.name}): {reason}")
    text = page.read_text(encoding="utf-8")
    folder = tmp_path / "work"
    folder.mkdir()
    data = None
    if "VPR_UNCERTAINTY_DATA" in code or "shared/data" in text:
        data = request.getfixturevalue("data_dir")  # skipped without the real data, a failure under CI
        (tmp_path / "shared").mkdir()
        (tmp_path / "shared" / "data").symlink_to(data.resolve())
    configs = re.findall(r"```toml\n(.*?)```", text, re.S)
    if configs:
        (folder / "reproduce.toml").write_text(configs[0], encoding="utf-8")
    bin_dir = Path(sys.executable).parent  # the environment's python and vpr-uncertainty entry point
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "NO_COLOR": "1"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")]))
    if data is not None:
        env["VPR_UNCERTAINTY_DATA"] = str(tmp_path / "shared" / "data")
    done = subprocess.run(["bash", "-e", "-c", code], cwd=folder, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, f"{page.name}: exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    missing = [number for number in _expected_numbers(code) if number not in done.stdout]
    assert not missing, f"{page.name}: {missing} not in the output:\n{done.stdout[-3000:]}"
    if page.name == "reproduce-the-study.md":
        _table1_evidence_matches(folder / "runs" / "reproduce" / "table1.md")


def _table1_evidence_matches(table1: Path) -> None:
    """The evidence page's Table 1 (the config's first input) has the cells of the tutorial's own run: the same
    AUC-PR, intervals and bold marks in each VPR-method column (the Mean and ms/query columns are the run's own)."""

    def columns(table: str) -> dict[str, list[str]]:
        lines = [line.strip("|").split("|") for line in table.strip().splitlines() if line.startswith("|")]
        header = [cell.strip() for cell in lines[0]]
        return {name: [line[index].strip() for line in lines[2:]] for index, name in enumerate(header)}

    spec = importlib.util.spec_from_file_location("table1_evidence", ROOT / "benchmarks" / "table1_evidence.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    page = columns(script.page_table((DOCS / "evidence" / "table1.md").read_text(encoding="utf-8")))
    run = columns(table1.read_text(encoding="utf-8").split("\n\n")[0])
    vpr_methods = [name for name in page if name not in ("method", "Mean", "ms/query")]
    assert len(vpr_methods) == 10 and page["method"] == run["method"]
    assert {name: page[name] for name in vpr_methods} == {name: run[name] for name in vpr_methods}


# --- shell examples name real commands --------------------------------------------------------------------------


def test_shell_examples_name_existing_commands():
    """Every ``vpr-uncertainty COMMAND`` in a bash block of the README or docs is a command of the CLI."""
    from vpr_uncertainty.pipeline import COMMANDS

    pages = [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]
    used = set()
    for page in pages:
        for block in re.findall(r"```bash\n(.*?)```", page.read_text(encoding="utf-8"), re.S):
            used |= set(re.findall(r"vpr-uncertainty (?:--plugin \S+ )?([a-z][\w-]*)", block))
    assert used and used <= set(COMMANDS), used - set(COMMANDS)
