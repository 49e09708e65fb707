"""Join the parts of one study, run as ``--part K/N`` in several processes or machines.

    python -m experiments.merge OUT PART [PART ...]
    python -m experiments.NAME --scale SCALE --resume --out OUT

Each PART is the ``--out`` folder of one part (its results.json and reconstructions.npz):
the same experiment, scale, config and seed. OUT gets every run of them together; the
experiment, resumed on OUT, then does any run no part finished and writes its report from
all of them. Parts may share runs they both resumed from (a merged folder copied into each,
then ``--part K/N --resume``): a run in two parts is kept once if its reconstruction is the
same, bit for bit; measured twice, or parts of different studies, it stops the merge.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from .runner import check_writable, write_json, write_npz

SAME = ("experiment", "scale", "config", "seed")  # what makes two parts one study


def merge(out: str | Path, parts: list[str | Path]) -> dict:
    """Write the runs of every folder in ``parts`` into ``out`` (results.json and
    reconstructions.npz); returns the merged results dict. The first part's notes and
    versions head the file; ``parts`` records each part's folder, versions and runs, and
    ``wall_seconds`` is the sum over the runs (the work, not the time it took side by side;
    as `execute` counts it, a support estimate shared by several runs once)."""
    if not parts:
        raise ValueError("merge: `parts` is empty; expected at least one --out folder.")
    out = Path(out)
    if any(Path(p).resolve() == out.resolve() for p in parts):
        raise ValueError(f"merge: `out` {out} is one of the parts; write the merge elsewhere.")
    merged: dict | None = None
    volumes: dict[str, np.ndarray] = {}
    for part in map(Path, parts):
        for name in ("results.json", "reconstructions.npz"):
            if not (part / name).exists():
                raise ValueError(f"merge: part {part} has no {name}.")
        results = json.loads((part / "results.json").read_text())
        if merged is None:
            merged = {k: v for k, v in results.items() if k != "failures"}  # judged anew
            merged |= {"rows": [], "histories": {}, "wall_seconds": 0.0, "parts": []}
        for key in SAME:
            if results[key] != merged[key]:
                raise ValueError(
                    f"merge: part {part} is another study ({key} {results[key]!r}, the first "
                    f"part's {merged[key]!r})."
                )
        with np.load(part / "reconstructions.npz") as saved:
            own = {key: saved[key] for key in saved.files}
        for row in results["rows"]:
            key = f"{row['scene']}/{row['run']}"
            if key in volumes:
                if not np.array_equal(volumes[key], own[key]):
                    raise ValueError(f"merge: {key} was measured in two parts (again in {part}).")
                continue  # a run both parts resumed from: kept once
            volumes[key] = own[key]
            merged["rows"].append(row)
            merged["histories"][key] = results["histories"][key]
            merged["wall_seconds"] += _work(row)
        volumes |= {key: value for key, value in own.items() if key.startswith("truth/")}
        merged["parts"].append(
            {"folder": str(part), "runs": len(results["rows"]), "versions": results["versions"]}
        )
    check_writable(out)
    write_npz(out / "reconstructions.npz", volumes)
    write_json(out / "results.json", merged)
    return merged


def _work(row: dict) -> float:
    """A run's share of a study's ``wall_seconds``: its own, less a support estimate it
    reused (``execute`` counts each estimate once)."""
    reused = row.get("support_seconds", 0.0) if row.get("support_reused") else 0.0
    return row["wall_seconds"] - reused


def cli(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.merge",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("out", type=Path, help="the folder to write the joined study to")
    parser.add_argument("parts", type=Path, nargs="+", help="each part's --out folder")
    args = parser.parse_args(argv)
    try:
        merged = merge(args.out, args.parts)
    except ValueError as error:
        parser.error(str(error))
    print(
        f"{len(merged['rows'])} runs from {len(args.parts)} parts in {args.out}/; resume the "
        f"{merged['experiment']} study there (--scale {merged['scale']} --resume --out "
        f"{args.out}) to finish it and write its report."
    )
    return merged


if __name__ == "__main__":
    cli()
