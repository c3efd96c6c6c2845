"""Figures like the book's, as PNG bytes (matplotlib, Agg backend; no display needed)."""
from __future__ import annotations

import io

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from .experiment import Figure  # noqa: E402


def panels(n: int, height: float = 2.0, width: float = 7.0, sharex: bool = True):
    fig, axes = plt.subplots(n, 1, figsize=(width, height * n + 0.4), sharex=sharex, squeeze=False)
    return fig, [a[0] for a in axes]


def finish(fig, name: str, caption: str) -> Figure:
    """The figure as a PNG (closed afterwards)."""
    for ax in fig.axes:
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format='png', dpi=90)
    plt.close(fig)
    return Figure(name, caption, buf.getvalue())


def time_plot(name: str, caption: str, t, series, xlabel: str = 't (s)') -> Figure:
    """One panel per entry of ``series``: [(ylabel, [(y, style/label), ...]), ...]."""
    fig, axes = panels(len(series))
    for ax, (ylabel, curves) in zip(axes, series):
        for y, label in curves:
            ax.plot(t[:len(y)], y, lw=0.9, label=label or None)
        ax.set_ylabel(ylabel)
        if any(label for _, label in curves):
            ax.legend(fontsize=7, loc='best')
    axes[-1].set_xlabel(xlabel)
    return finish(fig, name, caption)
