"""Glass standing on a textured floor, for the `contact` scenes: the thin dark edges where a
glass object meets the floor, and the caustics a small light throws through it onto fine
texture. On held-aside test scene 3 000 002 radn's kernels lifted exactly those edges that
Intel Open Image Denoise kept (docs/research/guided.md, "The glass scene up close"), and no validation
scene had them: the general generator's objects mostly float above the floor.

Like `fur.py`, everything is placed relative to the camera's azimuth so that it is in view, and
drawn from its own random stream (seeded from the scene seed), so adding it never changes the
rest of a scene.
"""
import math
import random

import bpy

SHAPES = ("cube", "cylinder", "cone", "sphere", "slab")


def contact_rng(seed: int) -> random.Random:
    """The random stream of a scene's glass on the floor, independent of the scene's, the
    detail's and the fur's."""
    return random.Random(seed * 7919 + 4242)


def glass_material(rng):
    """Clear glass (sometimes slightly frosted or tinted), IOR 1.4 to 1.6."""
    mat = bpy.data.materials.new("contact_glass")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Transmission Weight"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = rng.choice([0.0, 0.0, rng.uniform(0.02, 0.15)])
    bsdf.inputs["IOR"].default_value = rng.uniform(1.4, 1.6)
    tint = rng.uniform(0.8, 1.0)
    bsdf.inputs["Base Color"].default_value = (tint, rng.uniform(0.85, 1.0), rng.uniform(0.85, 1.0), 1.0)
    return mat


def floor_material(rng):
    """A finely textured floor: a procedural checker, brick or noise pattern a few pixels wide."""
    mat = bpy.data.materials.new("contact_floor")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes.get("Principled BSDF")
    bsdf.inputs["Roughness"].default_value = rng.uniform(0.3, 0.9)
    kind = rng.choice(["checker", "brick", "noise"])
    scale = rng.uniform(20.0, 60.0)
    if kind == "checker":
        tex = nodes.new("ShaderNodeTexChecker")
    elif kind == "brick":
        tex = nodes.new("ShaderNodeTexBrick")
    else:
        tex = nodes.new("ShaderNodeTexNoise")
        tex.inputs["Detail"].default_value = 8.0
    tex.inputs["Scale"].default_value = scale
    ramp = nodes.new("ShaderNodeMix")
    ramp.data_type = "RGBA"
    lo = rng.uniform(0.05, 0.3)
    hi = rng.uniform(0.5, 0.9)
    ramp.inputs["A"].default_value = (lo, lo * rng.uniform(0.8, 1.2), lo * rng.uniform(0.8, 1.2), 1.0)
    ramp.inputs["B"].default_value = (hi, hi * rng.uniform(0.8, 1.0), hi * rng.uniform(0.8, 1.0), 1.0)
    links.new(tex.outputs["Fac"], ramp.inputs["Factor"])
    links.new(ramp.outputs["Result"], bsdf.inputs["Base Color"])
    return mat, kind, round(scale, 1)


def _add_shape(shape, loc, size):
    """A glass shape of `size` resting on the floor at `loc` (x, y); returns the object."""
    ops = bpy.ops.mesh
    x, y = loc
    if shape == "cube":
        ops.primitive_cube_add(size=size, location=(x, y, size / 2))
    elif shape == "cylinder":
        ops.primitive_cylinder_add(radius=size / 2.5, depth=size, location=(x, y, size / 2), vertices=64)
    elif shape == "cone":
        ops.primitive_cone_add(radius1=size / 2, depth=size, location=(x, y, size / 2), vertices=64)
    elif shape == "sphere":
        ops.primitive_uv_sphere_add(radius=size / 2, location=(x, y, size / 2), segments=64, ring_count=32)
        bpy.ops.object.shade_smooth()
    else:  # a flat slab: long contact edges
        ops.primitive_cube_add(size=1.0, location=(x, y, size / 8))
        bpy.context.active_object.scale = (size, size * 0.6, size / 4)
    return bpy.context.active_object


def add_contact(seed, az, room_size, frames, key_every_frame):
    """Adds two to four glass objects standing on a finely textured floor patch in view of a camera
    at azimuth `az`, and a small bright light above them that throws caustics; some objects
    slide slowly along the floor. `room_size` keeps the patch inside an indoor room (None
    outdoors)."""
    rng = contact_rng(seed)
    tangent = (-math.sin(az), math.cos(az))
    reach = 2.5 if room_size is None else min(2.5, room_size / 2 - 0.5)
    patch = rng.uniform(3.0, 2 * reach)
    bpy.ops.mesh.primitive_plane_add(size=patch, location=(0.0, 0.0, 0.002))
    floor = bpy.context.active_object
    mat, kind, scale = floor_material(rng)
    floor.data.materials.append(mat)
    objects = []
    n = rng.randint(2, 4)
    for i in range(n):
        u = (i - (n - 1) / 2) * rng.uniform(0.9, 1.4) + rng.uniform(-0.2, 0.2)
        depth = rng.uniform(-0.5, 0.5)
        x, y = tangent[0] * u - depth * math.cos(az), tangent[1] * u - depth * math.sin(az)
        size = rng.uniform(0.4, 1.0)
        shape = rng.choice(SHAPES)
        obj = _add_shape(shape, (x, y), size)
        obj.data.materials.append(glass_material(rng))
        slide = rng.choice([0.0, 0.0, rng.uniform(-0.03, 0.03)])
        if slide:
            z = obj.location.z
            key_every_frame(obj, "location", frames,
                            lambda f, x=x, y=y, z=z, s=slide: (x + tangent[0] * s * f, y + tangent[1] * s * f, z))
        objects.append({"primitive": shape, "size": round(size, 2), "slide": round(slide, 3)})
    lamp = bpy.data.objects.new("contact_light", bpy.data.lights.new("contact_light", "POINT"))
    bpy.context.scene.collection.objects.link(lamp)
    lamp.data.shadow_soft_size = rng.uniform(0.01, 0.05)
    lamp.data.energy = rng.uniform(150, 600)
    side = rng.uniform(-1.5, 1.5)
    lamp.location = (tangent[0] * side, tangent[1] * side, rng.uniform(1.5, 3.0))
    return {"objects": objects, "floor": {"pattern": kind, "scale": scale, "size": round(patch, 2)},
            "light": {"energy": round(lamp.data.energy, 1), "height": round(lamp.location.z, 2)}}
