"""Denoising after an animation render: the frames each render writes are collected, and when
the render completes radn runs over them — in the background with the interface live, or in
this thread under `blender -b`."""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from . import operators, paths

_written: list[int] = []


def frame_range(frames: list[int], step: int) -> str:
    """radn's FIRST-LAST[xSTEP] for the frames a render wrote."""
    first, last = min(frames), max(frames)
    step = max(step, 1)
    return f"{first}-{last}" + (f"x{step}" if step > 1 else "")


@persistent
def _on_init(scene, *_):
    _written.clear()


@persistent
def _on_write(scene, *_):
    _written.append(scene.frame_current)


@persistent
def _on_cancel(scene, *_):
    _written.clear()


@persistent
def _on_complete(scene, *_):
    frames = sorted(set(_written))
    _written.clear()
    if not frames or not scene.radn.after_animation:
        return
    pattern = paths.render_sequence(scene)
    franges = frame_range(frames, scene.frame_step)
    if bpy.app.background:
        job = operators.run_blocking(operators.request_for(scene, pattern, franges))
        print(f"radn: {job.error}" if job.error else operators.summary(job))
        return

    def start():
        wm = bpy.context.window_manager
        window = wm.windows[0] if wm.windows else None
        with bpy.context.temp_override(window=window):
            bpy.ops.radn.denoise_sequence("INVOKE_DEFAULT", input=pattern, frames=franges)
        return None

    # the render job still holds the interface: start once it has returned
    bpy.app.timers.register(start, first_interval=0.1)


_HANDLERS = (
    (bpy.app.handlers.render_init, _on_init),
    (bpy.app.handlers.render_write, _on_write),
    (bpy.app.handlers.render_cancel, _on_cancel),
    (bpy.app.handlers.render_complete, _on_complete),
)


def register() -> None:
    """Adds the render handlers."""
    for lst, fn in _HANDLERS:
        if fn not in lst:
            lst.append(fn)


def unregister() -> None:
    """Removes the render handlers."""
    for lst, fn in _HANDLERS:
        if fn in lst:
            lst.remove(fn)
