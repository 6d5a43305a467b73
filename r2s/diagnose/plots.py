"""Pictures of the residual before and after (matplotlib, Agg; returns PNG bytes).

``residual_figure``: the depth residual map before / after, the depth residual against
depth, the per-block SSE (before, predicted with the effect, measured after the rerun),
per-object prior scale and per-object rollout motion, before and after.
"""

from __future__ import annotations

import io
from typing import Optional

import numpy as np

from r2s.diagnose.data import Residuals
from r2s.diagnose.stats.summary import sse_by_block


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return buf.getvalue()


def _depth_map(ax, res: Optional[Residuals], title: str, vmax_mm: float) -> None:
    ax.set_title(title, fontsize=9)
    ax.axis("off")
    if res is None or res.depth_map is None:
        ax.text(0.5, 0.5, "n/a", ha="center", va="center", transform=ax.transAxes)
        return
    im = ax.imshow(res.depth_map.residual_m * 1000.0, cmap="coolwarm", vmin=-vmax_mm,
                   vmax=vmax_mm)
    ax.figure.colorbar(im, ax=ax, fraction=0.035, label="observed - model (mm)")


def _vs_depth(ax, runs: list[tuple[str, Optional[Residuals]]]) -> None:
    ax.set_title("depth residual on objects vs depth", fontsize=9)
    for label, res in runs:
        if res is None or res.depth_map is None:
            continue
        dm = res.depth_map
        ok = dm.on_object & np.isfinite(dm.residual_m) & np.isfinite(dm.depth_m)
        if ok.sum() < 20:
            continue
        z, r = dm.depth_m[ok], dm.residual_m[ok] * 1000.0
        edges = np.quantile(z, np.linspace(0, 1, 9))
        mid = 0.5 * (edges[1:] + edges[:-1])
        med = [np.median(r[(z >= a) & (z <= b)]) for a, b in zip(edges[:-1], edges[1:])]
        ax.plot(mid, med, "o-", label=label)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("observed depth (m)")
    ax.set_ylabel("median residual (mm)")
    ax.legend(fontsize=8)


def _sse_bars(ax, before: Residuals, predicted: Optional[Residuals],
              measured: Optional[Residuals]) -> None:
    ax.set_title("normalised residual (SSE) per block", fontsize=9)
    runs = [("before", sse_by_block(before)), ("predicted", sse_by_block(predicted)),
            ("after rerun", sse_by_block(measured))]
    names = sorted(set().union(*[set(r) for _, r in runs]))
    x = np.arange(len(names))
    for k, (label, sse) in enumerate(runs):
        if sse:
            ax.bar(x + (k - 1) * 0.27, [sse.get(n, 0.0) for n in names], 0.27, label=label)
    ax.set_xticks(x, names, fontsize=8)
    ax.set_yscale("symlog")
    ax.legend(fontsize=8)


def _scales(ax, runs: list[tuple[str, Optional[Residuals]]]) -> None:
    ax.set_title("prior scale that fits the observation", fontsize=9)
    for k, (label, res) in enumerate(runs):
        if res is None or res.registration is None:
            continue
        objs = res.registration.objects
        ax.bar(np.arange(len(objs)) + (k - 0.5) * 0.4, [o.scale - 1.0 for o in objs], 0.4,
               label=label)
        ax.set_xticks(np.arange(len(objs)), [str(o.id) for o in objs], fontsize=8)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("object")
    ax.set_ylabel("scale - 1")
    ax.legend(fontsize=8)


def _motion(ax, runs: list[tuple[str, Optional[Residuals]]]) -> None:
    ax.set_title("rollout motion per object", fontsize=9)
    for k, (label, res) in enumerate(runs):
        if res is None or res.physics is None:
            continue
        ids = sorted(res.physics.motion)
        vals = [res.physics.motion[i].translation_norm_m * 1000.0 for i in ids]
        ax.bar(np.arange(len(ids)) + (k - 0.5) * 0.4, vals, 0.4, label=f"{label} (mm)")
        ax.set_xticks(np.arange(len(ids)), [str(i) for i in ids], fontsize=8)
    ax.set_yscale("symlog")
    ax.set_xlabel("object")
    ax.legend(fontsize=8)


