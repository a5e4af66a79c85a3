"""Drawing of the detected output trace (like the paper's Figure 6), shared by the env's render
and the monitor node. Matplotlib is imported lazily, so importing this module is cheap.
"""

from __future__ import annotations

import numpy as np

from .physics import trace_time_axis_ns


def draw_trace(
    ax,
    trace,
    samples_per_slot: int,
    pulse_spacing_fs: float = 12.5e6,
    power: float | None = None,
    title: str | None = None,
    color: str = "tab:purple",
):
    """Draw one trace (L,) on a matplotlib Axes."""
    trace = np.asarray(trace, dtype=np.float64).ravel()
    spp = int(samples_per_slot)
    t = trace_time_axis_ns(trace.size // spp, spp, pulse_spacing_fs)
    ax.fill_between(t, trace, color=color, alpha=0.35, linewidth=0)
    ax.plot(t, trace, color=color, linewidth=1.2)
    ax.set_ylim(-0.02, 1.05)
    ax.set_xlim(t[0] - pulse_spacing_fs * 1e-6, t[-1] + pulse_spacing_fs * 1e-6)
    ax.set_xlabel("time (ns)")
    ax.set_ylabel("pulse energy / stacked energy")
    text = title or ""
    if power is not None:
        text = f"{text}  P/Pmax = {power:.3f}".strip()
    if text:
        ax.set_title(text, fontsize=10)
    ax.grid(alpha=0.3)
    return ax


def render_rgb(
    trace,
    samples_per_slot: int,
    pulse_spacing_fs: float = 12.5e6,
    power: float | None = None,
    title: str | None = None,
    size=(6.4, 3.2),
    dpi: int = 80,
) -> np.ndarray:
    """The trace drawn off-screen (Agg), as an (H, W, 3) uint8 image."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    draw_trace(ax, trace, samples_per_slot, pulse_spacing_fs, power=power, title=title)
    fig.tight_layout()
    canvas.draw()
    img = np.asarray(canvas.buffer_rgba())[..., :3].copy()
    return img


class HumanViewer:
    """A pyplot window that redraws the trace (for ``render_mode="human"``)."""

    def __init__(self) -> None:
        import matplotlib.pyplot as plt

        self.plt = plt
        self.fig, self.ax = plt.subplots(figsize=(6.4, 3.2))
        plt.ion()

    def show(self, trace, samples_per_slot, pulse_spacing_fs, power=None, title=None) -> None:
        self.ax.clear()
        draw_trace(self.ax, trace, samples_per_slot, pulse_spacing_fs, power=power, title=title)
        self.fig.tight_layout()
        self.fig.canvas.draw_idle()
        self.plt.pause(0.001)

    def close(self) -> None:
        self.plt.close(self.fig)
