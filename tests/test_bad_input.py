"""Bad input, nothing lost.

The table of bad inputs in docs/solvers.md ("Bad input") is the test: each row's call runs
after the page's setup block, and must raise (or warn) as the row says, with the message
it shows. And an experiment interrupted mid-way resumes keeping every finished run as it
was, repeating none, with no half-written file left behind.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest

from experiments import merge, runner, stability

SOLVERS_MD = Path(__file__).resolve().parent.parent / "docs" / "solvers.md"
ROW = re.compile(r"^\| (?P<input>.+?) \| `(?P<call>.+?)` \| `(?P<kind>\w+)`: (?P<seen>.+) \|$")


def _section() -> str:
    text = SOLVERS_MD.read_text(encoding="utf-8")
    start = text.index("\n## Bad input\n")
    end = text.find("\n## ", start + 1)
    return text[start : None if end < 0 else end]


def _table() -> list[dict]:
    lines = [line for line in _section().splitlines() if line.startswith("| ")][1:]  # no header
    rows = []
    for line in lines:
        match = ROW.match(line)
        assert match, f"a row of the Bad input table does not parse: {line}"
        row = match.groupdict()
        row["message"], _, row["comment"] = row.pop("seen").partition(" — ")
        rows.append(row)
    return rows


TABLE = _table()


def _setup() -> str:
    return re.search(r"```python\n(.*?)```", _section(), re.S).group(1)


def _holds(seen: str, message: str) -> bool:
    """Whether ``message`` holds the documented text, "…" standing for anything."""
    return re.search(".*?".join(map(re.escape, seen.split("…"))), message, re.S) is not None


def test_the_table_covers_every_entry_point_and_kind_of_bad_input():
    calls = " ".join(row["call"] for row in TABLE)
    for entry in (
        "rj.fit(",
        "rj.synthesize(",
        "rj.grt_operator(",
        "rj.Scene(",
        "rj.Scene.empty(",
        "rj.scenes.",
        "rj.Radar(",
        "rj.Viewpoints(",
        "rj.estimate_support(",
        "rj.save(",
        "rj.load(",
        "rj.load_rift_public(",
        "rj.export_ply(",
        'cli("--out"',
    ):
        assert entry in calls, f"no row calls {entry}"
    inputs = [row["input"] for row in TABLE]
    for kind in (
        "NaN",
        "inf",
        "wrong shape",
        "not numbers",
        "empty support",
        "Viewpoints: empty",
        "zero signal",
        "granularity outside the extent",
        "zero granularity",
        "negative granularity",
        "zero extent",
        "negative extent",
        "unknown method",
        "unknown option",
        "unknown loss",
        "unknown recipe",
        "unknown model",
        "unknown name",
        "`--out` is a file",
    ):
        assert any(kind in text for text in inputs), f"no row tries {kind!r}"
    assert len({row["call"] for row in TABLE}) == len(TABLE), "a call appears twice"


@pytest.mark.parametrize("row", TABLE, ids=[row["input"] for row in TABLE])
def test_bad_input_gives_what_the_table_says(row, tmp_path, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("a run started before the command line was checked")

    monkeypatch.setattr(runner, "fit_and_evaluate", refuse)
    namespace: dict = {}
    exec(_setup(), namespace)
    (a_file := tmp_path / "notes.txt").write_text("")
    namespace["a_file"] = str(a_file)
    namespace["cli"] = lambda *args: stability.cli(["--scale", "quick", "--no-progress", *args])
    kind, seen, call = row["kind"], row["message"], row["call"]

    if kind == "ValueError":
        with pytest.raises(ValueError) as info:
            eval(call, namespace)
        message = str(info.value)
        # the argument, named: `name`, or an unknown option's name in a list
        assert re.search(r"`\w+`|\['\w+'\]", seen), f"the message names no argument: {seen}"
    elif kind == "SystemExit":
        stderr = io.StringIO()
        with pytest.raises(SystemExit) as info, contextlib.redirect_stderr(stderr):
            eval(call, namespace)
        assert info.value.code == 2  # argparse's usage error
        message = stderr.getvalue().replace(str(tmp_path), "…")
        assert "--" in seen, f"the message names no option: {seen}"
        assert not list(tmp_path.rglob(".*.tmp")), "the --out check left a file behind"
    elif kind == "UserWarning":
        with pytest.warns(UserWarning) as record:
            result = eval(call, namespace)
        message = str(record[0].message)
        # the zero signal: a result, not an error; the row says which
        assert f"`stopped` saying `{result.stopped.outcome}`" in row["comment"]
        assert not np.any(np.asarray(result.scene.reflectivity))
    elif kind == "AttributeError":
        # only a missing module attribute (a scene builder): Python's own error
        assert call.startswith("rj.scenes.") and "(" not in call
        with pytest.raises(AttributeError) as info:
            eval(call, namespace)
        message = str(info.value)
    else:
        pytest.fail(f"the table documents {kind}; bad input gives a ValueError")
    assert _holds(seen, message), f"documented: {seen!r}\nactual: {message!r}"


def test_holds_reads_the_ellipsis_as_anything():
    assert _holds("a `x`… got 3.", "a `x` must be good, got 3.")
    assert not _holds("a `x`… got 3.", "a `y` must be good, got 3.")
    assert not _holds("got 3.", "got 4.")


# --- Interrupted and resumed -----------------------------------------------------------


def _no_temporary_files(out: Path) -> None:
    assert not list(out.glob(".*.tmp")), "a half-written file was left behind"


@pytest.mark.slow
def test_an_interrupted_experiment_resumes_without_losing_or_repeating_a_run(tmp_path, monkeypatch):
    """experiments.stability at its quick scale, interrupted in the middle of its second
    run, then resumed."""
    argv = ["--scale", "quick", "--out", str(tmp_path), "--no-progress"]
    fit_and_evaluate = runner.fit_and_evaluate
    calls = []

    def interrupted_on_the_second(*args, **kwargs):
        calls.append(kwargs["method"])
        if len(calls) == 2:
            raise KeyboardInterrupt  # Ctrl-C in the middle of the second run
        return fit_and_evaluate(*args, **kwargs)

    monkeypatch.setattr(runner, "fit_and_evaluate", interrupted_on_the_second)
    with pytest.raises(KeyboardInterrupt):
        stability.cli(argv)
    _no_temporary_files(tmp_path)
    first = json.loads((tmp_path / "results.json").read_text())
    (kept,) = first["rows"]
    key = f"{kept['scene']}/{kept['run']}"
    with np.load(tmp_path / "reconstructions.npz") as saved:
        kept_volume = saved[key]

    calls.clear()

    def counted(*args, **kwargs):
        calls.append(kwargs["method"])
        return fit_and_evaluate(*args, **kwargs)

    monkeypatch.setattr(runner, "fit_and_evaluate", counted)
    results = stability.cli([*argv, "--resume"])
    _no_temporary_files(tmp_path)
    runs = stability.runs(stability.SCALES["quick"])
    assert len(calls) == len(runs) - 1, "a finished run was repeated, or one was skipped"
    assert [(r["scene"], r["run"]) for r in results["rows"]] == [(r.scene, r.label) for r in runs]
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["rows"] == json.loads(json.dumps(results["rows"]))
    # the finished run is kept as measured; only the verdicts that compare it with the
    # runs done since (stability's judge: its cell's median, failed or not) may change
    judged = {"noise", "cell_median", "cell_best", "failed"}
    assert {k: v for k, v in saved["rows"][0].items() if k not in judged} == {
        k: v for k, v in kept.items() if k not in judged
    }
    assert saved["histories"][key] == first["histories"][key]
    with np.load(tmp_path / "reconstructions.npz") as volumes:
        np.testing.assert_array_equal(volumes[key], kept_volume)
        assert all(f"{r['scene']}/{r['run']}" in volumes.files for r in saved["rows"])


@pytest.mark.slow
def test_a_study_run_in_parts_joins_into_the_whole(tmp_path, monkeypatch):
    """experiments.stability at its quick scale as parts 1 and 2 of 3 (in two folders),
    merged, then resumed: the resumed study runs part 3 alone and holds every run once."""
    argv = ["--scale", "quick", "--no-progress"]
    for k in (1, 2):
        stability.cli([*argv, "--out", str(tmp_path / f"part-{k}"), "--part", f"{k}/3"])
    merge.cli([str(tmp_path / "all"), str(tmp_path / "part-1"), str(tmp_path / "part-2")])
    fit_and_evaluate = runner.fit_and_evaluate
    calls = []

    def counted(*args, **kwargs):
        calls.append((kwargs["method"], len(args[1])))
        return fit_and_evaluate(*args, **kwargs)

    monkeypatch.setattr(runner, "fit_and_evaluate", counted)
    results = stability.cli([*argv, "--out", str(tmp_path / "all"), "--resume"])
    runs = stability.runs(stability.SCALES["quick"])
    assert calls == [(run.method, run.n_train) for run in runs[2::3]]
    done = sorted((r["scene"], r["run"]) for r in results["rows"])
    assert done == sorted((run.scene, run.label) for run in runs)
    assert (tmp_path / "all" / "results.md").exists()
    assert "in 2 parts run side by side" in (tmp_path / "all" / "results.md").read_text()


def test_an_interrupted_save_leaves_the_last_complete_files(tmp_path, monkeypatch):
    """Ctrl-C while a result is being renamed into place: the file on disk is still the
    previous, complete one, and the temporary file is gone."""
    path = tmp_path / "results.json"
    runner.write_json(path, {"rows": [1]})
    replace = runner.os.replace

    def interrupted(source, target):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        runner.write_json(path, {"rows": [1, 2]})
    monkeypatch.setattr(runner.os, "replace", replace)
    assert json.loads(path.read_text()) == {"rows": [1]}
    _no_temporary_files(tmp_path)
