"""Draw docs/figures/architecture.png: feltool's subpackages in their layers (from the table in
docs/architecture.md) and the imports between them (from the code).

An arrow A -> B means a module of A imports a module of B; arrows implied by a longer path are
left out (the transitive reduction), so the picture shows the structure, not every import.

usage: python scripts/architecture_figure.py [OUT.png]
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from tests.test_architecture import graph, layers, unit  # noqa: E402


def unit_edges() -> set[tuple[str, str]]:
    return {(unit(m), unit(t)) for m, ts in graph().items() for t in ts if unit(m) != unit(t)}


def reduction(edges: set[tuple[str, str]]) -> set[tuple[str, str]]:
    """The edges not implied by a path of two or more edges."""
    succ: dict[str, set[str]] = {}
    for a, b in edges:
        succ.setdefault(a, set()).add(b)

    def reach(a: str, skip: tuple[str, str]) -> set[str]:
        seen, todo = set(), [a]
        while todo:
            x = todo.pop()
            for y in succ.get(x, ()):
                if (x, y) != skip and y not in seen:
                    seen.add(y)
                    todo.append(y)
        return seen

    return {(a, b) for a, b in edges if b not in reach(a, (a, b))}


def main(out: Path) -> None:
    table = layers()
    rows: dict[int, list[str]] = {}
    for name, layer in table.items():
        rows.setdefault(layer, []).append(name)
    pos = {}
    for layer, names in rows.items():
        for i, name in enumerate(names):
            pos[name] = ((i + 1) / (len(names) + 1), layer)
    fig, ax = plt.subplots(figsize=(7.5, 9.5))
    for a, b in sorted(reduction(unit_edges())):
        (x0, y0), (x1, y1) = pos[a], pos[b]
        ax.add_patch(FancyArrowPatch((x0, y0 - 0.22), (x1, y1 + 0.22), arrowstyle="-|>",
                                     mutation_scale=9, lw=0.8, color="#5577aa", alpha=0.7,
                                     connectionstyle="arc3,rad=0.08"))
    for name, (x, y) in pos.items():
        label = "feltool/__init__" if name == "feltool" else (
            f"{name}.py" if name in ("errors", "bounds", "files", "_version") else f"{name}/")
        ax.add_patch(FancyBboxPatch((x - 0.1, y - 0.2), 0.2, 0.4,
                                    boxstyle="round,pad=0.01,rounding_size=0.05",
                                    fc="#eef2f8", ec="#334466", lw=0.9))
        ax.text(x, y, label, ha="center", va="center", fontsize=8.5, family="monospace")
    for layer in rows:
        ax.text(-0.02, layer, str(layer), ha="right", va="center", fontsize=8, color="#777777")
    ax.set_xlim(-0.06, 1.02)
    ax.set_ylim(0.4, max(rows) + 0.6)
    ax.axis("off")
    ax.set_title("feltool: subpackages by layer; an arrow is an import (transitive reduction)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=130)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "figures" / "architecture.png")
