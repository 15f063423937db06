"""One builder per scene family: each lays out its scene from `rng` over `frames` and returns
what it drew (kept in the manifest)."""
import math

import bpy

from .scenes import (
    box,
    camera,
    emitter,
    key_each_frame,
    label,
    light,
    material,
    random_rgb,
    rod,
    world,
)

WORDS = ("ISBN 0-1", "VOL. III", "NOTES", "RADN", "No. 42", "FIELD GUIDE", "ATLAS", "LOG 7")


def shelves(rng, frames):
    """Books of random sizes on three boards, lit through a window at the side; a sideways dolly."""
    wood = material("wood", (0.45, 0.27, 0.12), 0.45, texture="wave", bump=0.15, scale=float(rng.uniform(3, 9)))
    wall = material("wall", random_rgb(rng, 0.5, 0.85), 0.8, texture="gabor", bump=0.05, scale=40.0)
    box((8, 8, 0.1), (0, 0, 0), material("floor", (0.3, 0.22, 0.15), 0.3, texture="wave", scale=2.0))
    box((8, 0.1, 4), (0, 1.2, 2), wall)
    box((0.1, 8, 4), (-3.2, 0, 2), wall)
    books = 0
    for z in (0.4, 1.1, 1.8):
        box((3.4, 0.5, 0.04), (0, 0.9, z), wood)
        x = -1.6
        while x < 1.6:
            w, h = rng.uniform(0.04, 0.12), rng.uniform(0.3, 0.55)
            tilt = rng.uniform(-0.25, 0.0) if rng.random() < 0.1 else 0.0
            box((w, rng.uniform(0.3, 0.45), h), (x + w / 2, 0.9, z + 0.02 + h / 2),
                material(f"book{books}", random_rgb(rng), rng.uniform(0.2, 0.7)), rot=(0, tilt, 0))
            if rng.random() < 0.2:
                label(str(rng.choice(WORDS)), (x + w / 2 + 0.01, 0.64, z + 0.05), w * 0.6,
                      material("ink", (0.9, 0.85, 0.6), 0.3), rot=(math.pi / 2, -math.pi / 2, 0))
            x += w + rng.uniform(0.0, 0.02)
            books += 1
    win = box((0.05, 1.2, 1.0), (3.3, 0.2, 2.0), emitter("window", (1.0, 0.95, 0.85), float(rng.uniform(10, 30))))
    light("AREA", (3.2, 0.2, 2.0), float(rng.uniform(500, 1200)), (1.0, 0.93, 0.8), 1.2, rot=(0, -math.pi / 2, 0))
    light("POINT", (-1.5, -1.5, 3.2), float(rng.uniform(60, 150)), (1.0, 0.8, 0.6), 0.2)
    world((0.02, 0.02, 0.03), 1.0)
    y = rng.uniform(-2.8, -2.2)
    dx = rng.uniform(0.3, 0.8)
    camera(frames, (-dx, y, 1.2), (dx, y, 1.25), (-dx * 0.7, 0.9, 1.1), (dx * 0.7, 0.9, 1.1), float(rng.uniform(28, 45)))
    return {"books": books, "window": win.name}


