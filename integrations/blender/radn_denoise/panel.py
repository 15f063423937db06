"""Output Properties ▸ Temporal denoise (radn)."""

from __future__ import annotations

import bpy

from . import operators, passes, paths


class RADN_PT_temporal_denoise(bpy.types.Panel):
    """radn's settings, what the scene lacks for it, and the run in progress"""

    bl_label = "Temporal Denoise (radn)"
    bl_idname = "RADN_PT_temporal_denoise"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "output"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_header(self, context):
        self.layout.prop(context.scene.radn, "after_animation", text="")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        scene = context.scene
        s = scene.radn
        layout.prop(s, "after_animation")
        if s.after_animation:
            layout.label(text="Needs the Denoising Data pass (and Vector, where motion blur is off)", icon="INFO")
        layout.label(text=passes.motion_source(scene), icon="INFO")
        layout.prop(s, "output")
        if not s.output:
            layout.label(text="Writes to: " + paths.default_output(paths.render_sequence(scene)), icon="INFO")
        layout.prop(s, "strength")
        col = layout.column(heading="Extra Passes")
        col.prop(s, "aovs")
        col.prop(s, "other_aovs")
        issues = passes.problems(scene)
        if issues:
            box = layout.box()
            for text in issues:
                box.label(text=text, icon="ERROR")
            box.operator("radn.enable_passes")
        if paths.blender_oidn_library() is None:
            layout.label(text="Blender's OIDN not found: radn uses its built-in copy of OIDN's networks", icon="INFO")
        job = operators.current
        row = layout.row()
        if job is not None and not job.done:
            row.label(text=f"Denoising {job.frames_done:.1f}/{job.frames_total} frames")
            row.operator("radn.cancel", icon="CANCEL")
        else:
            op = row.operator("radn.denoise_sequence", text="Denoise Rendered Sequence", icon="RENDER_ANIMATION")
            op.input = paths.render_sequence(scene)
            if job is not None and job.error is not None:
                layout.label(text="Last run: " + job.error, icon="ERROR")


classes = (RADN_PT_temporal_denoise,)
