"""Bytes per rendezvous on the paper episode: polynomials vs raw points vs occupancy grid.

Runs ``simulate("paper", seed=0, exchange=...)`` once with an exchange that, for every message
it builds, also encodes the same meeting's data as the other payloads (SPEC §4, last point):

* polynomials — the landmarks changed since the last meeting (the paper's method);
* points — the sender's beam hit points since the last meeting;
* grid — a 2-bit occupancy raster (5 cm) of the sender's whole map.

Every figure includes the message header and the exchange trailer (see ``comms/exchange.py``).

Usage: ``python scripts/exchange_bytes.py [--seed 0]``
"""

from __future__ import annotations

import argparse

from polyslam_env.apps.simulate import simulate
from polyslam_env.comms.channel import ChannelConfig
from polyslam_env.comms.exchange import RendezvousExchange
from polyslam_env.core.seeding import make_rngs
from polyslam_env.world.config import WorldConfig

COLUMNS = (
    "polynomials/float32",
    "polynomials/float64",
    "points/float32",
    "points/float64",
    "grid/float32",
    "grid/float64",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    seed = parser.parse_args().seed
    wcfg = WorldConfig()
    exchange = RendezvousExchange(
        ChannelConfig(),
        3,
        make_rngs(seed, ["channel"])["channel"],
        wcfg.camera.sigma_d,
        wcfg.camera.sigma_bearing,
        max_range=wcfg.range_sensor.max_range,
        compare_payloads=True,
    )
    simulate("paper", seed=seed, exchange=exchange, world_config=wcfg)
    head = f"{'message':>10} {'step':>5} {'polys':>5} {'points':>6} {'grid':>8}"
    print(head + "".join(f" {c:>20}" for c in COLUMNS))
    for e in exchange.payload_log:
        grid = f"{e.grid_shape[0]}x{e.grid_shape[1]}"
        row = f"{f'r{e.sender + 1}->r{e.receiver + 1}':>10} {e.step:>5} {e.n_polynomials:>5}"
        row += f" {e.n_points:>6} {grid:>8}"
        print(row + "".join(f" {e.sizes[c]:>20}" for c in COLUMNS))
    if exchange.payload_log:
        n = len(exchange.payload_log)
        mean = {c: sum(e.sizes[c] for e in exchange.payload_log) / n for c in COLUMNS}
        base = mean["polynomials/float32"]
        print(
            f"{'mean':>10} {'':>5} {'':>5} {'':>6} {'':>8}"
            + "".join(f" {mean[c]:>20.0f}" for c in COLUMNS)
        )
        print(
            f"{'ratio':>10} {'':>5} {'':>5} {'':>6} {'':>8}"
            + "".join(f" {mean[c] / base:>20.2f}" for c in COLUMNS)
        )


if __name__ == "__main__":
    main()
