"""Join the parts of one study, run as ``--part K/N`` in several processes or machines.

    python -m experiments.merge OUT PART [PART ...]
    python -m experiments.NAME --scale SCALE --resume --out OUT

Each PART is the ``--out`` folder of one part (its results.json and reconstructions.npz):
the same experiment, scale, config and seed. OUT gets every run of them together; the
experiment, resumed on OUT, then does any run no part finished and writes its report from
all of them. A run done in two parts, or parts of different studies, stop the merge.
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
    ``wall_seconds`` is their sum (the work, not the time it took side by side)."""
    if not parts:
        raise ValueError("merge: `parts` is empty; expected at least one --out folder.")
    out = Path(out)
    if any(Path(p).resolve() == out.resolve() for p in parts):
        raise ValueError(f"merge: `out` {out} is one of the parts; write the merge elsewhere.")
    merged: dict | None = None
    volumes: dict[str, np.ndarray] = {}
    done: set[tuple[str, str]] = set()
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
        for row in results["rows"]:
            run = (row["scene"], row["run"])
            if run in done:
                raise ValueError(f"merge: {run[0]} {run[1]} is in two parts (again in {part}).")
            done.add(run)
            merged["rows"].append(row)
        merged["histories"] |= results["histories"]
        merged["wall_seconds"] += results["wall_seconds"]
        merged["parts"].append(
            {"folder": str(part), "runs": len(results["rows"]), "versions": results["versions"]}
        )
        with np.load(part / "reconstructions.npz") as saved:
            volumes |= {key: saved[key] for key in saved.files}  # truths: the same in each
    check_writable(out)
    write_npz(out / "reconstructions.npz", volumes)
    write_json(out / "results.json", merged)
    return merged


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
