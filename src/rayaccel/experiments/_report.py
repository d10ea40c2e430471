"""Shared output for the experiments: markdown tables and matplotlib figures."""

from __future__ import annotations

from pathlib import Path

__all__ = ["markdown_table", "new_figure", "save_figure", "build_and_render_bars"]


def _cell(value) -> str:
    return str(value).replace("|", "\\|")


def markdown_table(headers: list[str], rows: list[list], align_right_from: int = 1) -> list[str]:
    """Lines of a markdown table; columns from ``align_right_from`` on are right-aligned; a ``|`` in a
    cell is escaped so that it does not split the cell."""
    marks = ["---" if i < align_right_from else "---:" for i in range(len(headers))]
    lines = ["| " + " | ".join(_cell(h) for h in headers) + " |", "|" + "|".join(marks) + "|"]
    lines += ["| " + " | ".join(_cell(cell) for cell in row) + " |" for row in rows]
    return lines


def new_figure(n_panels: int = 1, width: float = 6.0, height: float = 4.2):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, n_panels, figsize=(width * n_panels, height), dpi=120, squeeze=False)
    return fig, axes[0]


def save_figure(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def build_and_render_bars(labels: list[str], build_seconds: list[float], render_seconds: list[float], title: str,
                          side: int, path: Path) -> Path:
    """Two log-scale bar charts side by side: construction time and render time per label."""
    fig, (left, right) = new_figure(2)
    positions = list(range(len(labels)))
    left.bar(positions, build_seconds, color="C0")
    right.bar(positions, render_seconds, color="C1")
    left.set(yscale="log", ylabel="seconds", title=f"{title}: construction time")
    right.set(yscale="log", ylabel="seconds", title=f"{title}: render time, {side}x{side} with shadows")
    for ax in (left, right):
        ax.set_xticks(positions, labels, rotation=40, ha="right", fontsize=8)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    return save_figure(fig, path)
