"""Markdown tables, PNG plots (matplotlib, Agg) and summary.json of an evaluation run."""

from __future__ import annotations

import json
from pathlib import Path

from tracker.evaluation.metrics import TOLERANCES, confusion, session_row, timing_distribution


def markdown_table(rows: list[dict], columns: list[str] | None = None) -> str:
    if not rows:
        return "(no sessions)\n"
    cols = columns or list(rows[0])
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        out.append("| " + " | ".join("" if r.get(c) is None else str(r.get(c)) for c in cols) + " |")
    return "\n".join(out) + "\n"


def distribution_table(dist: dict) -> str:
    rows = []
    for T, c in dist.items():
        total = max(1, sum(c.values()))
        rows.append({"T (s)": T, **{k: f"{v} ({100 * v / total:.1f} %)" for k, v in c.items()}})
    return markdown_table(rows)


def plot_distribution(dist: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    Ts = [float(T) for T in dist]
    keys = list(dist)
    kinds = ["early", "within", "late", "never"]
    colours = {"early": "#f2a33a", "within": "#3a9a4a", "late": "#3a6bd6", "never": "#c0392b"}
    fig, ax = plt.subplots(figsize=(5, 3.2))
    bottom = [0.0] * len(Ts)
    for k in kinds:
        vals = [100 * dist[T][k] / max(1, sum(dist[T].values())) for T in keys]
        ax.bar(Ts, vals, width=0.6, bottom=bottom, label=k, color=colours[k])
        bottom = [b + v for b, v in zip(bottom, vals, strict=True)]
    ax.set_xticks(Ts)
    ax.set_xlabel("tolerance T (s)")
    ax.set_ylabel("% of connections")
    ax.set_title(title)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_confusion(m: list[list[int]], names: list[str], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 3.6))
    ax.imshow(m, cmap="Blues")
    for i, row in enumerate(m):
        for j, v in enumerate(row):
            ax.text(j, i, str(v), ha="center", va="center")
    ax.set_xticks(range(len(names)), names, rotation=20, fontsize=7)
    ax.set_yticks(range(len(names)), names, fontsize=7)
    ax.set_xlabel("true structure")
    ax.set_ylabel("recognised structure")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_sweep(curves: dict[str, dict], path: Path, title: str) -> None:
    """``curves``: label → timing distribution; plots % within ±T against T."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.2))
    for label, dist in curves.items():
        Ts = [float(T) for T in dist]
        ax.plot(Ts, [100 * dist[T]["within"] / max(1, sum(dist[T].values())) for T in dist], marker="o", label=label)
    ax.set_xticks(list(TOLERANCES))
    ax.set_xlabel("tolerance T (s)")
    ax.set_ylabel("% detected within ±T")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_experiment(out: Path, name: str, results: list, summary: dict, structures: list[str] | None = None,
                     header: str = "") -> None:
    """``<name>.md``, ``<name>_timing.png``, (guess) ``<name>_confusion.png`` and ``<name>_sessions.json``."""
    out.mkdir(parents=True, exist_ok=True)
    rows = [session_row(r) for r in results]
    dist = timing_distribution(results)
    md = [f"## {name}\n", header, "\n### Sessions\n", markdown_table(rows),
          "\n### Timing (early / within / late / never)\n", distribution_table(dist)]
    keys = ["sessions", "connections_total", "connections_detected", "connections_within_1s", "connections_never",
            "mean_deviation_s", "mean_abs_deviation_s", "false_completions", "guess_correct", "sentences_correct"]
    md += ["\n### Summary\n", markdown_table([{k: summary.get(k) for k in keys if k in summary}])]
    plot_distribution(dist, out / f"{name}_timing.png", f"{name}: connection timing")
    if structures:
        m = confusion(results, structures)
        summary["confusion"] = {"rows_recognised_cols_true": m, "structures": structures}
        md += ["\n### Confusion matrix (rows = recognised, columns = true)\n",
               markdown_table([{"recognised": n, **{s: m[i][j] for j, s in enumerate(structures)}}
                               for i, n in enumerate(structures)])]
        plot_confusion(m, structures, out / f"{name}_confusion.png", f"{name}: guess confusion")
    (out / f"{name}.md").write_text("\n".join(md), encoding="utf-8")
    (out / f"{name}_sessions.json").write_text(json.dumps([r.to_dict() for r in results], indent=1, default=str))
