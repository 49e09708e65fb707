"""The scripts in docs/examples/ run as written and write sane figures and numbers.

They run in this one process, in this order, so that JAX compiles each solver once for
their shared shapes (the radar, grids and view counts are the same on purpose): compilation
is most of their time at these sizes, 10-25 s of one core per method. For that reason
compare_solvers runs two of its six methods here (its loop does the same for each; every
method is tested in test_fit.py, test_solvers.py and test_inr.py)."""

import json
import math
import runpy
from pathlib import Path

import pytest

# end to end, 30-85 s each: CI's second command runs them (`pytest -m slow`, see .ci/run)
pytestmark = pytest.mark.slow

EXAMPLES = Path(__file__).resolve().parent.parent / "docs" / "examples"


def run_example(name: str, out: Path, *options: str):
    """Run ``docs/examples/<name>.py --out out *options``; returns what its ``main`` returned."""
    main = runpy.run_path(str(EXAMPLES / f"{name}.py"), run_name=name)["main"]
    result = main(["--out", str(out), *options])
    png = out / f"{name}.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert json.loads((out / f"{name}.json").read_text()) == result
    return result


def test_compare_solvers(tmp_path, capsys):
    methods = ["lsmr", "rift-n"]  # the ones unseen_viewpoints runs too: compiled once
    rows = run_example("compare_solvers", tmp_path, "--methods", ",".join(methods))
    assert list(rows) == methods
    table = capsys.readouterr().out
    for method, row in rows.items():
        assert f"| {method} |" in table
        assert 0 <= row["m_ssim"] <= 1 and 0 <= row["t_iou"] <= 1 and 0 < row["m_cos"] <= 1
        assert 0 <= row["p_rmse"] <= math.pi and 0 < row["residual"] < 1.5
        assert row["seconds"] > 0 and row["iterations"] >= 1
    # every method finds the cube: far above an empty or random image
    assert min(row["m_ssim"] for row in rows.values()) > 0.2


def test_unseen_viewpoints(tmp_path):
    rows = run_example("unseen_viewpoints", tmp_path)
    # on the data's own grid the unseen views are predicted; on the coarser grid they are not
    assert rows["LSMR, 0.4 m grid"]["p_rmse"] < 0.1
    assert rows["LSMR, 0.8 m grid"]["p_rmse"] > 1.0
    assert all(0 <= row["p_rmse"] <= math.pi for row in rows.values())


def test_custom_scene(tmp_path):
    metrics = run_example("custom_scene", tmp_path)
    # every voxel of the T and the ball found; the residual is the 10 dB noise, √(0.1/1.1)
    assert metrics["t_iou"] == 1.0 and metrics["m_ssim"] > 0.5 and metrics["m_cos"] > 0.98
    assert 0.25 < metrics["residual"] < 0.35
