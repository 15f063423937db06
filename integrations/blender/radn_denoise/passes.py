"""The render passes radn reads, where its motion comes from, and what stands in its way."""

from __future__ import annotations

from typing import Optional

import bpy


def enable_needed(scene: bpy.types.Scene) -> list[str]:
    """Turns on what radn needs on every rendered view layer: Denoising Data (albedo and normal),
    Vector (motion; only without motion blur, which Cycles cannot write it with: radn then
    finds motion itself) and multilayer EXR output. Returns what it changed, for a report."""
    changed = []
    for layer in scene.view_layers:
        if not layer.use:
            continue
        cycles = getattr(layer, "cycles", None)
        if cycles is not None and not cycles.denoising_store_passes:
            cycles.denoising_store_passes = True
            changed.append(f"{layer.name}: Denoising Data")
        if not scene.render.use_motion_blur and not layer.use_pass_vector:
            layer.use_pass_vector = True
            changed.append(f"{layer.name}: Vector")
    settings = scene.render.image_settings
    if settings.file_format != "OPEN_EXR_MULTILAYER":
        settings.file_format = "OPEN_EXR_MULTILAYER"
        changed.append("output: OpenEXR MultiLayer")
    return changed


def _vectors_written(scene: bpy.types.Scene) -> bool:
    """Whether the renders will hold Cycles' motion vectors."""
    layers = [layer for layer in scene.view_layers if layer.use]
    return not scene.render.use_motion_blur and all(layer.use_pass_vector for layer in layers)


def motion_flag(scene: bpy.types.Scene) -> Optional[str]:
    """radn's --motion for this scene's renders: "estimate" with motion blur on (Cycles may still
    write an empty Vector pass then), else radn's own choice."""
    return "estimate" if scene.render.use_motion_blur else None


def motion_source(scene: bpy.types.Scene) -> str:
    """Which motion radn will align the frames with, in the user's words (for the panel)."""
    if scene.render.use_motion_blur:
        return "Motion: estimated from the frames (motion blur is on)"
    if _vectors_written(scene):
        return "Motion: Cycles' Vector pass"
    return "Motion: estimated from the frames (no Vector pass)"


def problems(scene: bpy.types.Scene) -> list[str]:
    """Why radn would denoise this scene's renders poorly or not at all, in the user's words."""
    out = []
    if scene.render.engine != "CYCLES":
        out.append("radn denoises Cycles renders (the engine is not Cycles)")
    if scene.render.image_settings.file_format != "OPEN_EXR_MULTILAYER":
        out.append("output must be OpenEXR MultiLayer")
    for layer in scene.view_layers:
        if not layer.use:
            continue
        cycles = getattr(layer, "cycles", None)
        if cycles is not None and not cycles.denoising_store_passes:
            out.append(f"{layer.name}: turn on Denoising Data")
    return out
