"""The scene's radn settings (Output Properties ▸ Temporal denoise (radn))."""

from __future__ import annotations

import bpy

from . import passes

#: Cycles light passes radn can denoise with the beauty's weights (layer name, label)
LIGHT_PASSES = (
    ("DiffDir", "Diffuse Direct"),
    ("DiffInd", "Diffuse Indirect"),
    ("GlossDir", "Glossy Direct"),
    ("GlossInd", "Glossy Indirect"),
    ("TransDir", "Transmission Direct"),
    ("TransInd", "Transmission Indirect"),
    ("VolumeDir", "Volume Direct"),
    ("VolumeInd", "Volume Indirect"),
    ("Emit", "Emission"),
    ("Env", "Environment"),
    ("AO", "Ambient Occlusion"),
)


def _enabled_changed(self: "RadnSettings", context: bpy.types.Context) -> None:
    if self.after_animation:
        passes.enable_needed(context.scene)


class RadnSettings(bpy.types.PropertyGroup):
    """Per-scene settings of the temporal denoiser."""

    after_animation: bpy.props.BoolProperty(
        name="After Rendering an Animation",
        description=(
            "Denoise the frames of every animation render with radn when it finishes "
            "(turns on the Denoising Data and Vector passes and multilayer EXR output)"
        ),
        default=False,
        update=_enabled_changed,
    )
    output: bpy.props.StringProperty(
        name="Output",
        description=(
            "Where denoised frames go: a pattern with #### for the frame, or a folder. "
            "Empty: a radn folder beside the render. Never the render itself"
        ),
        default="",
        subtype="FILE_PATH",
    )
    strength: bpy.props.FloatProperty(
        name="Strength",
        description="1 as tuned; lower keeps more of the render's noise and detail",
        default=1.0,
        min=0.1,
        max=4.0,
        soft_max=2.0,
    )
    aovs: bpy.props.EnumProperty(
        name="Extra Passes",
        description="Light passes to denoise with the beauty's weights (each must be enabled)",
        items=[(key, label, f"Denoise the {label} pass too") for key, label in LIGHT_PASSES],
        options={"ENUM_FLAG"},
        default=set(),
    )
    other_aovs: bpy.props.StringProperty(
        name="Other Passes",
        description="Further layers to denoise with the beauty's weights, comma-separated (AOVs, light groups)",
        default="",
    )

    def aov_list(self) -> list[str]:
        """The extra layers to denoise, as radn names them."""
        names = [key for key, _ in LIGHT_PASSES if key in self.aovs]
        names += [n.strip() for n in self.other_aovs.split(",") if n.strip()]
        return names