def residual_figure(before: Residuals, predicted: Optional[Residuals],
                    measured_after: Optional[Residuals], title: str) -> bytes:
    """PNG bytes of the before/after figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [("before", before), ("after", measured_after if measured_after is not None
                                 else predicted)]
    vmax = 10.0
    if before.depth_map is not None:
        r = before.depth_map.residual_m
        if np.isfinite(r).any():
            vmax = float(max(2.0, np.nanpercentile(np.abs(r) * 1000.0, 95)))
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    _depth_map(axes[0, 0], before, "depth residual before", vmax)
    _depth_map(axes[0, 1], measured_after, "depth residual after (rerun)", vmax)
    _vs_depth(axes[0, 2], runs)
    _sse_bars(axes[1, 0], before, predicted, measured_after)
    _scales(axes[1, 1], runs)
    _motion(axes[1, 2], runs)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data


def structure_figure(finding, width: int, height: int, title: str) -> bytes:
    """PNG bytes of a structured residual (:class:`r2s.diagnose.stats.structure_test.
    StructureFinding`): the table's tile residuals where they lie in the image, and
    against the generic feature that explains most of them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from r2s.diagnose.stats.structure_test import FEATURE_TEXT

    tiles = np.asarray(finding.tiles_mm, dtype=float)
    centres = np.asarray(finding.centres_px, dtype=float).reshape(-1, 2)
    vmax = float(max(0.5, np.max(np.abs(tiles)) if len(tiles) else 1.0))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    ax = axes[0]
    sc = ax.scatter(centres[:, 0], centres[:, 1], c=tiles, cmap="coolwarm", vmin=-vmax,
                    vmax=vmax, s=260, marker="s")
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_aspect("equal")
    ax.set_title("table: mean distance to its plane per image tile (mm)", fontsize=9)
    fig.colorbar(sc, ax=ax, fraction=0.035, label="towards the camera (mm)")
    ax = axes[1]
    name = finding.best_feature
    if name == "position" and len(getattr(finding, "position_fit_mm", ())) == len(tiles):
        fit = np.asarray(finding.position_fit_mm, dtype=float)
        ax.plot(fit, tiles, "o", ms=4)
        lim = [float(min(fit.min(), tiles.min())), float(max(fit.max(), tiles.max()))]
        ax.plot(lim, lim, "-", lw=1.5)
        ax.set_xlabel("a quadratic in column and row together, fitted (mm)")
    elif name is not None and name in finding.feature_values:
        x = np.asarray(finding.feature_values[name], dtype=float)
        ax.plot(x, tiles, "o", ms=4)
        order = np.argsort(x)
        if len(x) >= 4 and np.ptp(x) > 0:
            coef = np.polyfit(x, tiles, 2)
            ax.plot(x[order], np.polyval(coef, x[order]), "-", lw=1.5)
        ax.set_xlabel(FEATURE_TEXT[name])
    ax.axhline(0, color="k", lw=0.5)
    ax.set_ylabel("tile residual (mm)")
    ax.set_title(f"against {FEATURE_TEXT.get(name, '-')}: R^2 {finding.best_r2:.2f}",
                 fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data


def edge_figure(finding, title: str) -> bytes:
    """PNG bytes of a depth-to-colour misregistration (:class:`r2s.diagnose.stats.
    edge_alignment.EdgeFinding`): the masks' outline pixels on a depth edge against the
    shift, summed over the objects, with the scene's top and each object's own; beside it,
    the best count over the shifts against the outlines' turn about the image centre."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    corr = np.asarray(finding.correlation, dtype=float)
    s = corr.shape[0] // 2
    profile = getattr(finding, "turn_profile", None)
    fig, axes = plt.subplots(1, 2 if profile is not None else 1,
                             figsize=(10.4 if profile is not None else 5.6, 4.8),
                             squeeze=False)
    ax = axes[0, 0]
    im = ax.imshow(corr, origin="upper", extent=(-s - 0.5, s + 0.5, s + 0.5, -s - 0.5),
                   cmap="viridis")
    fig.colorbar(im, ax=ax, label="mask outline pixels on a depth edge")
    for oid, (dx, dy) in sorted(finding.peaks_px.items()):
        ax.plot(dx, dy, "w.", ms=6)
        ax.annotate(str(oid), (dx, dy), color="w", fontsize=7, xytext=(3, 3),
                    textcoords="offset points")
    ax.plot(*finding.shift_px, "r+", ms=14, mew=2, label="scene")
    ax.axhline(0, color="w", lw=0.5)
    ax.axvline(0, color="w", lw=0.5)
    ax.set_xlabel("depth edges right of the mask outline (px)")
    ax.set_ylabel("depth edges below the mask outline (px)")
    ax.set_title(f"unturned: shift ({finding.shift_px[0]:+.1f}, {finding.shift_px[1]:+.1f}) "
                 f"px, {finding.agreement:.0%} of objects agree", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    if profile is not None:
        ax = axes[0, 1]
        prof = np.asarray(profile, dtype=float)
        ax.plot(prof[:, 0], prof[:, 1], "k.-")
        ax.axvline(finding.turn_deg, color="r", lw=1.5,
                   label=f"turn {finding.turn_deg:+.2f} deg")
        ax.axvline(0, color="0.6", lw=0.5)
        ax.set_xlabel("outlines turned about the image centre (deg, + clockwise)")
        ax.set_ylabel("best count over the shifts")
        ax.set_title(f"turned: best count x{finding.turn_gain:.2f} the unturned one", fontsize=9)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data


def colour_figure(finding, title: str) -> bytes:
    """PNG bytes of a colour-dependent depth error (:class:`r2s.diagnose.stats.colour_test.
    ColourFinding`): per object, its patch residuals against their grey level (the
    registered priors' test) or its depth's fine detail against the grey's, binned (the
    texture test), with its fitted line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.6))
    for oid, (grey, resid_mm) in sorted(finding.points.items()):
        g, r = np.asarray(grey, dtype=float), np.asarray(resid_mm, dtype=float)
        line = ax.plot(g, r, "o", ms=3, alpha=0.6,
                       label=f"object {oid}: {finding.slopes_mm[oid]:+.1f} mm, "
                             f"t {finding.z_by_object[oid]:+.1f}")[0]
        if np.ptp(g) > 0:
            coef = np.polyfit(g, r, 1)
            xs = np.array([g.min(), g.max()])
            ax.plot(xs, np.polyval(coef, xs), "-", color=line.get_color(), lw=1.5)
    ax.axhline(0, color="k", lw=0.5)
    if finding.source == "texture":
        lo, hi = ax.get_xlim()
        xs = np.array([lo, hi])
        ax.plot(xs, finding.slope_mm * xs, "k--", lw=1,
                label=f"scene: {finding.slope_mm:+.1f} mm per unit grey")
        ax.set_xlabel("grey level's detail: what a quadratic over its 8 px patch leaves")
        ax.set_ylabel("depth's detail in the same patches, binned by grey (mm)")
    else:
        ax.set_xlabel("grey level of the surface (0 black, 1 white)")
        ax.set_ylabel("observed minus prior depth, 6 px patches (mm)")
    ax.set_title(f"z = {finding.z:.1f} (reported at |z| >= {finding.z_threshold:.1f})",
                 fontsize=9)
    ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data
