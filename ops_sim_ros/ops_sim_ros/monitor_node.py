"""The live monitor ``ops_monitor``: the detected trace and the history of P_N / P_max.

The paper's "real-time rendering of the pulse intensity to monitor the controlling process".
With a display it opens a window; ``-p save:=FILE`` records instead (headless):

- ``.png``: the first trace received ("before"), the latest ("after") and the power history,
  rewritten every ``png_period_s`` and on exit (stop the monitor before the controller, so that
  the last "after" is a controlled one);
- ``.gif`` / ``.mp4``: one frame every ``frame_period_s`` (like the paper's Figure 17 sequence),
  written on exit (``.mp4`` needs ffmpeg on PATH).

The power history's x axis is the time since the monitor's first reading, from the publisher's
timestamps (the simulator's or rig's clock, so a frame drawn meanwhile does not bunch the
readings); a dashed line marks the first command on ``ops/delay_cmd``, where the controller
starts. ``title`` heads the figure (the demos give the controller, N, mode and seed).
"""

from __future__ import annotations

import os
import shutil
import time
from collections import deque
from pathlib import Path

import numpy as np
from ops_contract.node_params import ParamSpec, declare_all
from ops_contract.ros_interface import (
    QOS_EVERY_READING,
    QOS_RELIABLE,
    TOPIC_DELAY_CMD,
    TOPIC_INTENSITY,
    TOPIC_POWER,
    MessageGuard,
    ParameterError,
    power_from_msg,
    run_node,
    trace_from_msg,
)
from rclpy.node import Node
from std_msgs.msg import Float32, Float32MultiArray

SAVE_FORMATS = (".png", ".gif", ".mp4")
PARAMS = [
    ParamSpec("save", "", "record to this file (.png, .gif or .mp4) instead of a window"),
    ParamSpec("title", "", "the figure's title (e.g. the controller, N, mode and seed)"),
    ParamSpec("history", 2000, "power readings kept in the history plot", low=10, high=10**7),
    ParamSpec(
        "frame_period_s",
        0.1,
        "time between recorded or drawn frames",
        low=0.01,
        high=60.0,
    ),
    ParamSpec(
        "png_period_s",
        2.0,
        "how often a .png record is rewritten",
        low=0.1,
        high=3600.0,
    ),
    ParamSpec(
        # A frame is ~1 MB in memory: 3000 frames are ~3 GB.
        "max_frames",
        600,
        "largest number of frames kept for .gif / .mp4",
        low=1,
        high=3000,
    ),
    ParamSpec(
        "pulse_spacing_ns",
        12.5,
        "pulse spacing T for the time axis",
        low=1e-3,
        high=1e6,
    ),
]


def publisher_time(info) -> float:
    """A message's time (s): the publisher's timestamp from its MessageInfo, else now."""
    stamp = info.get("source_timestamp") if isinstance(info, dict) else None
    return stamp * 1e-9 if isinstance(stamp, int) and stamp > 0 else time.time()