def facade(rng, frames):
    """A street front under Nishita sky and sun: window grids, balcony railings of thin rods,
    a textured pavement; the camera pans along the street."""
    world(sky=(float(rng.uniform(0.15, 0.7)), float(rng.uniform(0, 2 * math.pi))), strength=0.08)
    light("SUN", (0, 0, 10), float(rng.uniform(0.8, 1.6)), (1.0, 0.95, 0.88), rot=(rng.uniform(0.4, 1.0), 0, rng.uniform(0, 6)))
    box((40, 40, 0.1), (0, 0, -0.05), material("pavement", (0.35, 0.35, 0.33), 0.7, texture="voronoi",
                                                 bump=0.3, scale=float(rng.uniform(20, 60))))
    glass = material("pane", (0.05, 0.07, 0.08), 0.05, metal=0.8)
    rail = material("rail", (0.08, 0.08, 0.08), 0.35, metal=1.0)
    x0, n = -9.0, 0
    while x0 < 9.0:
        w, h = rng.uniform(3, 6), rng.uniform(5, 12)
        box((w, 3, h), (x0 + w / 2, 4, h / 2), material(f"wall{n}", random_rgb(rng, 0.3, 0.8), 0.8, texture="wave",
                                                         bump=0.1, scale=float(rng.uniform(10, 30))))
        cols, rows = int(w / 1.1), int(h / 1.6)
        for c in range(cols):
            for r in range(rows):
                cx, cz = x0 + (c + 0.5) * w / cols, 1.0 + r * 1.6
                box((0.6, 0.1, 0.9), (cx, 2.48, cz), glass)
                if r > 0 and rng.random() < 0.3:
                    for k in range(7):
                        rod((cx - 0.45 + k * 0.15, 2.2, cz - 0.5), (cx - 0.45 + k * 0.15, 2.2, cz - 0.05), 0.008, rail)
                    rod((cx - 0.5, 2.2, cz - 0.05), (cx + 0.5, 2.2, cz - 0.05), 0.012, rail)
        x0 += w + rng.uniform(0.1, 0.6)
        n += 1
    for k in range(3):  # overhead wires across the street
        z = rng.uniform(4, 6)
        rod((-12, -3 + k * 0.3, z), (12, 2 + k * 0.3, z + rng.uniform(-0.5, 0.5)), 0.01, rail)
    pan = rng.uniform(0.15, 0.35)
    camera(frames, (-1.0, -8, 1.7), (1.0, -8, 1.7), (-pan * 10, 4, 3.0), (pan * 10, 4, 3.2), float(rng.uniform(24, 35)))
    return {"buildings": n}


def tabletop(rng, frames):
    """Glass, copper, wax and small print on a turntable over a cloth, under two soft boxes."""
    world((0.8, 0.85, 0.9), float(rng.uniform(0.05, 0.2)))
    box((6, 6, 0.1), (0, 0, -0.05), material("cloth", random_rgb(rng, 0.2, 0.8), 0.9, texture="magic", bump=0.2,
                                              scale=float(rng.uniform(15, 40))))
    turn = bpy_empty()
    objs = [("glass", material("glass", (0.95, 0.97, 1.0), 0.0, glass=1.0)),
            ("copper", material("copper", (0.95, 0.55, 0.35), float(rng.uniform(0.1, 0.35)), metal=1.0)),
            ("wax", material("wax", (0.9, 0.75, 0.6), 0.5, wax=0.6)),
            ("ceramic", material("ceramic", random_rgb(rng), 0.15, texture="voronoi", scale=12.0))]
    for i, (kind, mat) in enumerate(objs):
        a = i * math.pi / 2 + rng.uniform(-0.3, 0.3)
        loc = (0.55 * math.cos(a), 0.55 * math.sin(a), 0.0)
        o = add_shape(rng, loc, mat)
        o.parent = turn
    tag = label(str(rng.choice(WORDS)), (-0.3, -0.75, 0.005), 0.09, material("print", (0.05, 0.05, 0.05), 0.4),
                rot=(0, 0, 0))
    tag.parent = turn
    spin = rng.uniform(0.02, 0.06) * rng.choice([-1, 1])
    key_each_frame(turn, "rotation_euler", frames, lambda t: (0, 0, spin * t * (frames[1] - frames[0])))
    light("AREA", (1.5, -1.0, 2.0), float(rng.uniform(60, 150)), (1, 0.97, 0.92), 1.5, rot=(0.6, 0.5, 0.5))
    light("AREA", (-1.8, 0.5, 1.2), float(rng.uniform(15, 40)), (0.85, 0.9, 1.0), 0.8, rot=(0.9, -0.9, 0))
    r, z = rng.uniform(2.0, 2.8), rng.uniform(0.8, 1.5)
    a0 = rng.uniform(-1.9, -1.2)
    camera(frames, (r * math.cos(a0), r * math.sin(a0), z), (r * math.cos(a0 + 0.12), r * math.sin(a0 + 0.12), z),
           (0, 0, 0.25), (0, 0, 0.25), float(rng.uniform(40, 70)))
    return {"spin_per_frame": float(spin)}


