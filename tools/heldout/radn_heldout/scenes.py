"""The held-out scene families, built with bpy from a seed: `shelves` (an interior of books on
shelves lit through a window), `facade` (a street front under sky and sun with railings and
window grids), `tabletop` (glass, copper, wax and small print turning under soft boxes) and
`haze` (a spot light through blinds into a hazy room). Every animation is keyed on every frame
(linear), so Cycles' motion vectors are the motion between consecutive frames."""
import math

import bpy
import numpy as np

FAMILIES = ("shelves", "facade", "tabletop", "haze")


def reset():
    """An empty file (no default cube, camera or light)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)


def material(name, color, rough=0.5, metal=0.0, glass=0.0, wax=0.0, texture=None, bump=0.0, scale=8.0):
    """A Principled BSDF; `texture` (wave, magic, gabor, voronoi) modulates its colour and bump."""
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (*color, 1.0)
    p.inputs["Roughness"].default_value = rough
    p.inputs["Metallic"].default_value = metal
    p.inputs["Transmission Weight"].default_value = glass
    p.inputs["Subsurface Weight"].default_value = wax
    if texture:
        tex = nt.nodes.new({"wave": "ShaderNodeTexWave", "magic": "ShaderNodeTexMagic",
                            "gabor": "ShaderNodeTexGabor", "voronoi": "ShaderNodeTexVoronoi"}[texture])
        tex.inputs["Scale"].default_value = scale
        ramp = nt.nodes.new("ShaderNodeMix")
        ramp.data_type = "RGBA"
        out = tex.outputs["Fac"] if "Fac" in tex.outputs else tex.outputs[0]
        if texture == "gabor":
            out = tex.outputs["Value"]
        elif texture == "voronoi":
            out = tex.outputs["Distance"]
        nt.links.new(out, ramp.inputs["Factor"])
        ramp.inputs["A"].default_value = (*[c * 0.35 for c in color], 1.0)
        ramp.inputs["B"].default_value = (*color, 1.0)
        nt.links.new(ramp.outputs["Result"], p.inputs["Base Color"])
        if bump:
            b = nt.nodes.new("ShaderNodeBump")
            b.inputs["Strength"].default_value = bump
            nt.links.new(out, b.inputs["Height"])
            nt.links.new(b.outputs["Normal"], p.inputs["Normal"])
    return m


def emitter(name, color, strength):
    """An emission-only material (a window, a lamp's face)."""
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nt = m.node_tree
    nt.nodes.remove(nt.nodes["Principled BSDF"])
    e = nt.nodes.new("ShaderNodeEmission")
    e.inputs["Color"].default_value = (*color, 1.0)
    e.inputs["Strength"].default_value = strength
    nt.links.new(e.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    return m


def box(size, loc, mat, rot=(0, 0, 0)):
    """A box of `size` (x, y, z) at `loc` with one material."""
    bpy.ops.mesh.primitive_cube_add(size=1, location=loc, rotation=rot)
    o = bpy.context.object
    o.scale = size
    o.data.materials.append(mat)
    return o


def rod(a, b, radius, mat):
    """A thin cylinder from point a to b (railings, wires, slats)."""
    a, b = np.array(a, float), np.array(b, float)
    d = b - a
    length = float(np.linalg.norm(d))
    rot = (0.0, math.acos(d[2] / length), math.atan2(d[1], d[0]))
    bpy.ops.mesh.primitive_cylinder_add(radius=radius, depth=length, location=tuple((a + b) / 2), rotation=rot,
                                        vertices=12)
    o = bpy.context.object
    o.data.materials.append(mat)
    return o


def label(text, loc, size, mat, rot=(math.pi / 2, 0, 0)):
    """Small print: a text object, extruded a little."""
    cu = bpy.data.curves.new("label", type="FONT")
    cu.body = text
    cu.size = size
    cu.extrude = size * 0.02
    o = bpy.data.objects.new("label", cu)
    bpy.context.collection.objects.link(o)
    o.location, o.rotation_euler = loc, rot
    o.data.materials.append(mat)
    return o


def key_each_frame(obj, path, frames, value):
    """Keys `obj.<path>` on every frame with `value(t)`, t in [0, 1], linear in between."""
    f0, f1 = frames
    for f in range(f0, f1 + 1):
        setattr(obj, path, value((f - f0) / max(1, f1 - f0)))
        obj.keyframe_insert(path, frame=f)
    for fc in obj.animation_data.action.fcurves:
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"


def camera(frames, start, end, target_start, target_end, lens):
    """A camera moving from `start` to `end` while looking from `target_start` to `target_end`
    (times the scene's `radn_camera_speed`, where it is set, as far)."""
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    bpy.context.collection.objects.link(cam)
    cam.data.lens = lens
    bpy.context.scene.camera = cam
    s, e, ts, te = (np.array(v, float) for v in (start, end, target_start, target_end))
    # a fast camera runs further along the same line in the same frames
    speed = float(bpy.context.scene.get("radn_camera_speed", 1.0))

    def pose(t):
        t *= speed
        p, q = s + (e - s) * t, ts + (te - ts) * t
        d = q - p
        return tuple(p), (math.atan2(math.hypot(d[0], d[1]), -d[2]), 0.0, math.atan2(d[1], d[0]) - math.pi / 2)

    key_each_frame(cam, "location", frames, lambda t: pose(t)[0])
    key_each_frame(cam, "rotation_euler", frames, lambda t: pose(t)[1])
    return cam


def light(kind, loc, energy, color=(1, 1, 1), size=1.0, rot=(0, 0, 0), spot=0.6):
    """A lamp of Blender's `kind` (AREA, SPOT, POINT, SUN) with small, sharp shadows."""
    d = bpy.data.lights.new(kind, type=kind)
    d.energy, d.color = energy, color
    if kind == "AREA":
        d.size = size
    elif kind == "SPOT":
        d.spot_size, d.shadow_soft_size = spot, 0.02
    elif kind in ("POINT", "SUN"):
        d.shadow_soft_size = size if kind == "POINT" else 0.01
        if kind == "SUN":
            d.angle = 0.02
    o = bpy.data.objects.new(kind, d)
    bpy.context.collection.objects.link(o)
    o.location, o.rotation_euler = loc, rot
    return o


def world(color=None, strength=1.0, sky=None):
    """A flat world colour, or Cycles' Nishita sky with the sun at `sky` = (elevation, rotation)."""
    w = bpy.data.worlds.new("world")
    bpy.context.scene.world = w
    w.use_nodes = True
    bg = w.node_tree.nodes["Background"]
    bg.inputs["Strength"].default_value = strength
    if sky:
        t = w.node_tree.nodes.new("ShaderNodeTexSky")
        t.sky_type = "NISHITA"
        t.sun_elevation, t.sun_rotation = sky
        t.sun_disc = False  # the sun is a lamp, so its strength is the scene's choice
        w.node_tree.links.new(t.outputs["Color"], bg.inputs["Color"])
    else:
        bg.inputs["Color"].default_value = (*color, 1.0)


def random_rgb(rng, lo=0.05, hi=0.85):
    """A colour with each channel drawn from [lo, hi)."""
    return tuple(float(x) for x in rng.uniform(lo, hi, 3))
