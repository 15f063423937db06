"""The render passes radn reads, and what stands in their way."""

from __future__ import annotations

import bpy


def enable_needed(scene: bpy.types.Scene) -> list[str]:
    """Turns on what radn needs on every rendered view layer: Denoising Data (albedo and normal),
    Vector (motion) and multilayer EXR output. Returns what it changed, for a report."""
    changed = []
    for layer in scene.view_layers:
        if not layer.use:
            continue
        cycles = getattr(layer, "cycles", None)
        if cycles is not None and not cycles.denoising_store_passes:
            cycles.denoising_store_passes = True
            changed.append(f"{layer.name}: Denoising Data")
        if not layer.use_pass_vector:
            layer.use_pass_vector = True
            changed.append(f"{layer.name}: Vector")
    settings = scene.render.image_settings
    if settings.file_format != "OPEN_EXR_MULTILAYER":
        settings.file_format = "OPEN_EXR_MULTILAYER"
        changed.append("output: OpenEXR MultiLayer")
    return changed


def problems(scene: bpy.types.Scene) -> list[str]:
    """Why radn would denoise this scene's renders poorly or not at all, in the user's words."""
    out = []
    if scene.render.engine != "CYCLES":
        out.append("radn denoises Cycles renders (the engine is not Cycles)")
    if scene.render.image_settings.file_format != "OPEN_EXR_MULTILAYER":
        out.append("output must be OpenEXR MultiLayer")
    if scene.render.use_motion_blur:
        out.append("Vector needs motion blur off: without it radn cannot follow motion")
    for layer in scene.view_layers:
        if not layer.use:
            continue
        cycles = getattr(layer, "cycles", None)
        if cycles is not None and not cycles.denoising_store_passes:
            out.append(f"{layer.name}: turn on Denoising Data")
        if not layer.use_pass_vector:
            out.append(f"{layer.name}: turn on the Vector pass")
    return out
