"""Fine detail for the `detail` scenes: what radn's denoisers failed on in held-out Cycles
sequences (issue 18). A textured wall with bump behind a fence of wires 0.5–2 px wide, small
text and decals on it, fine procedural textures with bump (brick, wood grain, noise), chrome
and gold objects whose reflections move unlike their surfaces, and glass.

Everything is placed relative to the camera's azimuth so that it is in view, and drawn from its
own random stream (seeded from the scene seed), so adding detail never changes the rest of a
scene: a scene without detail is the same as before this module existed.
"""
import math
import random
import string

import bpy

# Principled base colours of polished metals (linear RGB)
CHROME = (0.85, 0.86, 0.88, 1.0)
GOLD = (1.0, 0.766, 0.336, 1.0)
FINE_TEXTURES = ("brick", "wood", "noise", "voronoi", "checker")


def detail_rng(seed: int) -> random.Random:
    """The random stream of a scene's detail, independent of the scene's own stream."""
    return random.Random(seed * 7919 + 104729)


def _rgb(rng, lo, hi):
    return (rng.uniform(lo, hi), rng.uniform(lo, hi), rng.uniform(lo, hi), 1.0)


def fine_material(rng, texture, scale, bump_strength, metal=False, base=None):
    """A Principled material whose colour (and height, through a Bump node) follow a fine
    procedural texture: detail at the scale of one or two pixels that albedo carries."""
    mat = bpy.data.materials.new(f"fine_{texture}")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes.get("Principled BSDF")
    coord = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (scale, scale, scale)
    links.new(coord.outputs["Object"], mapping.inputs["Vector"])
    if texture == "brick":
        t = nodes.new("ShaderNodeTexBrick")
        t.inputs["Mortar Size"].default_value = rng.uniform(0.01, 0.03)
        t.inputs["Color1"].default_value = _rgb(rng, 0.3, 0.7)
        t.inputs["Color2"].default_value = _rgb(rng, 0.2, 0.5)
        t.inputs["Mortar"].default_value = _rgb(rng, 0.6, 0.9)
        colour, height = t.outputs["Color"], t.outputs["Fac"]
    else:
        if texture == "wood":
            t = nodes.new("ShaderNodeTexWave")
            t.inputs["Distortion"].default_value = rng.uniform(2, 8)
            t.inputs["Detail"].default_value = rng.uniform(2, 6)
            t.inputs["Detail Scale"].default_value = rng.uniform(1, 3)
            fac = t.outputs["Fac"]
        elif texture == "noise":
            t = nodes.new("ShaderNodeTexNoise")
            t.inputs["Detail"].default_value = rng.uniform(6, 15)
            t.inputs["Roughness"].default_value = rng.uniform(0.5, 0.75)
            fac = t.outputs["Fac"]
        elif texture == "voronoi":
            t = nodes.new("ShaderNodeTexVoronoi")
            fac = t.outputs["Distance"]
        else:
            t = nodes.new("ShaderNodeTexChecker")
            fac = t.outputs["Fac"]
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        a = base or _rgb(rng, 0.05, 0.9)
        mix.inputs["A"].default_value = a
        mix.inputs["B"].default_value = tuple(min(1.0, v * rng.uniform(0.2, 0.6)) for v in a[:3]) + (1.0,)
        links.new(fac, mix.inputs["Factor"])
        colour, height = mix.outputs["Result"], fac
    links.new(mapping.outputs["Vector"], t.inputs["Vector"])
    links.new(colour, bsdf.inputs["Base Color"])
    bump = nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = bump_strength
    bump.inputs["Distance"].default_value = 0.02
    links.new(height, bump.inputs["Height"])
    links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])
    if metal:
        bsdf.inputs["Metallic"].default_value = 1.0
        bsdf.inputs["Roughness"].default_value = rng.uniform(0.05, 0.3)
    else:
        bsdf.inputs["Roughness"].default_value = rng.uniform(0.4, 1.0)
    return mat