def haze(rng, frames):
    """A hazy room: a spot light through slatted blinds casts beams; balls roll across the floor."""
    world((0.01, 0.01, 0.015), 1.0)
    wall = material("plaster", random_rgb(rng, 0.5, 0.8), 0.9)
    box((8, 8, 0.1), (0, 0, 0), material("boards", (0.35, 0.25, 0.18), 0.4, texture="wave", scale=3.0, bump=0.1))
    box((8, 0.1, 4), (0, 2.5, 2), wall)
    for size, loc in (((0.1, 3.5, 4), (2.5, -2.25, 2)), ((0.1, 3.4, 4), (2.5, 2.8, 2)),
                      ((0.1, 1.6, 1.1), (2.5, 0.3, 0.55)), ((0.1, 1.6, 1.6), (2.5, 0.3, 3.2))):
        box(size, loc, wall)  # the wall at the blinds, around its window
    slat = material("slat", (0.8, 0.8, 0.78), 0.6)
    for k in range(12):
        box((0.02, 1.6, 0.04), (2.3, 0.3, 1.2 + k * 0.1), slat, rot=(0.5, 0, 0))
    light("SPOT", (3.5, 0.3, 2.2), float(rng.uniform(3000, 8000)), (1.0, 0.9, 0.75), rot=(0, 1.25, 0), spot=0.5)
    light("POINT", (-1.0, -1.0, 3.0), float(rng.uniform(5, 20)), (0.7, 0.8, 1.0), 0.3)
    fog = material("fog", (1, 1, 1))
    nt = fog.node_tree
    nt.nodes.remove(nt.nodes["Principled BSDF"])
    vol = nt.nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Density"].default_value = float(rng.uniform(0.03, 0.08))
    nt.links.new(vol.outputs[0], nt.nodes["Material Output"].inputs["Volume"])
    box((5, 5, 3.9), (0, 0, 2.0), fog)
    for i in range(int(rng.integers(2, 5))):
        ball = add_ball(rng, material(f"ball{i}", random_rgb(rng), float(rng.uniform(0.05, 0.5)), metal=float(rng.random() < 0.3)))
        x0, y0, v = rng.uniform(-1.5, 1.0), rng.uniform(-1.0, 1.5), rng.uniform(-0.06, 0.06, 2)
        key_each_frame(ball, "location", frames,
                       lambda t, x0=x0, y0=y0, v=v, z=ball.location[2]: (x0 + v[0] * t * 10, y0 + v[1] * t * 10, z))
    camera(frames, (-2.8, -3.2, 1.6), (-2.5, -2.8, 1.6), (0.8, 0.8, 1.2), (0.9, 0.8, 1.2), float(rng.uniform(22, 30)))
    return {}


def bpy_empty():
    """An empty object (the turntable the tabletop's objects are parented to)."""
    o = bpy.data.objects.new("turntable", None)
    bpy.context.collection.objects.link(o)
    return o


def add_shape(rng, loc, mat):
    """A smooth shape standing on the table: a sphere, a torus or a capped cylinder."""
    kind = rng.choice(["sphere", "torus", "cylinder"])
    s = rng.uniform(0.15, 0.3)
    if kind == "sphere":
        bpy.ops.mesh.primitive_uv_sphere_add(radius=s, location=(loc[0], loc[1], s), segments=48, ring_count=24)
    elif kind == "torus":
        bpy.ops.mesh.primitive_torus_add(major_radius=s, minor_radius=s * 0.35, location=(loc[0], loc[1], s * 0.35))
    else:
        bpy.ops.mesh.primitive_cylinder_add(radius=s * 0.7, depth=s * 2, location=(loc[0], loc[1], s), vertices=48)
    o = bpy.context.object
    bpy.ops.object.shade_smooth()
    o.data.materials.append(mat)
    return o


def add_ball(rng, mat):
    """A smooth ball resting on the floor at the origin (its motion is keyed later)."""
    r = rng.uniform(0.1, 0.25)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=r, location=(0, 0, r), segments=32, ring_count=16)
    o = bpy.context.object
    bpy.ops.object.shade_smooth()
    o.data.materials.append(mat)
    return o


BUILDERS = {"shelves": shelves, "facade": facade, "tabletop": tabletop, "haze": haze}
