"""Figures every experiment draws: maximum-intensity projections on one colour scale, and
the training curves."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .runner import save_figure

PLANES = {"x-y": 2, "x-z": 1, "y-z": 0}  # plane name -> the axis projected away


def mip(volume: np.ndarray, plane: str) -> np.ndarray:
    """The maximum-intensity projection of ``|volume| / max|volume|`` onto ``plane``,
    transposed for ``imshow(origin="lower")`` (first named axis horizontal)."""
    magnitude = np.abs(volume)
    peak = magnitude.max()
    return (magnitude / peak if peak > 0 else magnitude).max(axis=PLANES[plane]).T


def mip_grid(
    panels: list[list[tuple[str, np.ndarray | None]]],
    *,
    extent: float,
    plane: str,
    title: str,
    path: Path,
    row_labels: list[str] | None = None,
) -> None:
    """Rows × columns of MIPs, each volume scaled to its own maximum and drawn on one [0, 1]
    colour scale (the metrics normalise the same way); ``None`` leaves a cell empty."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_rows, n_cols = len(panels), max(len(row) for row in panels)
    fig, axes = plt.subplots(
        n_rows, n_cols, figsize=(2.3 * n_cols + 0.8, 2.3 * n_rows + 0.5), squeeze=False
    )
    image = None
    for i, row in enumerate(panels):
        for j in range(n_cols):
            ax = axes[i, j]
            if j >= len(row) or row[j][1] is None:
                ax.axis("off")
                continue
            name, volume = row[j]
            edge = extent * len(volume) / (len(volume) - 1)  # grid points are cell centres
            span = [-edge, edge, -edge, edge]
            image = ax.imshow(
                mip(volume, plane), origin="lower", extent=span, cmap="magma", vmin=0, vmax=1
            )
            ax.set_title(name, fontsize=9)
            ax.set_xticks([-extent, 0, extent])
            ax.set_yticks([-extent, 0, extent])
            ax.tick_params(labelsize=7)
            if i == n_rows - 1:
                ax.set_xlabel(f"{plane[0]} (m)", fontsize=8)
            if j == 0:
                label = f"{row_labels[i]}\n" if row_labels else ""
                ax.set_ylabel(f"{label}{plane[2]} (m)", fontsize=8)
    if image is not None:
        fig.colorbar(image, ax=axes, shrink=0.8, label="|ρ| / max |ρ| (MIP)")
    fig.suptitle(title)
    save_figure(fig, path)
    plt.close(fig)


def training_curves(histories: dict, *, title: str, path: Path) -> None:
    """RIFT's training loss (relative to its first epoch) and every run's relative data
    residual ‖y − Aρ‖/‖y‖, per epoch or sweep."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_loss, ax_res) = plt.subplots(1, 2, figsize=(12, 4.2))
    for key, history in histories.items():
        residual = np.asarray(history["residual"])
        steps = np.arange(1, len(residual) + 1)
        style = "-" if history["loss"] is not None else "--"
        (line,) = ax_res.plot(steps, residual, style, marker=".", label=key)
        if history["loss"] is not None:
            loss = np.asarray(history["loss"])
            ax_loss.plot(steps, loss / loss[0], color=line.get_color(), marker=".", label=key)
    ax_loss.set(xlabel="epoch", ylabel="training loss / first epoch's", title="RIFT loss")
    ax_res.set(
        xlabel="epoch (RIFT) or sweep (LS)",
        ylabel="‖y − Aρ‖ / ‖y‖",
        title="Relative data residual (dashed: LS)",
    )
    for ax in (ax_loss, ax_res):
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=6, ncol=2)
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
