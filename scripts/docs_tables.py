"""Write the results pages' tables from the JSON their commands write, so none is retyped.

Each study (:data:`STUDIES`) has a page under ``docs/results/``, the command that measures it,
and a renderer that turns the command's JSON into the page's section between
``<!-- BEGIN generated: NAME -->`` and ``<!-- END generated: NAME -->``: the tables, the exact
command, its date, the machine and its load. Each study also writes its one-line headline
into that section, and README's results table is rebuilt from the pages' headlines.

    python scripts/docs_tables.py paper --run               # measure (the full command), write
    python scripts/docs_tables.py paper --run -- --runs 20  # ... with an option changed
    python scripts/docs_tables.py paper --from out/docs/paper  # write from a finished run

``--run`` runs the command with its output in ``--out`` (default ``out/docs/NAME``) and records
``run.json`` there (command, start and end in UTC, the 1-minute load before and after, the
machine, the wall time); ``--from`` reads both files from a folder (``run.json`` must be
there: a table without its date, machine and load is not written). A run with other options
than the study's full command is said so on the page, with the full command beside it.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
README = ROOT / "README.md"
HEADLINE = re.compile(r"<!-- headline: (.*?) -->")


@dataclass(frozen=True)
class Study:
    """A results page, the command that measures it and how its JSON becomes the page."""

    page: str  # under docs/results/
    title: str  # README's name of the study
    command: tuple[str, ...]  # the full measurement, shell lines; "{out}": the output folder
    outputs: tuple[str, ...]  # JSON files the command writes into "{out}"
    render: Callable[[Sequence[Any]], tuple[str, str]]  # JSON → (Markdown, headline)


def _checks_text(checks: Mapping[str, Any]) -> str:
    shown = {k: v for k, v in checks.items() if isinstance(v, bool)}
    passed = sum(shown.values())
    names = ", ".join(f"`{k}` {'yes' if v else 'no'}" for k, v in shown.items())
    return f"{passed} of {len(shown)} checks hold: {names}."


def render_paper(data: Sequence[Any]) -> tuple[str, str]:
    """Seed 002: the paper's Table 1 (``polyslam reproduce``'s summary.json)."""
    from polyslam_env.apps.reproduce import table_rows

    summary = data[0]
    rows = table_rows(summary)
    lines = ["| metric | r1 | r2 | r3 | paper r1 / r2 / r3 |", "|---|---|---|---|---|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    single = summary["r3_single"]["completeness"]
    multi = summary["table"]["completeness"][2]
    frac = summary["checks"]["r3_multi_beats_single_fraction_of_runs"]
    lines += [
        "",
        f"Mean ± std over {summary['runs']} runs. r3's completeness alone (the same inputs,"
        f" no exchange): {single['mean']:.3f} ± {single['std']:.3f}; with the exchange"
        f" {multi['mean']:.3f} ± {multi['std']:.3f}, better in {100 * frac:.0f} % of runs.",
    ]
    if summary.get("bytes_per_message"):
        b = summary["bytes_per_message"]
        lines.append(f"Bytes per message: {b['mean']:.0f} ({b['min']:.0f}–{b['max']:.0f}).")
    lines += ["", _checks_text(summary["checks"])]
    nu = " / ".join(f"{s['mean'] * 100:.1f}" for s in summary["table"]["nu_mean"])
    checks = [v for v in summary["checks"].values() if isinstance(v, bool)]
    headline = (
        f"`nu_mean` {nu} cm for r1 / r2 / r3 over {summary['runs']} runs;"
        f" {sum(checks)} of {len(checks)} checks hold"
    )
    return "\n".join(lines), headline


def render_app_table(module: str) -> Callable[[Sequence[Any]], tuple[str, str]]:
    """A study whose app (``polyslam_env.apps.<module>``) prints a plain-text table with its
    ``table_text``: that table and the summary's checks."""

    def render(data: Sequence[Any]) -> tuple[str, str]:
        summary = data[0]
        table_text = importlib.import_module(f"polyslam_env.apps.{module}").table_text
        text = f"```text\n{table_text(summary)}\n```\n\n{_checks_text(summary['checks'])}"
        checks = [v for v in summary["checks"].values() if isinstance(v, bool)]
        return text, f"{sum(checks)} of {len(checks)} checks hold ({summary['runs']} runs)"

    return render


def _seeds_markdown() -> Any:
    """``scripts/seeds_markdown.py``, the one writer of the seed pages' Markdown tables."""
    sys.path.insert(0, str(Path(__file__).parent))
    return importlib.import_module("seeds_markdown")


