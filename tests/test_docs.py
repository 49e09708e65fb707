"""The Python examples in docs/ run as written, and the site builds."""

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import docs_blocks, run_docs_block

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
# blocks that another test runs and checks the results of (each costs seconds of training)
ELSEWHERE = {
    ("rift.md", 1): "test_inr.py::test_coarse_to_fine_explains_what_the_coarse_grid_cannot",
}
ALL_BLOCKS = [
    (page.name, i) for page in sorted(DOCS.glob("*.md")) for i in range(len(docs_blocks(page.name)))
]
# blocks that train for 15-40 s (a first fit compiles most of it): CI's second command runs
# them (`pytest -m slow`, see .ci/run)
SLOW = {("quickstart.md", 0), ("rift.md", 0)}
BLOCKS = [
    pytest.param(*block, id=f"{block[0]}-{block[1]}", marks=[pytest.mark.slow] * (block in SLOW))
    for block in ALL_BLOCKS
    if block not in ELSEWHERE
]


@pytest.mark.parametrize("page, index", BLOCKS)
def test_docs_example_runs(page, index):
    run_docs_block(page, index)


def test_docs_have_examples():
    assert BLOCKS, "no ```python blocks found under docs/"
    assert SLOW <= set(ALL_BLOCKS), "a block named in SLOW is gone"
    for (page, index), test in ELSEWHERE.items():  # ... and the named test runs the block
        assert (page, index) in ALL_BLOCKS
        file, name = test.split("::")
        tree = ast.parse((ROOT / "tests" / file).read_text())
        (function,) = [f for f in tree.body if isinstance(f, ast.FunctionDef) and f.name == name]
        calls = [
            [ast.literal_eval(a) for a in node.args]
            for node in ast.walk(function)
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "run_docs_block"
        ]
        assert [page, index] in calls, f"{test} does not run {page} block {index}"


def test_site_builds(tmp_path):
    """``mkdocs build --strict`` (the API pages from the docstrings, the examples' code and
    figures, every link): ~6 s. Skipped where the docs requirements are not installed."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings_handlers.python")
    pytest.importorskip("griffe_public_redundant_aliases")
    build = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        timeout=300,
    )
    assert build.returncode == 0, build.stdout + build.stderr
    for page in ["index.html", "quickstart/index.html", "api/index.html"]:
        assert (tmp_path / page).is_file(), page
    api = (tmp_path / "api" / "index.html").read_text()
    assert 'id="rift_jax.fit"' in api and 'id="rift_jax.Scene"' in api
    # the function, though a module of the same name defines it (docs/api/griffe_rebound.py)
    solvers = (tmp_path / "api" / "solvers" / "index.html").read_text()
    assert 'id="rift_jax.solvers.kaczmarz"' in solvers
    for example in ["compare_solvers", "unseen_viewpoints", "custom_scene"]:
        page = (tmp_path / "examples" / example / "index.html").read_text()
        text = re.sub(r"<[^>]+>", "", page)  # the code is highlighted: one span per token
        assert f'src="../{example}.png"' in page and "def main(argv=None):" in text
        assert (tmp_path / "examples" / f"{example}.png").is_file()
