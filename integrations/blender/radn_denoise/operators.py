"""`radn.denoise_sequence`: radn over an EXR sequence, with progress, cancel (Esc) and errors in
Blender's interface; `radn.cancel` stops the running one."""

from __future__ import annotations

from typing import Optional

import bpy

from . import passes, paths
from .job import DenoiseJob, JobRequest

#: the run in progress, shown by the panel (one at a time)
current: Optional[DenoiseJob] = None


def summary(job: DenoiseJob) -> str:
    """One line on a finished run, for reports."""
    r = job.result
    return (
        f"radn: denoised {r.written} frames ({r.skipped} already done) in {r.seconds:.1f} s "
        f"-> {job.request.output}"
    )


def request_for(scene: bpy.types.Scene, input_pattern: str, frames: Optional[str]) -> JobRequest:
    """A run over `input_pattern` with the scene's panel settings and Blender's own OIDN."""
    s = scene.radn
    return JobRequest(
        input=input_pattern,
        output=paths.resolve_output(s.output, input_pattern),
        frames=frames,
        strength=s.strength,
        aovs=s.aov_list(),
        motion=passes.motion_flag(scene),
        oidn_library=paths.blender_oidn_library(),
    )


def run_blocking(request: JobRequest, log=print) -> DenoiseJob:
    """Runs radn in this thread, printing progress a frame at a time (background mode)."""
    shown = [-1]

    def each(done: float, total: int) -> None:
        if int(done) != shown[0]:
            shown[0] = int(done)
            log(f"radn: {int(done)}/{total} frames")

    return DenoiseJob(request, on_progress=each).run()


class RADN_OT_denoise_sequence(bpy.types.Operator):
    """Denoise an EXR sequence with radn (temporal, guided by Blender's OIDN); Esc cancels"""

    bl_idname = "radn.denoise_sequence"
    bl_label = "Denoise Sequence (radn)"
    bl_options = {"REGISTER"}

    input: bpy.props.StringProperty(
        name="Input",
        description="The sequence: a pattern with #### for the frame (multilayer EXRs from Cycles)",
        subtype="FILE_PATH",
    )
    output: bpy.props.StringProperty(
        name="Output",
        description="Pattern or folder for the denoised frames (empty: a radn folder beside the input)",
        subtype="FILE_PATH",
    )
    frames: bpy.props.StringProperty(
        name="Frames", description="FIRST-LAST[xSTEP] (empty: every frame found)", default=""
    )
    overwrite: bpy.props.BoolProperty(
        name="Overwrite", description="Recompute denoised frames that exist (default: skip them)"
    )

    _timer = None
    _job: Optional[DenoiseJob] = None

    def _request(self, context: bpy.types.Context) -> JobRequest:
        pattern = bpy.path.abspath(self.input) if self.input else paths.render_sequence(context.scene)
        request = request_for(context.scene, pattern, self.frames or None)
        if self.output:
            request.output = paths.resolve_output(self.output, pattern)
        request.overwrite = self.overwrite
        return request

    def execute(self, context: bpy.types.Context):
        """Runs to the end in this thread (scripts, background mode)."""
        job = run_blocking(self._request(context))
        return self._finish(job)

    def invoke(self, context: bpy.types.Context, event):
        """Runs in the background with progress in the status bar; Esc cancels."""
        global current
        if current is not None and not current.done:
            self.report({"ERROR"}, "radn is already denoising a sequence (cancel it first)")
            return {"CANCELLED"}
        self._job = current = DenoiseJob(self._request(context)).start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 1000)
        return {"RUNNING_MODAL"}

    def modal(self, context: bpy.types.Context, event):
        job = self._job
        if event.type == "ESC":
            job.cancel()  # radn stops at its next band; the timer sees it end
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        wm = context.window_manager
        wm.progress_update(int(job.fraction * 1000))
        if context.workspace is not None:
            context.workspace.status_text_set(
                f"radn: {job.frames_done:.1f}/{job.frames_total} frames (Esc to cancel)"
            )
        for area in context.screen.areas if context.screen else ():
            if area.type == "PROPERTIES":
                area.tag_redraw()
        if not job.done:
            return {"RUNNING_MODAL"}
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        return self._finish(job)

    def _finish(self, job: DenoiseJob):
        if job.error is not None:
            self.report({"WARNING"} if job.cancelled else {"ERROR"}, f"radn: {job.error}")
            return {"CANCELLED"}
        self.report({"INFO"}, summary(job))
        return {"FINISHED"}


class RADN_OT_cancel(bpy.types.Operator):
    """Stop the running radn denoise (frames finished are kept)"""

    bl_idname = "radn.cancel"
    bl_label = "Cancel radn"

    @classmethod
    def poll(cls, context):
        return current is not None and not current.done

    def execute(self, context):
        current.cancel()
        return {"FINISHED"}


class RADN_OT_enable_passes(bpy.types.Operator):
    """Turn on what radn needs: Denoising Data, Vector (without motion blur), OpenEXR MultiLayer"""

    bl_idname = "radn.enable_passes"
    bl_label = "Enable Needed Passes"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        changed = passes.enable_needed(context.scene)
        self.report({"INFO"}, "radn: " + (", ".join(changed) if changed else "all set already"))
        return {"FINISHED"}


classes = (RADN_OT_denoise_sequence, RADN_OT_cancel, RADN_OT_enable_passes)