def render_mblcc(data: Sequence[Any]) -> tuple[str, str]:
    """Seed 003: Table 1 beside the seed's, paired differences, the EM sweep, diversity."""
    summary = data[0]
    text = f"{_seeds_markdown().mblcc_tables(summary)}\n\n{_checks_text(summary['checks'])}"
    checks = [v for v in summary["checks"].values() if isinstance(v, bool)]
    return (
        text,
        f"{sum(checks)} of {len(checks)} checks of the seed's orderings hold for every robot at"
        f" once ({summary['runs']} runs; the page says which hold in part)",
    )


def render_alignment(data: Sequence[Any]) -> tuple[str, str]:
    """Seed 004 under the seed's protocol, then under the guarded one."""
    tables = _seeds_markdown()
    parts, heads = [], []
    for summary in data:
        parts.append(f"**{summary['protocol']} protocol** ({summary['runs']} runs):\n")
        parts.append(tables.alignment_table(summary) + "\n")
        if len(summary["by_confusion"]) > 1:
            parts.append(tables.confusion_table(summary) + "\n")
        parts.append(_checks_text(summary["checks"]) + "\n")
        checks = [v for v in summary["checks"].values() if isinstance(v, bool)]
        heads.append(f"{summary['protocol']}: {sum(checks)} of {len(checks)} checks hold")
    return "\n".join(parts), f"{'; '.join(heads)} ({data[0]['runs']} runs)"


def render_seif(data: Sequence[Any]) -> tuple[str, str]:
    """Seed 001: the blind fusion of one run's pieces."""
    text, _ = render_app_table("reproduce_seif")(data)
    t = data[0]["table"]
    headline = (
        f"{100 * t['fraction_correct']:.0f} % of pieces fused correctly, fused map error"
        f" {t['fused_over_single_mean']:.2f}× the single run's ({data[0]['runs']} runs)"
    )
    return text, headline


def render_fidelity(data: Sequence[Any]) -> tuple[str, str]:
    """The large floors: ``polyslam fidelity``'s own Markdown (tables, checks, misses)."""
    from polyslam_env.apps.fidelity import markdown

    summary = data[0]
    text = markdown(summary)
    on = [by["exchange_on"] for by in summary["table"].values()]
    precision = min(t["map_precision"]["min"] for t in on)
    nu = max(t["nu_mean"]["max"] for t in on)
    failed = [f"{m} `{c}`" for m, checks in summary["checks"].items() for c, ok in checks.items()
              if not ok]  # fmt: skip
    passed = "every check holds" if not failed else "fails: " + ", ".join(failed)
    seeds = summary.get("settings", {}).get("seeds", "?")
    headline = (
        f"with the exchange: worst robot `map_precision` {precision:.3f}, worst `nu_mean`"
        f" {100 * nu:.1f} cm on {', '.join(summary['table'])} ({seeds} seeds); {passed}"
    )
    return text, headline


def render_speed(data: Sequence[Any]) -> tuple[str, str]:
    """``polyslam benchmark --json``: the targets with this run's figures, and the machine."""
    results = data[0]
    lines = ["| figure | measured | target | met |", "|---|---|---|---|"]
    for r in results["targets"]:
        value = "—" if r["measured"] is None else f"{r['measured']:.3g}"
        goal = ("≤ " if r["at_most"] else "≥ ") + f"{r['goal']:g}"
        if r["met"] is False and value == f"{r['goal']:.3g}":  # a miss rounding onto the goal
            value = f"{r['measured']:.4g}"
        met = "not measured" if r["met"] is None else "yes" if r["met"] else "no"
        lines.append(f"| {r['target']} | {value} | {goal} | {met} |")
    m = results["machine"]
    lines += [
        "",
        f"BLAS {m['blas']}, numpy {m['numpy']}, pymunk {m['pymunk']}, Python {m['python']};"
        f" the benchmark's own 1-minute load readings: {m.get('load_before')} before,"
        f" {m.get('load_after')} after.",
    ]
    measured = [r for r in results["targets"] if r["met"] is not None]
    ratio = next((r["measured"] for r in measured if "MPE" in r["target"]), None)
    headline = f"{sum(r['met'] for r in measured)} of {len(measured)} speed targets met"
    if ratio is not None:
        headline += f"; full-SLAM env at {ratio:.2f}× PettingZoo MPE's steps/s"
    return "\n".join(lines), headline


