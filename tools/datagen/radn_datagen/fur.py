"""Fur and grass for the `fur` scenes: strands thinner than a pixel over large areas, where the
general generator's particle hair (about one scene in six, often small or out of view) left
radn's guided model behind Intel Open Image Denoise (issue 19). Furry objects near the scene
origin, some turning so their strands move, and a patch of grass on the ground between them and
the camera.

Like `detail.py`, everything is placed relative to the camera's azimuth so that it is in view,
and drawn from its own random stream (seeded from the scene seed), so adding fur never changes
the rest of a scene.
"""
import math
import random

import bpy

SHAPES = ("sphere", "monkey", "cube", "torus", "cylinder")


def fur_rng(seed: int) -> random.Random:
    """The random stream of a scene's fur, independent of the scene's and the detail's."""
    return random.Random(seed * 6007 + 31337)


def _rgb(rng, lo, hi):
    return (rng.uniform(lo, hi), rng.uniform(lo, hi), rng.uniform(lo, hi), 1.0)


def strand_material(rng):
    """A strand material: either a Principled BSDF of random colour and roughness, or Cycles'
    Principled Hair BSDF with a random melanin (real fur's absorption and its glints)."""
    mat = bpy.data.materials.new("strands")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    if rng.random() < 0.5:
        bsdf = nodes.get("Principled BSDF")
        bsdf.inputs["Base Color"].default_value = _rgb(rng, 0.02, 0.9)
        bsdf.inputs["Roughness"].default_value = rng.uniform(0.2, 0.8)
        return mat, "principled"
    hair = nodes.new("ShaderNodeBsdfHairPrincipled")
    hair.parametrization = "MELANIN"
    hair.inputs["Melanin"].default_value = rng.uniform(0.05, 0.9)
    hair.inputs["Roughness"].default_value = rng.uniform(0.2, 0.5)
    out = nodes.get("Material Output")
    links.new(hair.outputs[0], out.inputs["Surface"])
    return mat, "hair"


def add_strands(rng, obj, count, length, children, radius):
    """Particle hair on `obj`: `count` parent strands of `length` with interpolated children
    (dense fur at little scene cost); `radius` is the root radius in scene units."""
    mod = obj.modifiers.new("fur", "PARTICLE_SYSTEM")
    settings = mod.particle_system.settings
    settings.type = "HAIR"
    settings.count = count
    settings.hair_length = length
    settings.use_advanced_hair = True
    settings.child_type = "INTERPOLATED" if children else "NONE"
    settings.rendered_child_count = children
    settings.child_percent = min(children, 4)
    settings.root_radius = 1.0
    settings.tip_radius = 0.0
    settings.radius_scale = radius
    settings.use_close_tip = True
    settings.brownian_factor = rng.uniform(0.0, 0.1)
    settings.factor_random = rng.uniform(0.0, 0.3)
    settings.roughness_2 = rng.uniform(0.0, 0.05)
    mat, kind = strand_material(rng)
    obj.data.materials.append(mat)
    settings.material = len(obj.data.materials)
    return {"strands": count * max(children, 1), "length": round(length, 3), "radius": round(radius, 4),
            "shader": kind}


def _body_material(rng):
    mat = bpy.data.materials.new("fur_body")
    mat.use_nodes = True
    mat.node_tree.nodes.get("Principled BSDF").inputs["Base Color"].default_value = _rgb(rng, 0.02, 0.6)
    return mat


def add_furry_objects(rng, az, frames, key_every_frame):
    """One to three furry objects near the scene origin, across the camera's view; some turn."""
    out = []
    tangent = (-math.sin(az), math.cos(az))
    n = rng.randint(1, 3)
    for i in range(n):
        u = (i - (n - 1) / 2) * rng.uniform(1.0, 1.6) + rng.uniform(-0.3, 0.3)
        depth = rng.uniform(-0.6, 0.6)
        size = rng.uniform(0.5, 1.1)
        loc = (tangent[0] * u - depth * math.cos(az), tangent[1] * u - depth * math.sin(az), size / 2 + 0.05)
        shape = rng.choice(SHAPES)
        ops = bpy.ops.mesh
        if shape == "sphere":
            ops.primitive_uv_sphere_add(radius=size / 2, location=loc, segments=48, ring_count=24)
        elif shape == "monkey":
            ops.primitive_monkey_add(size=size, location=loc)
        elif shape == "cube":
            ops.primitive_cube_add(size=size * 0.8, location=loc)
        elif shape == "torus":
            ops.primitive_torus_add(major_radius=size / 2, minor_radius=size / 5, location=loc)
        else:
            ops.primitive_cylinder_add(radius=size / 2.5, depth=size, location=loc, vertices=48)
        obj = bpy.context.active_object
        obj.data.materials.append(_body_material(rng))
        fur = add_strands(rng, obj, rng.randint(1500, 4000), rng.uniform(0.04, 0.2) * size,
                          rng.randint(5, 20), rng.uniform(0.001, 0.004))
        spin = rng.choice([0.0, rng.uniform(-0.08, 0.08)])
        if spin:
            key_every_frame(obj, "rotation_euler", frames, lambda f, s=spin: (0.0, 0.0, f * s))
        out.append({"primitive": shape, "spin": round(spin, 3), **fur})
    return out


def add_grass(rng, az, room_size):
    """A patch of grass on the ground between the furry objects and the camera."""
    reach = 1.2 if room_size is None else min(1.2, room_size / 2 - 1.5)
    toward = rng.uniform(0.3, max(0.4, reach))
    centre = (toward * math.cos(az), toward * math.sin(az), 0.005)
    size = rng.uniform(1.5, 3.0)
    bpy.ops.mesh.primitive_plane_add(size=size, location=centre)
    patch = bpy.context.active_object
    patch.data.materials.append(_body_material(rng))
    grass = add_strands(rng, patch, rng.randint(2000, 5000), rng.uniform(0.05, 0.25), rng.randint(5, 15),
                        rng.uniform(0.002, 0.006))
    return {"size": round(size, 2), "distance_toward_camera": round(toward, 2), **grass}


def add_fur(seed, az, room_size, frames, key_every_frame):
    """Adds a scene's fur (furry objects, and grass in most scenes) in view of a camera at
    azimuth `az`; `room_size` keeps the grass inside an indoor room (None outdoors)."""
    rng = fur_rng(seed)
    desc = {"objects": add_furry_objects(rng, az, frames, key_every_frame)}
    desc["grass"] = add_grass(rng, az, room_size) if rng.random() < 0.7 else None
    return desc
