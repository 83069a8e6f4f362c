"""The ``human`` rendering: show frames in a matplotlib window that is reused from step to step.

matplotlib is used because it is already a dependency and picks a GUI toolkit by itself. The
window is created on the first frame and updated in place afterwards (creating a figure per step
would leak windows and be slow); :func:`show_frame` therefore returns a handle that the
environment keeps (``env._renderer``) and passes back on the next call, and ``env.close()`` calls
``handle.close()``.

Training jobs often run with ``render_mode="human"`` left on by accident on machines without a
display. That must not crash a long run, so without an interactive backend (headless, Agg) a
call does nothing at all, and the first one in the process warns through ``gymnasium.logger``.
Once per process, not per env: the missing display is a fact about the machine, and tools that
make many envs in every render mode (Gymnasium's ``check_env`` makes a ``human`` env for each
call) would otherwise repeat it for every env.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

#: Windows show frames this many times larger than the array (48-pixel cells are small on screen).
WINDOW_SCALE = 1.5
_EVENT_LOOP_SECONDS = 0.001
#: Whether this process has said that it cannot open windows (module docstring).
_NO_DISPLAY_REPORTED = {"done": False}


class FrameWindow:
    """A matplotlib figure showing one frame at a time; keep it and pass it back to update it."""

    def __init__(self, figure: Any, image: Any) -> None:
        self.figure = figure
        self.image = image

    @property
    def is_open(self) -> bool:
        """False once the user closed the window (the next frame then opens a new one)."""
        import matplotlib.pyplot as plt  # matplotlib waits: importing morality_gym.render.window must not load it

        return plt.fignum_exists(self.figure.number)

    def update(self, frame: np.ndarray, title: str) -> None:
        """Replace the shown frame and let the GUI process its events briefly."""
        self.image.set_data(frame)
        _set_title(self.figure, title)
        _refresh(self.figure)

    def close(self) -> None:
        import matplotlib.pyplot as plt  # matplotlib waits: importing morality_gym.render.window must not load it

        plt.close(self.figure)


class NoDisplay:
    """The handle used when frames cannot be shown: it has already warned and does nothing."""

    def __init__(self, reason: str) -> None:
        self.reason = reason

    def close(self) -> None:
        """Nothing to close; present so that callers can treat every handle alike."""


def _set_title(figure: Any, title: str) -> None:
    manager = figure.canvas.manager
    if manager is not None:
        manager.set_window_title(title)


def _refresh(figure: Any) -> None:
    """Draw and run the event loop for a moment, for this figure only (``plt.pause`` would show
    every figure and may raise the window above the user's terminal on each frame)."""
    canvas = figure.canvas
    canvas.draw_idle()
    try:
        canvas.start_event_loop(_EVENT_LOOP_SECONDS)
    except NotImplementedError:
        canvas.flush_events()


def _open_window(frame: np.ndarray, title: str) -> FrameWindow | NoDisplay:
    """A new window showing ``frame``, or a :class:`NoDisplay` saying why there is none.

    Any exception while opening counts as "no window": GUI toolkits fail in many ways without a
    display (Tk's TclError, a missing Qt, a RuntimeError), and none of them should stop a run.
    """
    import matplotlib.pyplot as plt  # matplotlib waits: importing morality_gym.render.window must not load it

    height, width = frame.shape[:2]
    try:
        figure = plt.figure(figsize=(width * WINDOW_SCALE / 100, height * WINDOW_SCALE / 100), dpi=100)
    except Exception as exc:  # noqa: BLE001 - see the docstring
        return NoDisplay(f"matplotlib could not open a window ({type(exc).__name__}: {exc})")
    if figure.canvas.required_interactive_framework is None:
        plt.close(figure)
        return NoDisplay(f"matplotlib's backend {plt.get_backend()!r} cannot open windows (no display?)")
    try:
        axes = figure.add_axes((0.0, 0.0, 1.0, 1.0))
        axes.set_axis_off()
        image = axes.imshow(frame, interpolation="antialiased")
        _set_title(figure, title)
        figure.show()
        _refresh(figure)
    except Exception as exc:  # noqa: BLE001 - see the docstring
        plt.close(figure)
        return NoDisplay(f"matplotlib could not show the window ({type(exc).__name__}: {exc})")
    return FrameWindow(figure, image)


def show_frame(frame: np.ndarray, handle: Any, title: str) -> FrameWindow | NoDisplay:
    """Show ``frame`` in the window of ``handle`` (opening one if needed); returns the handle to
    pass back next time. Without a display it warns once and returns a do-nothing handle."""
    if isinstance(handle, NoDisplay):
        return handle
    if isinstance(handle, FrameWindow) and handle.is_open:
        handle.update(frame, title)
        return handle
    window = _open_window(frame, title)
    if isinstance(window, NoDisplay) and not _NO_DISPLAY_REPORTED["done"]:
        _NO_DISPLAY_REPORTED["done"] = True
        gymnasium.logger.warn(
            f"render_mode='human' cannot show {title}: {window.reason}. Frames are not shown; "
            "use render_mode='rgb_array' to record them, or set MPLBACKEND to an interactive backend. "
            "(Said once per process.)"
        )
    return window


__all__ = ["FrameWindow", "NoDisplay", "show_frame"]