def render_learning(data: Sequence[Any]) -> tuple[str, str]:
    """``polyslam evaluate --policy frontier,frontier_team,random,ppo,ppo_drive,ppo_careful
    --json`` on each map (issue 44's policies)."""
    lines = [
        "| map | policy | team coverage | steps to 90 % | `nu_mean` (m) | bytes sent |",
        "|---|---|---|---|---|---|",
    ]
    cover: dict[str, list[float]] = {}
    for report in data:
        for policy, stats in report["comparison"].items():
            c, s = stats["coverage"], stats["steps_to_90"]
            if s["reached"]:
                reached = (
                    f"{s['mean']:.0f} ± {s['std']:.0f} ({s['reached']:.0f}/{s['episodes']:.0f})"
                )
            else:  # no episode reached 90 %: no mean, no spread
                reached = f"never (0/{s['episodes']:.0f})"
            lines.append(
                f"| {report['map']} | {policy} | {c['mean']:.3f} ± {c['std']:.3f} | {reached} |"
                f" {stats['nu_mean']['mean']:.4f} | {stats['bytes_sent']['mean']:.0f} |"
            )
            cover.setdefault(policy, []).append(c["mean"])
    mean = {p: sum(v) / len(v) for p, v in cover.items()}
    headline = ", ".join(f"{p} {v:.3f}" for p, v in mean.items())
    return "\n".join(lines), f"team coverage on held-out layouts: {headline}"


STUDIES: dict[str, Study] = {
    "fidelity": Study(
        "fidelity.md",
        "Fidelity on large floors",
        ("polyslam fidelity --seeds 20 --steps 600 --workers 2 --out {out}",),
        ("summary.json",),
        render_fidelity,
    ),
    "paper": Study(
        "paper.md",
        "Seed 002: the paper's Table 1",
        ("polyslam reproduce --runs 100 --out {out}",),
        ("summary.json",),
        render_paper,
    ),
    "mblcc": Study(
        "mblcc.md",
        "Seed 003: MBLCC FastSLAM",
        (
            "polyslam reproduce --paper mblcc --config configs/mblcc_tables.yaml --runs 50"
            " --out {out}",
        ),
        ("summary.json",),
        render_mblcc,
    ),
    "alignment": Study(
        "alignment.md",
        "Seed 004: map alignment",
        (
            "polyslam reproduce --paper alignment --protocol seed --runs 10 --out {out}/seed",
            "polyslam reproduce --paper alignment --protocol guarded --runs 10 --out {out}/guarded",
        ),
        ("seed/summary.json", "guarded/summary.json"),
        render_alignment,
    ),
    "seif": Study(
        "seif.md",
        "Seed 001: SEIF fusion",
        ("polyslam reproduce --paper seif --runs 10 --out {out}",),
        ("summary.json",),
        render_seif,
    ),
    "learning": Study(
        "learning.md",
        "Learning",
        (
            "polyslam evaluate --policy frontier,frontier_team,random,ppo,ppo_drive,ppo_careful"
            " --map generator:office_floor --seed 10000 --episodes 20 --json {out}/office.json",
            "polyslam evaluate --policy frontier,frontier_team,random,ppo,ppo_drive,ppo_careful"
            " --map generator:warehouse --seed 10000 --episodes 20 --json {out}/warehouse.json",
        ),
        ("office.json", "warehouse.json"),
        render_learning,
    ),
    "speed": Study(
        "speed.md",
        "Speed",
        ("polyslam benchmark --json {out}/benchmark.json",),
        ("benchmark.json",),
        render_speed,
    ),
}


def commands(study: Study, out: str, extra: Sequence[str] = ()) -> list[list[str]]:
    """The study's command lines with ``{out}`` filled in and ``extra`` options appended to
    each, as argument lists."""
    return [shlex.split(line.replace("{out}", out)) + list(extra) for line in study.command]


def full_command(study: Study, out: str = "OUT") -> str:
    return " && ".join(shlex.join(c) for c in commands(study, out))


