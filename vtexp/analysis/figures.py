"""Figures of the report, drawn with matplotlib (Agg) and returned as PNG bytes.

Each function takes a tidy table that an analysis function returned and only
draws it: no statistics are computed here. The tests measure the figures as
they are saved (tests/report_render.py: no text on text, legends off the data,
cells large enough to read).
"""

from __future__ import annotations

import io
import textwrap

import numpy as np
import pandas as pd

from .psychometric import curve

__all__ = ["rate_by_condition", "per_participant_lines", "confusion_heatmaps",
           "psychometric_curves"]


def _plt():
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    _plt().close(fig)
    return buf.getvalue()


def _y_axis(ax, dv: str, scale: dict[int, str] | None = None) -> None:
    """Rates as percentages; a rating scale's points with their words, end to end."""
    if dv == "rate":
        ax.set_ylim(0, 1.05)
        ax.yaxis.set_major_formatter(lambda v, _: f"{v * 100:.0f}%")
    elif scale:
        points = sorted(scale)
        ax.set_ylim(points[0] - 0.3, points[-1] + 0.3)
        ax.set_yticks(points, [f"{v} {scale[v]}".strip() for v in points], fontsize=8)


def rate_by_condition(measures: pd.DataFrame, dv: str, x: str, trace: str | None,
                      ylabel: str, *, scale: dict[int, str] | None = None) -> bytes:
    """Mean of the participants' values per condition, ± 1 SE across participants.

    Seed 000 Fig. 11 (recognition rate per mode) in line form: x axis ``x``,
    one line per level of ``trace``, the legend outside the axes (to the
    right) so that it never covers a line. ``scale`` (a rating scale's points
    and their words) labels the y axis with the scale.
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    keys = [x] + ([trace] if trace else [])
    g = measures.groupby(keys, observed=True)[dv]
    stats = g.agg(["mean", "std", "count"]).reset_index()
    stats["se"] = stats["std"] / np.sqrt(stats["count"])
    xs = [str(v) for v in measures[x].cat.categories] if hasattr(measures[x], "cat") else \
        sorted(measures[x].astype(str).unique())
    pos = {v: i for i, v in enumerate(xs)}
    groups = [(None, stats)] if not trace else list(stats.groupby(trace, observed=True))
    width = 0.25 / max(1, len(groups))
    for k, (name, s) in enumerate(groups):
        off = (k - (len(groups) - 1) / 2) * width
        px = [pos[str(v)] + off for v in s[x]]
        ax.errorbar(px, s["mean"], yerr=s["se"], marker="o", capsize=3, linewidth=1.5,
                    label=str(name) if name is not None else None)
    ax.set_xticks(range(len(xs)), xs, rotation=30 if len(xs) > 5 else 0)
    ax.set_xlabel(x)
    ax.set_ylabel(f"{ylabel} (mean ± SE)")
    _y_axis(ax, dv, scale)
    if trace:
        ax.legend(title=trace, fontsize=8, ncol=2 if len(groups) > 12 else 1,
                  loc="upper left", bbox_to_anchor=(1.02, 1), borderaxespad=0)
    ax.grid(axis="y", alpha=0.3)
    return _png(fig)


def per_participant_lines(measures: pd.DataFrame, dv: str, x: str, ylabel: str, *,
                          trace: str | None = None,
                          scale: dict[int, str] | None = None) -> bytes:
    """One line per participant across the levels of ``x`` (seed 000 Figs. 12–13).

    With ``trace``, one panel per level of it: averaging over a factor whose
    levels pull the measure in opposite directions (circle rated +2, rectangle
    −2) would draw a flat line that no participant gave. Each participant's
    value at a level is their mean over the remaining factors; the bold line
    is the mean of the participants.
    """
    plt = _plt()
    xs = [str(v) for v in measures[x].cat.categories] if hasattr(measures[x], "cat") else \
        sorted(measures[x].astype(str).unique())
    pos = {v: i for i, v in enumerate(xs)}
    panels = [(None, measures)] if not trace else \
        [(k, g) for k, g in measures.groupby(trace, observed=True, sort=True)]
    fig, axes = plt.subplots(1, len(panels), figsize=(max(7.0, 4.2 * len(panels)), 4),
                             squeeze=False, sharey=True)
    cmap = plt.get_cmap("tab20")
    for ax, (name, sub) in zip(axes[0], panels):
        per = sub.groupby(["participant", x], observed=True)[dv].mean().reset_index()
        for k, (p, s) in enumerate(per.groupby("participant", observed=True)):
            ax.plot([pos[str(v)] for v in s[x]], s[dv], marker=".", linewidth=1, alpha=0.8,
                    color=cmap(k % 20), label=f"sub-{p}")
        mean = per.groupby(x, observed=True)[dv].mean()
        ax.plot([pos[str(v)] for v in mean.index], mean.to_numpy(), color="black",
                linewidth=3, label="mean")
        ax.set_xticks(range(len(xs)), xs, rotation=30 if len(xs) > 5 else 0)
        ax.set_xlabel(x)
        if name is not None:
            ax.set_title(f"{trace} {name}", fontsize=9)
        _y_axis(ax, dv, scale)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel(ylabel)
    axes[0][-1].legend(fontsize=7, ncol=2, bbox_to_anchor=(1.02, 1), loc="upper left")
    return _png(fig)


def confusion_heatmaps(confusion: pd.DataFrame, by: list[str]) -> bytes:
    """Row-normalised confusion matrices, one panel per condition, proportions printed.

    The panel grows with the number of categories (about 0.3 inch a row, so a
    26 × 26 letter matrix is readable), panels per row shrink accordingly, and
    titles are wrapped to the panel's width so that neighbours do not overlap.
    """
    plt = _plt()
    groups = [((), confusion)] if not by else list(confusion.groupby(by, observed=True))
    n = len(groups)
    k = confusion["stimulus"].nunique() if "stimulus" in confusion else 4
    side = max(3.0, 0.32 * k)                     # inches per panel
    cols = max(1, min(4, n, int(14 // side)))
    rows = int(np.ceil(n / cols))
    fontsize = 7 if k <= 12 else 5.5
    fig, axes = plt.subplots(rows, cols, figsize=(side * cols + 1.6, (side + 0.9) * rows),
                             squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for i, (ax, (key, g)) in enumerate(zip(axes.ravel(), groups)):
        first_col, bottom = i % cols == 0, i + cols >= n
        m = g.pivot_table(index="stimulus", columns="response", values="proportion",
                          observed=False, dropna=False)
        im = ax.imshow(m.to_numpy(dtype=float), vmin=0, vmax=1, cmap="Blues")
        labels = [str(v) for v in m.columns]
        ax.set_xticks(range(len(labels)), labels, rotation=45 if k <= 12 else 90,
                      ha="right" if k <= 12 else "center", fontsize=fontsize)
        ax.set_yticks(range(len(m.index)), [str(v) for v in m.index] if first_col else [],
                      fontsize=fontsize)
        for a in range(m.shape[0]):
            for b in range(m.shape[1]):
                v = m.iat[a, b]
                if v == v and (k <= 12 or v >= 0.005):
                    # inside its cell: no part of the layout (laying out a letter
                    # matrix's 676 numbers took most of its second)
                    ax.text(b, a, f"{v * 100:.0f}", ha="center", va="center",
                            fontsize=fontsize - (1 if k > 12 else 0),
                            color="white" if v > 0.6 else "black", in_layout=False)
        key = key if isinstance(key, tuple) else (key,)
        title = ", ".join(f"{f} {v}" for f, v in zip(by, key)) or "all trials"
        ax.set_title("\n".join(textwrap.wrap(title, width=max(12, int(side * 9)))),
                     fontsize=9)
        if bottom:
            ax.set_xlabel("response", fontsize=8)
        if first_col:
            ax.set_ylabel("stimulus", fontsize=8)
    fig.tight_layout(rect=(0, 0, 0.9, 1))
    cax = fig.add_axes((0.92, 0.25, 0.02, 0.5))
    fig.colorbar(im, cax=cax, label="proportion of the row")
    return _png(fig)


def psychometric_curves(fits: pd.DataFrame, points: pd.DataFrame, variable: str,
                        by: list[str] | None = None) -> bytes:
    """One panel per participant (and ``by`` level): the proportion of yes at each level
    played (marker area ∝ trials), the fitted function, and the threshold with its
    interval (a bar at the function's height there)."""
    plt = _plt()
    keys = ["participant", *(by or [])]
    n = len(fits)
    cols = min(n, 3)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    lo = float(points["level"].min()) if len(points) else 0.0
    hi = float(points["level"].max()) if len(points) else 1.0
    xs = np.linspace(lo, hi, 300)
    for ax, (_, f) in zip(axes.ravel(), fits.iterrows(), strict=False):
        mine = points
        for k in keys:
            mine = mine[mine[k].astype(str) == str(f[k])]
        ax.scatter(mine["level"], mine["proportion"], s=12 + 10 * mine["n"], alpha=0.5,
                   color="#4477aa", edgecolor="none", label="answers")
        ax.plot(xs, curve(f, xs), color="#222222", lw=1.5, label=f"{f['function']} fit")
        y = float(curve(f, np.array([f["threshold"]]))[0])
        ax.errorbar([f["threshold"]], [y], xerr=[[f["threshold"] - f["threshold_ci_low"]],
                                                 [f["threshold_ci_high"] - f["threshold"]]],
                    fmt="o", color="#cc3311", capsize=3, label="threshold, 95 % CI")
        ax.set_ylim(-0.03, 1.03)
        ax.set_title(", ".join(f"{k} {f[k]}" for k in keys), fontsize=9)
        ax.set_xlabel(variable)
        ax.set_ylabel("proportion yes")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    handles, labels = axes.ravel()[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=3,
               fontsize=8, frameon=False)
    fig.tight_layout()
    return _png(fig)
