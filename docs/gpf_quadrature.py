"""Error of the truncated-moment quadrature by Gauss-Legendre order and difficulty
(docs/gpf.md section 10): the table behind ``_GL_ORDERS`` in trackers/gpf/grid.py.

    .venv/bin/python docs/gpf_quadrature.py [--n 200000]

Random Gaussians on the unit cell (position sds log-uniform in 0.03-8 cells, |rho| <= 0.97,
means up to a few sds off the cell); per row the largest error against a 96-node rule
(mass, first moments over the larger sd, second moments over its square) in bins of the
difficulty ``D = max(L / sigma_x, |k| L / s)``.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from mttbench.trackers.gpf import grid as gpf_grid

BINS = (0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0)
EDGES = list(zip(BINS[:-1], BINS[1:], strict=True))


def moments(mean, cov, nodes):
    """All pairs at one order (the module's table replaced for the call)."""
    saved = gpf_grid._GL_ORDERS, gpf_grid._GL_RULES
    gpf_grid._GL_ORDERS = ((math.inf, nodes),)
    gpf_grid._GL_RULES = {nodes: np.polynomial.legendre.leggauss(nodes)}
    try:
        z, o = np.zeros(len(mean)), np.ones(len(mean))
        return gpf_grid.rect_position_moments(mean, cov, z, o, z, o)
    finally:
        gpf_grid._GL_ORDERS, gpf_grid._GL_RULES = saved


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200_000)
    n = ap.parse_args().n
    rng = np.random.default_rng(1)
    sx, sy = np.exp(rng.uniform(np.log(0.03), np.log(8.0), (2, n)))
    rho = rng.uniform(-0.97, 0.97, n)
    cov = np.empty((n, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = sx * sx, sy * sy
    cov[:, 0, 1] = cov[:, 1, 0] = rho * sx * sy
    mean = rng.uniform(-3.0, 4.0, (n, 2)) * np.maximum(1.0, np.c_[sx, sy]) * 0.5
    k = cov[:, 0, 1] / cov[:, 0, 0]
    s = np.sqrt(cov[:, 1, 1] - cov[:, 0, 1] * k)
    L = np.maximum(np.minimum(1.0 - mean[:, 0], 7 * sx) - np.maximum(-mean[:, 0], -7 * sx), 0)
    D = np.maximum(L / sx, np.abs(k) * L / s)
    scale = np.maximum(sx, sy)
    ref = moments(mean, cov, 96)
    print("| nodes | " + " | ".join(f"D {a:g}-{b:g}" for a, b in EDGES) + " |")
    print("|---" * len(BINS) + "|")
    for q in (6, 8, 12, 16, 20, 24):
        r = moments(mean, cov, q)
        err = np.maximum.reduce([np.abs(r[0] - ref[0]), np.abs(r[1] - ref[1]).max(1) / scale,
                                 np.abs(r[2] - ref[2]).max((1, 2)) / scale**2])
        cells = [err[(D >= a) & (D < b)].max(initial=0.0) for a, b in EDGES]
        print(f"| {q} | " + " | ".join(f"{e:.0e}" for e in cells) + " |")


if __name__ == "__main__":
    main()
