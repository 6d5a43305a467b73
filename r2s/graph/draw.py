"""Picture of a contact graph: the support tree top-down, table at the top.

Solid arrows: tree edges (parent -> child) labelled with H; dashed: extra supporters;
dotted grey arcs: proximity-only pairs. Returns PNG bytes; the caller writes them.
"""

from __future__ import annotations

import io

from r2s.graph.schema import ContactGraph


def tree_layout(graph: ContactGraph) -> dict[int, tuple[float, float]]:
    """(x, y) per node: leaves spread left to right in DFS order, parents over children."""
    pos: dict[int, tuple[float, float]] = {}
    next_x = [0.0]

    def place(i: int, depth: int) -> float:
        kids = graph.children_of(i)
        if not kids:
            x = next_x[0]
            next_x[0] += 1.0
        else:
            xs = [place(k, depth + 1) for k in kids]
            x = 0.5 * (min(xs) + max(xs))
        pos[i] = (x, -float(depth))
        return x

    place(graph.root, 0)
    return pos


def draw_contact_graph(graph: ContactGraph, title: str = "contact graph") -> bytes:
    """PNG bytes of the graph drawn with matplotlib (Agg backend)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    pos = tree_layout(graph)
    width = max(4.0, 1.6 * (max(x for x, _ in pos.values()) + 1))
    height = max(3.0, 1.5 * (1 + max(-y for _, y in pos.values())))
    fig, ax = plt.subplots(figsize=(width, height), dpi=100)
    for e in graph.proximity_edges:
        if e.support or e.a not in pos or e.b not in pos:
            continue
        (xa, ya), (xb, yb) = pos[e.a], pos[e.b]
        ax.annotate("", xy=(xb, yb), xytext=(xa, ya),
                    arrowprops=dict(arrowstyle="-", color="0.6", linestyle=":",
                                    connectionstyle="arc3,rad=0.3", shrinkA=14, shrinkB=14))
    for e in graph.support_edges:
        (xp, yp), (xc, yc) = pos[e.parent], pos[e.child]
        style = "-" if e.in_tree else "--"
        color = "black" if e.in_tree else "tab:blue"
        ax.annotate("", xy=(xc, yc), xytext=(xp, yp),
                    arrowprops=dict(arrowstyle="->", color=color, linestyle=style,
                                    shrinkA=14, shrinkB=14))
        ax.text(0.5 * (xp + xc), 0.5 * (yp + yc), f"H={e.likelihood:.2f}", fontsize=8,
                color=color, ha="center", va="center",
                bbox=dict(boxstyle="round,pad=0.1", fc="white", ec="none", alpha=0.8))
    for n in graph.nodes:
        x, y = pos.get(n.id, (0.0, 0.0))
        face = "tan" if n.is_root else "lightsteelblue"
        ax.text(x, y, f"{n.id}\n{n.label}", ha="center", va="center", fontsize=8,
                bbox=dict(boxstyle="round,pad=0.4", fc=face, ec="black"))
    xs = [p[0] for p in pos.values()]
    ys = [p[1] for p in pos.values()]
    ax.set_xlim(min(xs) - 0.8, max(xs) + 0.8)
    ax.set_ylim(min(ys) - 0.6, max(ys) + 0.6)
    ax.set_title(title, fontsize=10)
    ax.axis("off")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()
