"""The coverage / map error / bytes trade-off of policies, as a figure (issue 44 item 3).

Each ``--point LABEL POLICY FILE...`` is one point: the episodes of ``POLICY`` in the
``polyslam evaluate --json`` FILEs (one per map), pooled: mean team coverage at the end against
the mean of the robots' ``nu_mean`` (left panel) and against the team's bytes sent (right),
with 95 % t intervals of the means as error bars. The points no other point beats on both
axes of a panel (more coverage and less ν, or less bytes) are joined: the Pareto front. The
numbers are printed as well, and each point's differences to the first point paired by map and
seed (95 % t intervals). A FILE holds one policy (``evaluate --policy P``) or several.

    python scripts/pareto.py --out docs/img/pareto.png \\
        --point "ppo_drive (map_error 0)" ppo_drive office.json warehouse.json \\
        --point "ppo_careful (map_error 100)" ppo_careful office.json warehouse.json
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from polyslam_env.metrics.statistics import t_half_width

#: The measures per episode, in the order printed.
MEASURES = ("coverage", "nu_mean", "map_precision", "bytes")


def _episodes(policy: str, files: list[str]) -> dict[str, np.ndarray]:
    """Per episode of ``policy`` in ``files``, ordered by map and seed: team coverage, the
    robots' mean ``nu_mean`` and ``map_precision``, the team's bytes sent."""
    rows = []
    for path in files:
        report = json.load(open(path))
        episodes = report["episodes"]
        if "policy" in report:  # one policy's file
            episodes = {report["policy"]: episodes}
        if policy not in episodes:
            raise SystemExit(f"{path}: no episodes of policy {policy!r}")
        for e in episodes[policy]:
            robots = list(e["robots"].values())
            mapped = [r for r in robots if r.get("has_map", 1.0)]
            rows.append(
                (
                    report["map"],
                    int(e["seed"]),
                    float(e["team"]["coverage"]),
                    float(np.mean([r["nu_mean"] for r in mapped])),
                    float(np.mean([r["map_precision"] for r in mapped])),
                    float(sum(r["bytes_sent"] for r in robots)),
                )
            )
    rows.sort(key=lambda r: (r[0], r[1]))
    columns = list(zip(*rows, strict=True))
    out = {name: np.array(columns[k + 2]) for k, name in enumerate(MEASURES)}
    out["key"] = np.array([f"{m}#{s}" for m, s, *_ in rows])
    return out


def _front(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the points no other point beats (lower x and higher y), by x."""
    keep = [
        i
        for i in range(len(x))
        if not any(
            (x[j] <= x[i]) & (y[j] >= y[i]) & ((x[j] < x[i]) | (y[j] > y[i])) for j in range(len(x))
        )
    ]
    return np.array(sorted(keep, key=lambda i: x[i]), dtype=int)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--point",
        nargs="+",
        action="append",
        required=True,
        metavar="LABEL POLICY FILE",
        help="a point: its label, the policy, and the evaluate --json files (repeatable)",
    )
    parser.add_argument("--out", default="pareto.png", help="figure file (default pareto.png)")
    args = parser.parse_args()
    labels, data = [], []
    for point in args.point:
        if len(point) < 3:
            raise SystemExit(f"--point {' '.join(point)}: needs LABEL POLICY FILE...")
        labels.append(point[0])
        data.append(_episodes(point[1], point[2:]))
    import matplotlib.pyplot as plt

    cov = np.array([d["coverage"].mean() for d in data])
    cov_err = np.array([t_half_width(d["coverage"]) for d in data])
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, key, scale, xlabel in (
        (axes[0], "nu_mean", 1000.0, "nu_mean (mm, robots' mean)"),
        (axes[1], "bytes", 1.0, "bytes sent (team, per episode)"),
    ):
        x = scale * np.array([d[key].mean() for d in data])
        x_err = scale * np.array([t_half_width(d[key]) for d in data])
        for i, label in enumerate(labels):
            ax.errorbar(
                x[i], cov[i], xerr=x_err[i], yerr=cov_err[i], fmt="o", capsize=3, label=label
            )
        front = _front(x, cov)
        ax.plot(x[front], cov[front], "k--", lw=0.8, label="Pareto front")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("team coverage at episode end")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.savefig(args.out, dpi=110)
    for i, label in enumerate(labels):
        d = data[i]
        print(
            f"{label}: coverage {cov[i]:.3f} ± {cov_err[i]:.3f}, nu_mean"
            f" {d['nu_mean'].mean():.4f} ± {t_half_width(d['nu_mean']):.4f} m, bytes"
            f" {d['bytes'].mean():.0f} ± {t_half_width(d['bytes']):.0f}, map_precision"
            f" {d['map_precision'].mean():.3f}"
            f" ({len(d['coverage'])} episodes)"
        )
    for i, label in enumerate(labels[1:], start=1):
        if not np.array_equal(data[i]["key"], data[0]["key"]):
            print(f"{label}: not the same maps and seeds as {labels[0]}, not paired")
            continue
        paired = ", ".join(
            f"{name} {d.mean():+.4g} ± {t_half_width(d):.2g}"
            for name in MEASURES
            for d in [data[i][name] - data[0][name]]
        )
        print(f"{label} − {labels[0]}, paired by map and seed (95 % t): {paired}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