def polished_metal(rng, gold):
    """Chrome or gold, nearly mirror-like: its reflections move unlike the surface."""
    mat = bpy.data.materials.new("gold" if gold else "chrome")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = GOLD if gold else CHROME
    bsdf.inputs["Metallic"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = rng.choice([0.0, rng.uniform(0.01, 0.08)])
    return mat


def clear_glass(rng):
    """Clear or slightly frosted glass."""
    mat = bpy.data.materials.new("glass")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bsdf.inputs["Transmission Weight"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = rng.choice([0.0, 0.0, rng.uniform(0.02, 0.15)])
    bsdf.inputs["IOR"].default_value = rng.uniform(1.4, 1.55)
    return mat


def flat_material(rng, colour):
    mat = bpy.data.materials.new("flat")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = colour
    bsdf.inputs["Roughness"].default_value = rng.uniform(0.3, 0.9)
    return mat


def _facing(az):
    """Euler rotation that turns a plane (or text, both lie in XY facing +Z) to face the camera
    at azimuth `az` about the scene origin."""
    return (math.pi / 2, 0.0, az + math.pi / 2)


def _link(obj):
    bpy.context.scene.collection.objects.link(obj)
    return obj


def add_wall(rng, az, distance, width, height):
    """A wall facing the camera behind the scene origin, with a fine texture and bump."""
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    wall = bpy.context.active_object
    wall.scale = (width, height, 1.0)
    wall.rotation_euler = _facing(az)
    wall.location = (-distance * math.cos(az), -distance * math.sin(az), height / 2)
    texture = rng.choice(("brick", "brick", "wood", "noise"))
    # object coordinates are those of the unit plane: the texture scale is per wall width
    scale = rng.uniform(6.0, 14.0) if texture == "brick" else rng.uniform(10.0, 40.0)
    wall.data.materials.append(fine_material(rng, texture, scale, rng.uniform(0.3, 1.0)))
    return {"texture": texture, "scale": round(scale, 2), "distance": round(distance, 2)}


def add_fence(rng, az, distance, width, height):
    """A grid of thin wires (optionally tilted) facing the camera: 0.5–2 px wide at radn's
    training resolutions, the geometry a 5×5 kernel most easily averages away."""
    curve = bpy.data.curves.new("fence", "CURVE")
    curve.dimensions = "3D"
    radius = rng.uniform(0.003, 0.012)
    curve.bevel_depth = radius
    curve.bevel_resolution = 2
    spacing = rng.uniform(0.08, 0.3)
    tilt = rng.uniform(-0.6, 0.6)
    centre = (-distance * math.cos(az), -distance * math.sin(az))
    tangent = (-math.sin(az), math.cos(az))

    def point(u, v):
        # u along the fence, v up; tilt shears the grid
        uu = u * math.cos(tilt) - v * math.sin(tilt)
        vv = u * math.sin(tilt) + v * math.cos(tilt)
        return (centre[0] + tangent[0] * uu, centre[1] + tangent[1] * uu, height / 2 + vv, 1.0)

    half_w, half_h = width / 2, height / 2
    lines = 0
    for axis in (0, 1) if rng.random() < 0.8 else (0,):
        span = half_w if axis == 0 else half_h
        other = half_h if axis == 0 else half_w
        k = -span
        while k <= span and lines < 120:
            sp = curve.splines.new("POLY")
            sp.points.add(1)
            a, b = (k, -other), (k, other)
            sp.points[0].co = point(*a) if axis == 0 else point(a[1], a[0])
            sp.points[1].co = point(*b) if axis == 0 else point(b[1], b[0])
            k += spacing
            lines += 1
    obj = _link(bpy.data.objects.new("fence", curve))
    mat = polished_metal(rng, gold=False) if rng.random() < 0.4 else flat_material(rng, _rgb(rng, 0.02, 0.9))
    curve.materials.append(mat)
    return {"wire_radius": round(radius, 4), "spacing": round(spacing, 3), "wires": lines,
            "distance": round(distance, 2)}


def random_text(rng):
    """A short label of letters, digits and punctuation."""
    alphabet = string.ascii_letters + string.digits + "  -.:/#"
    words = rng.randint(1, 4)
    return " ".join("".join(rng.choice(alphabet) for _ in range(rng.randint(2, 8))) for _ in range(words)).strip()


def add_text(rng, az, distance, spread, z_range):
    """A line of small text facing the camera (a decal on the wall, or a sign in front of it),
    high contrast against what is behind it."""
    curve = bpy.data.curves.new("text", "FONT")
    body = random_text(rng) or "radn"
    curve.body = body
    curve.size = rng.uniform(0.08, 0.35)
    curve.extrude = rng.choice([0.0, 0.004])
    curve.align_x = "CENTER"
    obj = _link(bpy.data.objects.new("text", curve))
    obj.rotation_euler = _facing(az)
    u = rng.uniform(-spread, spread)
    tangent = (-math.sin(az), math.cos(az))
    obj.location = (-distance * math.cos(az) + tangent[0] * u, -distance * math.sin(az) + tangent[1] * u,
                    rng.uniform(*z_range))
    bright = rng.random() < 0.5
    colour = _rgb(rng, 0.7, 1.0) if bright else _rgb(rng, 0.0, 0.08)
    if rng.random() < 0.15:
        mat = polished_metal(rng, gold=True)
    else:
        mat = flat_material(rng, colour)
    curve.materials.append(mat)
    return {"text": body, "size": round(curve.size, 3)}


def add_objects(rng, az, frames, key_every_frame):
    """Chrome, gold, glass and finely textured objects near the scene origin; some turn, so
    their reflections and textures move differently."""
    out = []
    kinds = ["chrome", "gold", "glass", "fine"]
    rng.shuffle(kinds)
    tangent = (-math.sin(az), math.cos(az))
    for i, kind in enumerate(kinds[: rng.randint(2, 4)]):
        u = (i - 1.5) * rng.uniform(0.9, 1.4)
        depth = rng.uniform(-0.8, 0.8)
        size = rng.uniform(0.5, 1.1)
        loc = (tangent[0] * u - depth * math.cos(az), tangent[1] * u - depth * math.sin(az), size / 2 + 0.02)
        shape = rng.choice(("sphere", "torus", "cube", "monkey", "cylinder"))
        ops = bpy.ops.mesh
        if shape == "sphere":
            ops.primitive_uv_sphere_add(radius=size / 2, location=loc, segments=64, ring_count=32)
        elif shape == "torus":
            ops.primitive_torus_add(major_radius=size / 2, minor_radius=size / 6, location=loc)
        elif shape == "cube":
            ops.primitive_cube_add(size=size * 0.8, location=loc)
        elif shape == "monkey":
            ops.primitive_monkey_add(size=size, location=loc)
        else:
            ops.primitive_cylinder_add(radius=size / 2, depth=size, location=loc, vertices=64)
        obj = bpy.context.active_object
        if shape in ("sphere", "torus", "monkey", "cylinder"):
            bpy.ops.object.shade_smooth()
        if kind == "chrome":
            mat = polished_metal(rng, gold=False)
        elif kind == "gold":
            mat = polished_metal(rng, gold=True)
        elif kind == "glass":
            mat = clear_glass(rng)
        else:
            tex = rng.choice(FINE_TEXTURES)
            mat = fine_material(rng, tex, rng.uniform(8.0, 40.0), rng.uniform(0.2, 0.8), metal=rng.random() < 0.3)
        obj.data.materials.append(mat)
        spin = rng.choice([0.0, rng.uniform(-0.1, 0.1)])
        if spin:
            key_every_frame(obj, "rotation_euler", frames, lambda f, s=spin: (0.0, 0.0, f * s))
        out.append({"primitive": shape, "material": kind if kind != "fine" else f"fine_{tex}", "spin": spin})
    return out


def add_detail(seed, az, room_size, frames, key_every_frame):
    """Adds a scene's detail (wall, fence, text, polished and fine objects) in view of a camera
    at azimuth `az`; `room_size` keeps it inside an indoor room (None outdoors)."""
    rng = detail_rng(seed)
    limit = room_size / 2 - 0.15 if room_size else 6.0
    wall_distance = min(rng.uniform(2.2, 3.5), limit)
    width, height = 10.0, min(6.0, room_size - 0.2) if room_size else 6.0
    desc = {"wall": add_wall(rng, az, wall_distance, width, height)}
    fence_distance = wall_distance - rng.uniform(0.25, 1.0)
    desc["fence"] = add_fence(rng, az, fence_distance, rng.uniform(3.0, 6.0), rng.uniform(1.5, 3.0)) \
        if rng.random() < 0.85 else None
    desc["text"] = [add_text(rng, az, wall_distance - 0.02, 2.5, (0.3, 2.5)) for _ in range(rng.randint(2, 5))]
    desc["objects"] = add_objects(rng, az, frames, key_every_frame)
    return desc
