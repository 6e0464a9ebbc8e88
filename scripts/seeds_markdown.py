"""The Markdown tables of the seed 003 and 004 results pages, from the reproductions' summaries.

Usage::

    python scripts/seeds_markdown.py --mblcc out/mblcc/summary.json \\
        --alignment out/alignment_seed/summary.json out/alignment_guarded/summary.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from polyslam_env.apps.reproduce_mblcc import COLUMNS, DIVERSITY, METRICS, PAPER_TABLE

METHODS = ("ransac", "svd", "icp", "imp_icp")


def _pm(cell: dict[str, float], key: str = "std", digits: int = 2) -> str:
    """mean ± ``key`` (std, or se for a difference, which gets its sign)."""
    sign = "+" if key == "se" else ""
    return f"{cell['mean']:{sign}.{digits}f} ± {cell[key]:.{digits}f}"


def mblcc_tables(summary: dict[str, Any]) -> str:
    """Table 1 (mean ± std over runs, the seed's mean in brackets), the paired differences,
    the EM sweep, and the diversity per column and per EM setting."""
    out = ["| robot | column | pose error (m) | landmark error (m) |", "|---|---|---|---|"]
    for r in range(3):
        for alg in COLUMNS:
            seed = PAPER_TABLE.get(alg)
            cells = [summary["table"][m][alg][r] for m in METRICS]
            refs = [f" ({seed[r][k]:.2f})" if seed else "" for k in (0, 2)]
            row = [_pm(c) + ref for c, ref in zip(cells, refs, strict=True)]
            out.append(f"| r{r + 1} | {alg} | {row[0]} | {row[1]} |")
    out += ["", "| pair (a − b) | metric | r1 | r2 | r3 |", "|---|---|---|---|---|"]
    for metric, pairs in summary["paired"].items():
        for pair, cells in pairs.items():
            text = " | ".join(_pm(c, "se", 3) for c in cells)
            out.append(f"| {pair} | {metric} | {text} |")
    out += ["", "| R × | moves | metric | r1 | r2 | r3 | team |", "|---|---|---|---|---|---|---|"]
    for cell in summary["em_sweep"]:
        for metric in METRICS:
            d = cell["paired"][metric]
            text = " | ".join(_pm(c, "se", 3) for c in [*d["robots"], d["team"]])
            out.append(f"| {cell['scale']:g} | {cell['passes']} | {metric} | {text} |")
    names = " | ".join(DIVERSITY)
    out += ["", f"| column | {names} |", "|---" * (len(DIVERSITY) + 1) + "|"]
    for alg in COLUMNS:
        out.append(
            f"| {alg} | {_diversity_row({m: summary['diversity'][m][alg] for m in DIVERSITY})}"
        )
    out += ["", f"| R × | moves | {names} |", "|---" * (len(DIVERSITY) + 2) + "|"]
    for cell in summary["em_sweep"]:
        row = _diversity_row(cell["diversity"])
        out.append(f"| {cell['scale']:g} | {cell['passes']} | {row}")
    return "\n".join(out)


def _diversity_row(cells: dict[str, list[dict[str, float]]]) -> str:
    """The robots' mean of each diversity measure (— where an episode was too short)."""
    means = [[c["mean"] for c in cells[m]] for m in DIVERSITY]
    return " | ".join("—" if None in v else f"{sum(v) / len(v):.3f}" for v in means) + " |"


def _answer(row: dict[str, Any]) -> str:
    if row["position_error_mean"] is None:
        return f"— ({100 * row['accepted']:.0f} %)"
    err = f"{row['position_error_mean']:.2f} ± {row['position_error_std']:.2f}"
    return f"{err} ({100 * row['accepted']:.0f} %)"


def alignment_table(summary: dict[str, Any]) -> str:
    """|Δt| mean ± std over the answers (share of runs answered) per aligner and stage."""
    rows = summary["table"]["ransac"]["stages"]
    head = " | ".join(str(r["stage"] + 1) for r in rows)
    out = [f"| aligner | {head} | all stages |", "|---" * (len(rows) + 2) + "|"]
    shared = " | ".join(f"{r['shared']:.0f}" for r in rows)
    out.append(f"| landmarks both maps hold | {shared} | |")
    for method in METHODS:
        cells = summary["table"][method]
        text = " | ".join(_answer(r) for r in cells["stages"])
        out.append(f"| {method} | {text} | {_answer(cells['all_stages'])} |")
    rate = summary["descriptor_wrong_match_rate"]["by_stage"]
    text = " | ".join("—" if r is None else f"{100 * r:.0f} %" for r in rate)
    out.append(f"| wrong descriptor matches | {text} | |")
    return "\n".join(out)


def confusion_table(summary: dict[str, Any]) -> str:
    """Over all stages per confusion probability; paired differences against RANSAC."""
    out = [
        "| confusion | wrong matches | "
        + " | ".join(METHODS)
        + " | "
        + " | ".join(f"{m} − ransac" for m in METHODS[1:])
        + " |",
        "|---" * (2 + 2 * len(METHODS) - 1) + "|",
    ]
    for p, cell in summary["by_confusion"].items():
        rate = cell["descriptor_wrong_match_rate"]
        text = " | ".join(_answer(cell["all_stages"][m]) for m in METHODS)
        paired = " | ".join(
            "—" if d["cells"] == 0 else f"{d['mean']:+.3f} ± {d['se']:.3f} ({d['cells']})"
            for d in cell["paired_against_ransac"].values()
        )
        out.append(f"| {float(p):g} | {100 * rate:.0f} % | {text} | {paired} |")
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mblcc", type=Path)
    parser.add_argument("--alignment", type=Path, nargs="*", default=[])
    args = parser.parse_args()
    if args.mblcc:
        print(mblcc_tables(json.loads(args.mblcc.read_text())), end="\n\n")
    for path in args.alignment:
        summary = json.loads(path.read_text())
        print(f"{summary['protocol']} protocol ({path}):\n")
        print(alignment_table(summary), end="\n\n")
        if len(summary["by_confusion"]) > 1:
            print(confusion_table(summary), end="\n\n")


if __name__ == "__main__":
    main()
