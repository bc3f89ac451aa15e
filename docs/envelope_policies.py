"""The envelope under raster, renyi and search-track (docs/policies.md): per point and
tracker, OSPA under each policy and the paired differences (renyi - raster, search-track -
renyi), how often each comparison is beyond noise, and the best tracker-policy pair.

    python docs/envelope_policies.py RESULTS.parquet
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
from scipy import stats

POLICIES = ("raster", "renyi", "search-track")
CONTESTANTS = ("gpf", "pmb", "kfnn")


def paired(a: pd.Series, b: pd.Series) -> tuple[float, float]:
    """Mean of ``a - b`` over the seeds both have, and its 95% Student-t half-width."""
    d = (a - b).dropna()
    return float(d.mean()), float(stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1)
                                  / np.sqrt(len(d)))


def pm(d: float, h: float) -> str:
    return f"{d:+.3f} ± {h:.3f}" + (" *" if abs(d) > h else "")


def main(path: str) -> None:
    r = pd.read_parquet(path, columns=["scenario", "tracker", "policy", "seed", "ospa",
                                       "status"])
    m = r[r.status == "ok"].groupby(["scenario", "tracker", "policy", "seed"]).ospa.mean()
    lines, best, counts = [], [], {}
    for sc in sorted(m.index.get_level_values("scenario").unique()):
        runs = {}
        for tr in (*CONTESTANTS, "truth-aided"):
            s = {p: m[sc, tr, p] for p in POLICIES}
            d1, d2 = paired(s["renyi"], s["raster"]), paired(s["search-track"], s["renyi"])
            cells = " | ".join(f"{s[p].mean():.3f}" for p in POLICIES)
            lines.append(f"| `{sc}` | {tr} | {cells} | {pm(*d1)} | {pm(*d2)} |")
            if tr in CONTESTANTS:
                runs.update({(tr, p): s[p] for p in POLICIES})
                for what, (d, h) in (("renyi vs raster", d1), ("search-track vs renyi", d2)):
                    c = counts.setdefault((tr, what), [0, 0, 0])
                    c[0 if d + h < 0 else (2 if d - h > 0 else 1)] += 1
        order = sorted(runs, key=lambda k: runs[k].mean())
        d, h = paired(runs[order[1]], runs[order[0]])
        best.append(f"| `{sc}` | {' / '.join(order[0])} | {runs[order[0]].mean():.3f} | "
                    f"{' / '.join(order[1])} | {d:+.3f} ± {h:.3f}{' *' if d > h else ''} |")
    print("| point | tracker | " + " | ".join(POLICIES)
          + " | renyi − raster | search-track − renyi |")
    print("|---|---|---:|---:|---:|---:|---:|")
    print("\n".join(lines), end="\n\n")
    print("| tracker | comparison | better beyond noise | level | worse beyond noise |")
    print("|---|---|---:|---:|---:|")
    for (tr, what), (b, lv, w) in sorted(counts.items()):
        print(f"| {tr} | {what} | {b} | {lv} | {w} |")
    print()
    print("| point | best pair | OSPA | runner-up | runner-up − best |")
    print("|---|---|---:|---|---:|")
    print("\n".join(best))


if __name__ == "__main__":
    main(sys.argv[1])
