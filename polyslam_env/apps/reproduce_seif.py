"""Reproduce seed 001's map fusion (Thrun & Liu, §5): one run cut into K pieces, fused blind.

A car of the kinematic world drives seed 003's first path (a loop) through a random landmark
field. One SEIF maps the whole run (the **single-run map**, started at the true initial pose,
so it lives in the world frame). The run's sweeps are then cut into K = ``pieces`` disjoint
stretches; each is mapped alone by a fresh SEIF that starts at the origin of its own frame —
no piece knows where it started relative to another. The pieces are fused into piece 0's
map by :mod:`polyslam_env.slam.points.seif_fusion` (triplet hypotheses, likelihood against a
per-landmark gain), trying every unfused piece against the growing map until none joins.

Per run: the fraction of pieces fused **correctly** (transform within 1 m and 3° of the truth,
the true pose at the piece's start seen from piece 0's; a wrong fusion counts as not
correct), the landmarks collapsed across different true landmarks (wrong collapses), and
the RMS landmark error of the fused map (in piece 0's frame) next to the single-run map's.
The seed reports that the fused map's error stays close to the single run's; the checks are
≥ 90 % of pieces fused correctly and the fused error within 2× the single-run error.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from polyslam_env.apps.jobs import Runner, run_jobs, succeeded
from polyslam_env.apps.reproduce_mblcc import matched_filter_config
from polyslam_env.core.blas import blas_threads
from polyslam_env.core.config import Config
from polyslam_env.core.errors import ConfigError
from polyslam_env.core.geometry import between, wrap_remainder
from polyslam_env.core.seeding import make_rngs
from polyslam_env.slam.points import PointMeasurements, PointSlamConfig
from polyslam_env.slam.points.seif import PointSeif
from polyslam_env.slam.points.seif_fusion import FusionConfig, InformationMap, find_fusion, fuse
from polyslam_env.world.kinematic import KinematicConfig, simulate_episode

__all__ = ["SeifReproduceConfig", "reproduce", "run_one", "summarise", "table_text"]

#: A fused piece further off than this is wrong (as in the alignment study: the transform
#: relates frames tens of metres apart through maps with their own drift).
WRONG_XY, WRONG_THETA_DEG = 1.0, 3.0


@dataclass(frozen=True)
class SeifReproduceConfig(Config):
    """The study's settings: seed 003's world on its first path with 300 landmarks and the
    quieter car and sensor of the alignment study."""

    runs: int = 10
    pieces: int = 8  # K
    max_active: int = 20
    world: KinematicConfig = field(
        default_factory=lambda: KinematicConfig(
            speeds=(4.0,),
            paths=(KinematicConfig().paths[0],),
            landmarks=300,
            sigma_v=0.1,
            sigma_g_deg=1.0,
            sigma_r=0.1,
            sigma_b_deg=1.0,
        )
    )
    slam: PointSlamConfig = field(default_factory=PointSlamConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)

    def validate(self) -> None:
        if self.runs < 1 or self.pieces < 2 or self.max_active < 1:
            raise ConfigError(
                f"runs >= 1, pieces >= 2 and max_active >= 1 needed, got {self.runs},"
                f" {self.pieces}, {self.max_active}"
            )

    def filter_config(self) -> PointSlamConfig:
        """The filters' settings with the world's true noise, period and wheelbase."""
        return matched_filter_config(self.slam, self.world)


def _info_map(seif: PointSeif) -> InformationMap:
    h, _ = seif.landmark_information()
    return InformationMap(seif.mu[3:].reshape(-1, 2).copy(), h, np.array(seif.ids, np.int64))


def _rms(means: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((means - truth) ** 2, axis=1))))


def run_one(config: SeifReproduceConfig, seed: int) -> dict[str, Any]:
    """One seeded run: single-run map, K pieces, fusion, metrics."""
    with blas_threads(1):
        episode = simulate_episode(config.world, seed)
        robot = episode.robots[0]
        cfg = config.filter_config()
        single = PointSeif(cfg, robot.initial_pose, config.max_active)
        sweeps = len(robot.sweeps)
        for k in range(sweeps):
            single.step(robot.controls[k], PointMeasurements(*robot.sweeps[k]))
        single_map = single.landmarks()
        single_rms = _rms(single_map.means, episode.landmarks[single_map.ids])

        cuts = np.linspace(0, sweeps, config.pieces + 1).round().astype(int)
        starts = [robot.initial_pose if c == 0 else robot.true_poses[c - 1] for c in cuts[:-1]]
        pieces = []
        for p in range(config.pieces):
            seif = PointSeif(cfg, np.zeros(3), config.max_active)
            for k in range(cuts[p], cuts[p + 1]):
                seif.step(robot.controls[k], PointMeasurements(*robot.sweeps[k]))
            pieces.append(_info_map(seif))

        rng = make_rngs(seed, ["fusion"])["fusion"]
        fused = pieces[0]
        frame0 = starts[0]
        outcome: dict[int, dict[str, Any]] = {}
        pending = list(range(1, config.pieces))
        progress = True
        while pending and progress:
            progress = False
            for p in list(pending):
                found = find_fusion(fused, pieces[p], rng, config.fusion)
                if found is None:
                    continue
                truth = between(frame0, starts[p], wrap_remainder)
                e = found.transform - truth
                e[2] = wrap_remainder(float(e[2]))
                wrong_pairs = int(
                    np.sum(fused.ids[found.pairs[:, 0]] != pieces[p].ids[found.pairs[:, 1]])
                )
                fused = fuse(fused, pieces[p], found)
                outcome[p] = {
                    "error": e.tolist(),
                    "pairs": len(found.pairs),
                    "wrong_pairs": wrong_pairs,
                    "correct": bool(
                        math.hypot(e[0], e[1]) <= WRONG_XY
                        and abs(math.degrees(e[2])) <= WRONG_THETA_DEG
                    ),
                }
                pending.remove(p)
                progress = True
        truth_in_frame0 = between(
            frame0,
            np.column_stack([episode.landmarks, np.zeros(len(episode.landmarks))]),
            wrap_remainder,
        )[:, :2]
        fused_rms = _rms(fused.means, truth_in_frame0[fused.ids])
    correct = sum(o["correct"] for o in outcome.values())
    return {
        "seed": seed,
        "single_rms": single_rms,
        "fused_rms": fused_rms,
        "pieces_fused": len(outcome),
        "pieces_correct": correct,
        "fraction_correct": correct / (config.pieces - 1),
        "wrong_collapses": sum(o["wrong_pairs"] for o in outcome.values()),
        "collapsed": sum(o["pairs"] for o in outcome.values()),
        "landmarks_fused_map": len(fused),
        "landmarks_single_map": len(single_map.ids),
        "pieces": {str(k): v for k, v in sorted(outcome.items())},
    }


def _job(job: tuple[SeifReproduceConfig, int]) -> dict[str, Any]:
    return run_one(*job)


def reproduce(
    config: SeifReproduceConfig,
    workers: int | Runner = 2,
    progress: Callable[[int], None] | None = None,
) -> list[dict[str, Any]]:
    jobs = [(config, s) for s in range(config.runs)]
    return succeeded(run_jobs(_job, jobs, workers, progress, seed_of=lambda job: job[1]))


def summarise(config: SeifReproduceConfig, runs: list[dict[str, Any]]) -> dict[str, Any]:
    frac = float(np.mean([r["fraction_correct"] for r in runs]))
    ratio = np.array([r["fused_rms"] / r["single_rms"] for r in runs])
    table = {
        "fraction_correct": frac,
        "single_rms_mean": float(np.mean([r["single_rms"] for r in runs])),
        "fused_rms_mean": float(np.mean([r["fused_rms"] for r in runs])),
        "fused_over_single_mean": float(ratio.mean()),
        "fused_over_single_max": float(ratio.max()),
        "wrong_collapses": int(sum(r["wrong_collapses"] for r in runs)),
        "collapsed": int(sum(r["collapsed"] for r in runs)),
    }
    checks = {
        "at_least_90pct_pieces_fused_correctly": frac >= 0.9,
        "fused_error_within_2x_single_run": bool(ratio.mean() <= 2.0),
    }
    return {
        "runs": len(runs),
        "pieces": config.pieces,
        "table": table,
        "checks": checks,
        "per_run": runs,
    }


def table_text(summary: dict[str, Any]) -> str:
    t = summary["table"]
    return "\n".join(
        [
            f"pieces fused correctly: {100 * t['fraction_correct']:.0f} %"
            f" ({summary['pieces'] - 1} per run; wrong collapses {t['wrong_collapses']}"
            f" of {t['collapsed']})",
            f"single-run map RMS error: {t['single_rms_mean']:.3f} m",
            f"fused map RMS error:      {t['fused_rms_mean']:.3f} m"
            f" ({t['fused_over_single_mean']:.2f}× the single run on average,"
            f" worst {t['fused_over_single_max']:.2f}×)",
        ]
    )
