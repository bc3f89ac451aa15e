"""Draw the sixth held-out sample's positions at random, before looking at the code.

The production modules (``scenarios/``, ``trackers/``, ``benchmarks/engine/``,
``benchmarks/app/``, every ``*.py`` below them) are parsed with ``ast``; each statement
node (``ast.stmt``, nested ones included) counts once, except docstrings, imports and a
bare ``pass``. A file's weight is its count, so drawing uniformly over all the statements
draws a file with probability proportional to its count. The draw is a permutation of
all statements by ``numpy.random.default_rng(SeedSequence(6))``; the sample takes the
first 40 whose line shares no line with an earlier sample's ``original`` in the same file
(``tests/mutation/mutants.toml``, ``docs/mutation_heldout*.toml`` 1-5); a drawn position
skipped is printed as such. The next 20 are printed as spares (a position that cannot
hold any behaviour-changing bug in its function is replaced by the next spare).

Usage: .venv/bin/python docs/mutation_heldout_6_draw.py   (one line per position)"""
import ast
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ["scenarios", "trackers", "benchmarks/engine", "benchmarks/app"]
EARLIER = ["tests/mutation/mutants.toml", "docs/mutation_heldout.toml",
           *(f"docs/mutation_heldout_{k}.toml" for k in range(2, 6))]
N, SPARES = 40, 20


def _counted(node: ast.stmt) -> bool:
    if isinstance(node, (ast.Import, ast.ImportFrom, ast.Pass)):
        return False
    return not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
                and isinstance(node.value.value, str))


def statements() -> list[tuple[str, int]]:
    """Every counted statement as (file relative to the root, first line), files sorted."""
    out = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            tree = ast.parse(path.read_text(), filename=rel)
            out += sorted((rel, n.lineno) for n in ast.walk(tree)
                          if isinstance(n, ast.stmt) and _counted(n))
    return out


def earlier_lines() -> dict[str, set[str]]:
    """Each file's stripped lines that an earlier sample's ``original`` holds."""
    taken: dict[str, set[str]] = {}
    for f in EARLIER:
        for m in tomllib.loads((ROOT / f).read_text())["mutant"]:
            taken.setdefault(m["file"], set()).update(
                ln.strip() for ln in m["original"].splitlines() if ln.strip())
    return taken


def draw() -> list[tuple[str, int, str, str]]:
    """(file, line, the line's text, 'sample' | 'spare' | 'skipped') in drawn order."""
    stmts = statements()
    taken = earlier_lines()
    order = np.random.default_rng(np.random.SeedSequence(6)).permutation(len(stmts))
    rows, kept = [], 0
    texts: dict[str, list[str]] = {}
    for i in order:
        rel, line = stmts[i]
        lines = texts.setdefault(rel, (ROOT / rel).read_text().splitlines())
        text = lines[line - 1].strip()
        if text in taken.get(rel, set()):
            rows.append((rel, line, text, "skipped"))
            continue
        rows.append((rel, line, text, "sample" if kept < N else "spare"))
        kept += 1
        if kept == N + SPARES:
            break
    return rows


if __name__ == "__main__":
    stmts = statements()
    print(f"# {len(stmts)} statements in {len({f for f, _ in stmts})} files")
    for k, (rel, line, text, kind) in enumerate(draw()):
        print(f"{k:3d} {kind:8s} {rel}:{line}  {text}")
