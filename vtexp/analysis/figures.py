"""Figures of the report, drawn with matplotlib (Agg) and returned as PNG bytes.

Each function takes a tidy table that an analysis function returned and only
draws it: no statistics are computed here.
"""

from __future__ import annotations

import io

import numpy as np
import pandas as pd

__all__ = ["rate_by_condition", "per_participant_lines", "confusion_heatmaps"]


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


def _percent(ax, dv: str) -> None:
    if dv == "rate":
        ax.set_ylim(0, 1.05)
        ax.yaxis.set_major_formatter(lambda v, _: f"{v * 100:.0f}%")


def rate_by_condition(measures: pd.DataFrame, dv: str, x: str, trace: str | None,
                      ylabel: str) -> bytes:
    """Mean of the participants' values per condition, ± 1 SE across participants.

    Seed 000 Fig. 11 (recognition rate per mode) in line form: x axis ``x``,
    one line per level of ``trace``.
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
    _percent(ax, dv)
    if trace:
        ax.legend(title=trace, fontsize=8, ncol=2 if len(groups) > 4 else 1)
    ax.grid(axis="y", alpha=0.3)
    return _png(fig)


def per_participant_lines(measures: pd.DataFrame, dv: str, x: str, ylabel: str) -> bytes:
    """One line per participant across the levels of ``x`` (seed 000 Figs. 12–13).

    Each participant's value at a level is their mean over the other factors;
    the bold line is the mean of the participants.
    """
    plt = _plt()
    per = measures.groupby(["participant", x], observed=True)[dv].mean().reset_index()
    xs = [str(v) for v in measures[x].cat.categories] if hasattr(measures[x], "cat") else \
        sorted(measures[x].astype(str).unique())
    pos = {v: i for i, v in enumerate(xs)}
    fig, ax = plt.subplots(figsize=(7, 4))
    cmap = plt.get_cmap("tab20")
    for k, (p, s) in enumerate(per.groupby("participant", observed=True)):
        ax.plot([pos[str(v)] for v in s[x]], s[dv], marker=".", linewidth=1, alpha=0.8,
                color=cmap(k % 20), label=f"sub-{p}")
    mean = per.groupby(x, observed=True)[dv].mean()
    ax.plot([pos[str(v)] for v in mean.index], mean.to_numpy(), color="black", linewidth=3,
            label="mean")
    ax.set_xticks(range(len(xs)), xs, rotation=30 if len(xs) > 5 else 0)
    ax.set_xlabel(x)
    ax.set_ylabel(ylabel)
    _percent(ax, dv)
    ax.legend(fontsize=7, ncol=2, bbox_to_anchor=(1.02, 1), loc="upper left")
    ax.grid(axis="y", alpha=0.3)
    return _png(fig)


def confusion_heatmaps(confusion: pd.DataFrame, by: list[str]) -> bytes:
    """Row-normalised confusion matrices, one panel per condition, proportions printed."""
    plt = _plt()
    groups = [((), confusion)] if not by else list(confusion.groupby(by, observed=True))
    n = len(groups)
    cols = min(4, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols + 1.2, 3.1 * rows), squeeze=False)
    fig.subplots_adjust(hspace=0.55, wspace=0.08)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for k, (ax, (key, g)) in enumerate(zip(axes.ravel(), groups)):
        first_col, bottom = k % cols == 0, k + cols >= n
        m = g.pivot_table(index="stimulus", columns="response", values="proportion",
                          observed=False, dropna=False)
        im = ax.imshow(m.to_numpy(dtype=float), vmin=0, vmax=1, cmap="Blues")
        labels = [str(v) for v in m.columns]
        ax.set_xticks(range(len(labels)), labels, rotation=45, ha="right", fontsize=7)
        ax.set_yticks(range(len(m.index)), [str(v) for v in m.index] if first_col else [],
                      fontsize=7)
        for i in range(m.shape[0]):
            for j in range(m.shape[1]):
                v = m.iat[i, j]
                if v == v:
                    ax.text(j, i, f"{v * 100:.0f}", ha="center", va="center", fontsize=7,
                            color="white" if v > 0.6 else "black")
        key = key if isinstance(key, tuple) else (key,)
        ax.set_title(", ".join(f"{f} {v}" for f, v in zip(by, key)) or "all trials", fontsize=9)
        if bottom:
            ax.set_xlabel("response", fontsize=8)
        if first_col:
            ax.set_ylabel("stimulus", fontsize=8)
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.6, label="proportion of the row")
    return _png(fig)