class MonitorNode(Node):
    def __init__(self):
        super().__init__("ops_monitor")
        v = declare_all(self, PARAMS)
        self._save = Path(v["save"]).expanduser() if v["save"] else None
        if self._save is not None:
            suffix = self._save.suffix.lower()
            if suffix not in SAVE_FORMATS:
                raise ParameterError(
                    f"save must end in one of {', '.join(SAVE_FORMATS)} (got {v['save']!r})"
                )
            if suffix == ".mp4" and shutil.which("ffmpeg") is None:
                raise ParameterError("save: .mp4 needs ffmpeg on PATH; use .gif or .png instead")
            if not self._save.parent.exists():
                raise ParameterError(f"save: directory {self._save.parent} does not exist")
        elif not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
            raise ParameterError(
                "save: no display for a live window; record instead with "
                "--ros-args -p save:=monitor.png (or .gif / .mp4)"
            )
        self._spacing_fs = v["pulse_spacing_ns"] * 1e6
        self._frame_period = v["frame_period_s"]
        self._title = v["title"]
        self._powers: deque[float] = deque(maxlen=v["history"])
        self._stamps: deque[float] = deque(maxlen=v["history"])  # each reading's time (s)
        self._first_stamp: float | None = None  # the first reading's: the history's zero
        self._control_stamp: float | None = None  # the first command's on ops/delay_cmd
        self._frames: deque[np.ndarray] = deque(maxlen=v["max_frames"])
        self._first: tuple[np.ndarray, int, float] | None = None
        self._latest: tuple[np.ndarray, int] | None = None
        self._readings = 0
        self._next_frame_at = 0.0
        self._figure = None
        self._dirty = False
        self._guard = MessageGuard(self)

        self.create_subscription(Float32MultiArray, TOPIC_INTENSITY, self._on_trace, QOS_RELIABLE)
        # Every reading counts (the history plot, the readings figure): a deep queue, so drawing a
        # frame does not lose the readings that arrive meanwhile.
        self.create_subscription(Float32, TOPIC_POWER, self._on_power, QOS_EVERY_READING)
        # The controller's first command marks the history; then the subscription goes.
        self._cmd_sub = self.create_subscription(
            Float32MultiArray, TOPIC_DELAY_CMD, self._on_command, QOS_RELIABLE
        )
        self.create_timer(self._frame_period, self._on_frame)
        if self._save is not None and self._save.suffix.lower() == ".png":
            self.create_timer(v["png_period_s"], self._write_png)
        target = self._save or "a live window"
        self.get_logger().info(f"monitoring {self.resolve_topic_name(TOPIC_INTENSITY)} to {target}")

    # ------------------------------------------------------------------ inputs
    def _on_trace(self, msg: Float32MultiArray):
        trace = self._guard.take(TOPIC_INTENSITY, trace_from_msg, msg)
        if trace is None:
            return
        self._latest = trace
        self._dirty = True

    def _on_power(self, msg: Float32, info):
        # (``info`` without a default: rclpy passes the MessageInfo only to a callback that
        # cannot be called with the message alone)
        power = self._guard.take(TOPIC_POWER, power_from_msg, msg)
        if power is None:
            return
        stamp = publisher_time(info)
        if self._first_stamp is None:
            self._first_stamp = stamp
        self._stamps.append(stamp)
        self._powers.append(power)
        self._readings += 1
        if self._first is None and self._latest is not None:
            self._first = (*self._latest, power)
            self.get_logger().info(f"first trace received: P_N/P_max = {power:.4f}")

    def _on_command(self, msg: Float32MultiArray, info):
        if self._control_stamp is not None:
            return
        self._control_stamp = publisher_time(info)
        self.get_logger().info(
            f"the controller's first command came after {self._readings} readings"
        )
        self.destroy_subscription(self._cmd_sub)

    # ------------------------------------------------------------------ drawing
    def _draw(self, fig):
        """Trace(s) on top, the power history below."""
        from .rendering import draw_trace

        fig.clear()
        show_before = self._save is not None and self._save.suffix.lower() == ".png"
        cols = 2 if show_before and self._first is not None else 1
        grid = fig.add_gridspec(2, cols, height_ratios=(3, 2))
        power = self._powers[-1] if self._powers else None
        if cols == 2:
            trace, samples, p0 = self._first
            draw_trace(
                fig.add_subplot(grid[0, 0]),
                trace,
                samples,
                self._spacing_fs,
                p0,
                title="before",
                color="tab:red",
            )
        if self._latest is not None:
            trace, samples = self._latest
            draw_trace(
                fig.add_subplot(grid[0, cols - 1]),
                trace,
                samples,
                self._spacing_fs,
                power,
                title="after" if cols == 2 else "output trace",
            )
        self._draw_history(fig.add_subplot(grid[1, :]))
        if self._title:
            fig.suptitle(self._title, fontsize=11)
        fig.tight_layout()

    def _draw_history(self, ax):
        """P_N / P_max of every reading kept, against the time since the first reading, with
        the controller's start marked."""
        if self._powers:
            t = np.asarray(self._stamps) - self._first_stamp
            ax.plot(t, np.asarray(self._powers), color="tab:blue", linewidth=1.0)
        if self._control_stamp is not None:
            ax.axvline(
                self._control_stamp - (self._first_stamp or self._control_stamp),
                color="tab:green",
                linestyle="--",
                linewidth=1.2,
                label="controller starts (its first command)",
            )
            ax.legend(loc="lower right", fontsize=9)
        ax.set_ylim(0.0, 1.05)
        ax.set_xlabel(f"time since the monitor's first reading (s; {self._readings} readings)")
        ax.set_ylabel("P_N / P_max")
        ax.grid(alpha=0.3)

    def _offscreen_figure(self, size):
        if self._figure is None:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            self._figure = Figure(figsize=size, dpi=90)
            FigureCanvasAgg(self._figure)
        return self._figure

    def _on_frame(self):
        if not self._dirty or self._latest is None:
            return
        now = time.monotonic()
        if now < self._next_frame_at:
            return  # drawing is slower than frame_period_s here: keep readings flowing first
        self._dirty = False
        self._draw_frame()
        # At most a quarter of the time goes to drawing: a single-threaded executor takes one
        # reading per pass, so a frame that is always due would starve the subscriptions.
        took = time.monotonic() - now
        self._next_frame_at = now + max(self._frame_period, 4.0 * took)

    def _draw_frame(self):
        if self._save is None:
            self._show_live()
        elif self._save.suffix.lower() in (".gif", ".mp4"):
            fig = self._offscreen_figure((6.4, 4.8))
            self._draw(fig)
            fig.canvas.draw()
            self._frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())

    def _show_live(self):
        import matplotlib.pyplot as plt

        first = self._figure is None
        if first:
            plt.ion()
            self._figure = plt.figure("OPS monitor", figsize=(8, 6))
        self._draw(self._figure)
        self._figure.canvas.draw_idle()
        plt.pause(0.001)
        if first:
            self.get_logger().info("live window open")

    # ------------------------------------------------------------------ recording
    def _write_png(self):
        if self._latest is None:
            return
        fig = self._offscreen_figure((10, 6))
        self._draw(fig)
        tmp = self._save.with_name(self._save.stem + ".tmp.png")
        fig.savefig(tmp)
        tmp.replace(self._save)

    def _write_movie(self):
        if not self._frames:
            print(f"[WARN] [ops_monitor]: no trace received: {self._save} not written", flush=True)
            return
        frames = list(self._frames)
        if self._save.suffix.lower() == ".gif":
            from PIL import Image

            images = [Image.fromarray(f) for f in frames]
            images[0].save(
                self._save,
                save_all=True,
                append_images=images[1:],
                duration=int(self._frame_period * 1000),
                loop=0,
            )
        else:
            import subprocess

            h, w, _ = frames[0].shape
            cmd = [
                "ffmpeg",
                "-y",
                "-loglevel",
                "error",
                "-f",
                "rawvideo",
                "-pix_fmt",
                "rgb24",
                "-s",
                f"{w}x{h}",
                "-r",
                f"{1.0 / self._frame_period:.3f}",
                "-i",
                "-",
                "-pix_fmt",
                "yuv420p",
                str(self._save),
            ]
            subprocess.run(cmd, input=b"".join(f.tobytes() for f in frames), check=True)

    def finish(self):
        """Write the record (called on shutdown)."""
        if self._save is None:
            return
        started = time.monotonic()
        if self._save.suffix.lower() == ".png":
            self._write_png()
        else:
            self._write_movie()
        if self._save.exists():
            # Plain print: on Ctrl-C the ROS context (and its logger's rosout) is already gone.
            print(
                f"[INFO] [ops_monitor]: wrote {self._save} ({self._readings} readings, "
                f"{time.monotonic() - started:.1f} s to write)",
                flush=True,
            )

    def destroy_node(self):
        self.finish()
        super().destroy_node()


def main(args=None):
    raise SystemExit(run_node(MonitorNode, args))


if __name__ == "__main__":
    main()
