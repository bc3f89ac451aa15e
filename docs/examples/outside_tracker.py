"""A tracker written outside mttbench (the standard library only), for the README's example.

Nearest cell: a positive look marks its cell as holding a target, a negative look at that
cell clears it; each step it reports the centre of every marked cell, labelled by the
cell. It reads a world folder of ``mttbench export`` (``model_card.json``, ``looks.csv``)
and writes ``estimates.csv`` (step, x, y, label) into it for ``mttbench score``::

    python docs/examples/outside_tracker.py WORLD_DIR [WORLD_DIR ...]
"""

import csv
import json
import sys
from pathlib import Path

for world in map(Path, sys.argv[1:]):
    card = json.loads((world / "model_card.json").read_text())
    size, n_steps = card["grid"]["cell_size"], card["scenario"]["n_steps"]
    looks: dict[int, list[dict]] = {}
    with open(world / "looks.csv", newline="") as f:
        for row in csv.DictReader(f):
            looks.setdefault(int(row["step"]), []).append(row)
    marked: dict[int, tuple[int, int]] = {}  # cell -> (ix, iy)
    with open(world / "estimates.csv", "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["step", "x", "y", "label"])
        for k in range(n_steps):
            for row in looks.get(k, []):  # every look of the step, in the order made
                cell = int(row["cell"])
                if row["return"] == "1":
                    marked[cell] = (int(row["ix"]), int(row["iy"]))
                else:
                    marked.pop(cell, None)
            for cell, (ix, iy) in sorted(marked.items()):
                out.writerow([k, (ix + 0.5) * size, (iy + 0.5) * size, cell])