def machine() -> str:
    """Cores, CPU model, OS and Python of this machine."""
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            names = (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name"))
            cpu = next(names, cpu)
    except OSError:
        pass
    return (
        f"{os.cpu_count()} cores, {cpu}, {platform.system()} {platform.release()},"
        f" Python {platform.python_version()}"
    )


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _load() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "unknown"


def run(study: Study, out: Path, extra: Sequence[str]) -> dict[str, Any]:
    """Run the study's command(s) into ``out``; write and return ``run.json``."""
    out.mkdir(parents=True, exist_ok=True)
    started, load_before, t0 = _now(), _load(), time.time()
    lines = commands(study, str(out), extra)
    for line in lines:
        subprocess.run(line, check=True)
    meta = {
        "command": " && ".join(shlex.join(c) for c in lines),
        "started": started,
        "finished": _now(),
        "load_before": load_before,
        "load_after": _load(),
        "wall_s": round(time.time() - t0),
        "machine": machine(),
    }
    (out / "run.json").write_text(json.dumps(meta, indent=1))
    return meta


def section(name: str, study: Study, data: Sequence[Any], meta: Mapping[str, Any]) -> str:
    """The page's generated section: how it was made, then the study's tables."""
    body, headline = study.render(data)
    full = full_command(study)
    made = meta["command"].replace(" && ", "`, then `")
    lines = [
        f"<!-- headline: {headline} -->",
        f"Generated by `python scripts/docs_tables.py {name}` from the JSON of `{made}`,",
        f"run {meta['started'][:10]} {meta['started'][11:16]}–{meta['finished'][11:16]} UTC"
        f" ({meta['wall_s'] / 60:.0f} min) on {meta['machine']}; load averages (1, 5, 15 min)"
        f" {meta['load_before']} before, {meta['load_after']} after.",
    ]
    if _normalised(meta["command"]) != _normalised(full):
        lines.append(
            f"**A smaller run than the study's own**, which is `{full}` (`python"
            f" scripts/docs_tables.py {name} --run` runs it and rewrites this section)."
        )
    return "\n".join([*lines, "", body])


def _normalised(command: str) -> str:
    """A command without its output paths and the options that change no figure (progress
    bars, pictures), to compare runs of the same measurement."""
    command = re.sub(r"(--out|--json) \S+", r"\1", command)
    return re.sub(r" --(quiet|no-pictures)\b", "", command)


def replace_section(text: str, name: str, content: str) -> str:
    """``text`` with the section ``name`` (its BEGIN and END marks kept) holding ``content``."""
    begin, end = f"<!-- BEGIN generated: {name} -->", f"<!-- END generated: {name} -->"
    if text.count(begin) != 1 or text.count(end) != 1:
        raise SystemExit(f"docs_tables: {name}: the page needs one {begin!r} and one {end!r}")
    head, rest = text.split(begin)
    _, tail = rest.split(end)
    return f"{head}{begin}\n{content}\n{end}{tail}"


def headline_table(results: Path = RESULTS) -> str:
    """README's results table: one line per study, its headline read from its page."""
    lines = ["| study | headline | page |", "|---|---|---|"]
    for study in STUDIES.values():
        page = results / study.page
        found = HEADLINE.search(page.read_text()) if page.exists() else None
        text = found.group(1) if found else "not measured yet: the page has the command"
        link = f"docs/results/{study.page}"
        lines.append(f"| {study.title} | {text} | [{link}]({link}) |")
    return "\n".join(lines)


def write(name: str, folder: Path, results: Path = RESULTS, readme: Path = README) -> None:
    """Rewrite study ``name``'s page section from ``folder`` and README's results table."""
    study = STUDIES[name]
    meta_path = folder / "run.json"
    if not meta_path.exists():
        raise SystemExit(f"docs_tables: {meta_path}: missing (the run's date, machine and load)")
    meta = json.loads(meta_path.read_text())
    data = []
    for output in study.outputs:
        path = folder / output
        if not path.exists():
            raise SystemExit(f"docs_tables: {path}: missing (did the command finish?)")
        data.append(json.loads(path.read_text()))
    page = results / study.page
    page.write_text(replace_section(page.read_text(), name, section(name, study, data, meta)))
    readme.write_text(replace_section(readme.read_text(), "headline", headline_table(results)))
    print(f"wrote {page} and {readme}'s results table")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("study", choices=sorted(STUDIES))
    how = parser.add_mutually_exclusive_group(required=True)
    how.add_argument("--run", action="store_true", help="run the study's command, then write")
    how.add_argument("--from", dest="folder", help="write from a finished run's folder")
    parser.add_argument("--out", help="--run's output folder (default out/docs/STUDY)")
    parser.add_argument("extra", nargs="*", help="after --: options appended to the command")
    args = parser.parse_args(argv)
    if args.run:
        folder = Path(args.out or f"out/docs/{args.study}")
        run(STUDIES[args.study], folder, args.extra)
    else:
        folder = Path(args.folder)
    write(args.study, folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
