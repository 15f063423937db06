"""Procedural, animated Cycles scenes built entirely from script, reproducible from a seed.

Every scene is a layout (indoor room or outdoor ground), a handful of objects with
procedurally textured Principled materials (diffuse, glossy, metal, glass, emissive,
subsurface, hair or thin wires), lights (area, small bright points, sun + Nishita sky or a
world colour), and animation (camera dolly, pan, orbit or shake; moving, rotating and
deforming objects). The returned description is stored in the scene manifest.
"""
import math
import random

import bpy

MATERIAL_KINDS = ("diffuse", "glossy", "metal", "glass", "emissive", "subsurface")
TEXTURES = ("noise", "voronoi", "checker", "brick", "wave", "none")
CAMERA_MOVES = ("dolly", "pan", "orbit", "shake", "static")
OBJECT_MOTIONS = ("translate", "rotate", "deform", "static")
PRIMITIVES = ("cube", "sphere", "cylinder", "torus", "monkey", "cone", "ico")


def reset():
    """Starts from an empty file so nothing of Blender's default scene leaks in."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def _rgb(rng, lo=0.05, hi=0.9):
    return (rng.uniform(lo, hi), rng.uniform(lo, hi), rng.uniform(lo, hi), 1.0)


def _key_every_frame(target, path, frames, value_fn):
    """Keyframes `target.path` at every frame (one before and after the range too, so the
    vector pass at the ends sees real motion)."""
    for f in range(frames[0] - 1, frames[1] + 2):
        setattr(target, path, value_fn(f))
        target.keyframe_insert(data_path=path, frame=f)


def _texture_node(nodes, links, rng, kind):
    """A procedural texture giving a 0..1 factor with fine detail."""
    coord = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    s = rng.uniform(2.0, 14.0)
    mapping.inputs["Scale"].default_value = (s, s, s)
    links.new(coord.outputs["Object"], mapping.inputs["Vector"])
    if kind == "noise":
        t = nodes.new("ShaderNodeTexNoise")
        t.inputs["Detail"].default_value = rng.uniform(2, 10)
        out = t.outputs["Fac"]
    elif kind == "voronoi":
        t = nodes.new("ShaderNodeTexVoronoi")
        out = t.outputs["Distance"]
    elif kind == "checker":
        t = nodes.new("ShaderNodeTexChecker")
        out = t.outputs["Fac"]
    elif kind == "brick":
        t = nodes.new("ShaderNodeTexBrick")
        out = t.outputs["Fac"]
    else:
        t = nodes.new("ShaderNodeTexWave")
        t.inputs["Distortion"].default_value = rng.uniform(0, 8)
        t.inputs["Detail"].default_value = rng.uniform(1, 6)
        out = t.outputs["Fac"]
    links.new(mapping.outputs["Vector"], t.inputs["Vector"])
    return out


def make_material(rng, kind, texture):
    """A Principled BSDF material of the given kind, optionally textured."""
    mat = bpy.data.materials.new(f"{kind}_{texture}")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes.get("Principled BSDF")
    base_a, base_b = _rgb(rng), _rgb(rng)
    if texture != "none":
        fac = _texture_node(nodes, links, rng, texture)
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        mix.inputs["A"].default_value = base_a
        mix.inputs["B"].default_value = base_b
        links.new(fac, mix.inputs["Factor"])
        links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
        if rng.random() < 0.4 and kind in ("glossy", "metal"):
            rough = nodes.new("ShaderNodeMapRange")
            rough.inputs["To Min"].default_value = 0.05
            rough.inputs["To Max"].default_value = 0.5
            links.new(fac, rough.inputs["Value"])
            links.new(rough.outputs["Result"], bsdf.inputs["Roughness"])
    else:
        bsdf.inputs["Base Color"].default_value = base_a
    inp = bsdf.inputs
    if kind == "diffuse":
        inp["Roughness"].default_value = 1.0
    elif kind == "glossy":
        inp["Roughness"].default_value = rng.uniform(0.05, 0.4)
        inp["Coat Weight"].default_value = rng.uniform(0.0, 1.0)
    elif kind == "metal":
        inp["Metallic"].default_value = 1.0
        inp["Roughness"].default_value = rng.uniform(0.02, 0.5)
    elif kind == "glass":
        inp["Transmission Weight"].default_value = 1.0
        inp["Roughness"].default_value = rng.choice([0.0, 0.0, rng.uniform(0.05, 0.3)])
        inp["IOR"].default_value = rng.uniform(1.3, 1.6)
    elif kind == "emissive":
        inp["Emission Color"].default_value = _rgb(rng, 0.4, 1.0)
        inp["Emission Strength"].default_value = rng.uniform(2.0, 12.0)
    elif kind == "subsurface":
        inp["Subsurface Weight"].default_value = 1.0
        inp["Subsurface Scale"].default_value = rng.uniform(0.05, 0.3)
    return mat


def _add_primitive(kind, location, size):
    ops = bpy.ops.mesh
    if kind == "cube":
        ops.primitive_cube_add(size=size, location=location)
    elif kind == "sphere":
        ops.primitive_uv_sphere_add(radius=size / 2, location=location, segments=48, ring_count=24)
    elif kind == "cylinder":
        ops.primitive_cylinder_add(radius=size / 2, depth=size, location=location, vertices=48)
    elif kind == "torus":
        ops.primitive_torus_add(major_radius=size / 2, minor_radius=size / 6, location=location)
    elif kind == "monkey":
        ops.primitive_monkey_add(size=size, location=location)
    elif kind == "cone":
        ops.primitive_cone_add(radius1=size / 2, depth=size, location=location, vertices=48)
    else:
        ops.primitive_ico_sphere_add(radius=size / 2, subdivisions=3, location=location)
    obj = bpy.context.active_object
    if kind in ("sphere", "monkey", "torus", "ico"):
        bpy.ops.object.shade_smooth()
    return obj


def _add_hair(obj, rng):
    """Particle hair on an object: thin, high-frequency geometry."""
    mod = obj.modifiers.new("hair", "PARTICLE_SYSTEM")
    settings = mod.particle_system.settings
    settings.type = "HAIR"
    settings.count = rng.randint(800, 2500)
    settings.hair_length = rng.uniform(0.08, 0.3)
    settings.root_radius = 0.3
    settings.radius_scale = 0.01
    mat = bpy.data.materials.new("hair")
    mat.use_nodes = True
    mat.node_tree.nodes.get("Principled BSDF").inputs["Base Color"].default_value = _rgb(rng)
    obj.data.materials.append(mat)
    settings.material = len(obj.data.materials)


def _add_wires(rng, frames, origin):
    """A bundle of thin curves (cables, grass-like strands)."""
    curve = bpy.data.curves.new("wires", "CURVE")
    curve.dimensions = "3D"
    curve.bevel_depth = rng.uniform(0.004, 0.015)
    for _ in range(rng.randint(6, 20)):
        sp = curve.splines.new("POLY")
        sp.points.add(3)
        x0, y0 = rng.uniform(-1, 1), rng.uniform(-1, 1)
        for i, p in enumerate(sp.points):
            p.co = (origin[0] + x0 + rng.uniform(-0.2, 0.2), origin[1] + y0 + rng.uniform(-0.2, 0.2), i * 0.5, 1.0)
    obj = bpy.data.objects.new("wires", curve)
    bpy.context.scene.collection.objects.link(obj)
    mat = make_material(rng, rng.choice(["diffuse", "metal"]), "none")
    curve.materials.append(mat)
    return obj


def _animate_object(obj, rng, frames, motion):
    base_loc = tuple(obj.location)
    if motion == "translate":
        v = (rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), rng.uniform(-0.05, 0.05))
        _key_every_frame(obj, "location", frames, lambda f: tuple(b + f * d for b, d in zip(base_loc, v)))
    elif motion == "rotate":
        w = (rng.uniform(-0.08, 0.08), rng.uniform(-0.08, 0.08), rng.uniform(-0.15, 0.15))
        _key_every_frame(obj, "rotation_euler", frames, lambda f: tuple(f * d for d in w))
    elif motion == "deform":
        mod = obj.modifiers.new("twist", "SIMPLE_DEFORM")
        mod.deform_method = "TWIST"
        rate = rng.uniform(-0.08, 0.08)
        for f in range(frames[0] - 1, frames[1] + 2):
            mod.angle = f * rate
            mod.keyframe_insert("angle", frame=f)
    return motion


def _layout(rng, scene, outdoor):
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    bg = nodes.get("Background")
    desc = {}
    if outdoor:
        bpy.ops.mesh.primitive_plane_add(size=60, location=(0, 0, 0))
        ground = bpy.context.active_object
        ground.data.materials.append(make_material(rng, "diffuse", rng.choice(["noise", "voronoi", "brick", "checker"])))
        if rng.random() < 0.7:
            sky = nodes.new("ShaderNodeTexSky")
            sky.sky_type = "NISHITA"
            elevation = rng.uniform(0.15, 1.2)
            sky.sun_elevation = elevation
            sky.sun_rotation = rng.uniform(0, 2 * math.pi)
            links.new(sky.outputs["Color"], bg.inputs["Color"])
            bg.inputs["Strength"].default_value = rng.uniform(0.08, 0.25)
            sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
            scene.collection.objects.link(sun)
            sun.data.energy = rng.uniform(1.0, 3.0)
            sun.data.angle = rng.uniform(0.005, 0.05)
            sun.rotation_euler = (math.pi / 2 - elevation, 0, sky.sun_rotation)
            desc["sky"] = {"type": "nishita", "sun_elevation": elevation}
        else:
            bg.inputs["Color"].default_value = _rgb(rng, 0.2, 1.0)
            bg.inputs["Strength"].default_value = rng.uniform(0.3, 1.0)
            desc["sky"] = {"type": "color"}
    else:
        size = rng.uniform(7, 10)
        bpy.ops.mesh.primitive_cube_add(size=size, location=(0, 0, size / 2 - 0.01))
        room = bpy.context.active_object
        room.data.materials.append(make_material(rng, "diffuse", rng.choice(TEXTURES)))
        # flip normals so the inside faces are lit correctly
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.flip_normals()
        bpy.ops.object.mode_set(mode="OBJECT")
        bg.inputs["Color"].default_value = _rgb(rng, 0.0, 0.3)
        bg.inputs["Strength"].default_value = 0.2
        area = bpy.data.objects.new("area", bpy.data.lights.new("area", "AREA"))
        scene.collection.objects.link(area)
        area.data.size = rng.uniform(1.0, 3.0)
        area.data.energy = rng.uniform(400, 1500)
        area.location = (rng.uniform(-2, 2), rng.uniform(-2, 2), min(size - 0.5, rng.uniform(3.5, 5.0)))
        desc["room_size"] = size
    return desc


def build(seed: int, frames=(1, 9), resolution=(256, 256), motion_scale=1.0, layout=None, detail=False,
          fur=False, contact=False):
    """Builds scene `seed` in the current Blender session and returns its description. With
    `detail`, also the fine detail of `detail.add_detail`; with `fur`, the fur and grass of
    `fur.add_fur`; with `contact`, the glass standing on a textured floor of
    `contact.add_contact` (each from its own random stream: the rest of the scene is the same with
    or without them)."""
    rng = random.Random(seed)
    scene = reset()
    scene.frame_start, scene.frame_end = frames
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    outdoor = rng.random() < 0.5 if layout is None else layout == "outdoor"
    desc = {"seed": seed, "layout": "outdoor" if outdoor else "indoor"}
    desc.update(_layout(rng, scene, outdoor))

    objects = []
    for i in range(rng.randint(3, 7)):
        kind = rng.choice(PRIMITIVES)
        size = rng.uniform(0.5, 1.6)
        loc = (rng.uniform(-2.5, 2.5), rng.uniform(-2.5, 2.5), size / 2 + rng.uniform(0, 0.8))
        obj = _add_primitive(kind, loc, size)
        mkind = rng.choice(MATERIAL_KINDS)
        tex = rng.choice(TEXTURES)
        obj.data.materials.append(make_material(rng, mkind, tex))
        hair = rng.random() < 0.15 and mkind in ("diffuse", "glossy")
        if hair:
            _add_hair(obj, rng)
        motion = _animate_object(obj, rng, frames, rng.choice(OBJECT_MOTIONS)) if not hair else "static"
        objects.append({"primitive": kind, "material": mkind, "texture": tex, "hair": hair, "motion": motion})
    if rng.random() < 0.4:
        _add_wires(rng, frames, (rng.uniform(-2, 2), rng.uniform(-2, 2)))
        objects.append({"primitive": "wires", "material": "thin", "motion": "static"})
    lights = []
    for _ in range(rng.randint(0, 3)):
        # small, bright lights: the classic source of fireflies
        pt = bpy.data.objects.new("point", bpy.data.lights.new("point", "POINT"))
        scene.collection.objects.link(pt)
        pt.data.shadow_soft_size = rng.uniform(0.01, 0.08)
        pt.data.energy = rng.uniform(50, 400)
        pt.data.color = _rgb(rng, 0.5, 1.0)[:3]
        pt.location = (rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(0.5, 3.5))
        lights.append("point")
    desc["objects"] = objects
    desc["lights"] = lights

    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.data.lens = rng.uniform(24, 60)
    cam.data.dof.use_dof = False
    # indoors the camera must stay inside the room
    dist = rng.uniform(0.3, 0.42) * desc["room_size"] if not outdoor else rng.uniform(6, 10)
    az = rng.uniform(0, 2 * math.pi)
    height = rng.uniform(1.0, 3.5)
    move = rng.choice(CAMERA_MOVES)
    speed = rng.uniform(0.3, 1.0) * motion_scale
    shake = rng.uniform(0.005, 0.02)
    shake_rng = random.Random(seed * 7 + 1)
    jitter = {f: (shake_rng.gauss(0, 1), shake_rng.gauss(0, 1)) for f in range(frames[0] - 1, frames[1] + 2)}

    def cam_pose(f):
        a, d, x_off = az, dist, 0.0
        if move == "orbit":
            a = az + 0.02 * speed * f
        elif move == "dolly":
            d = dist - 0.08 * speed * f
        elif move == "pan":
            x_off = 0.06 * speed * f
        loc = (d * math.cos(a) + x_off * -math.sin(a), d * math.sin(a) + x_off * math.cos(a), height)
        return loc

    def cam_rot(f):
        loc = cam_pose(f)
        dx, dy, dz = -loc[0], -loc[1], 0.6 - loc[2]
        yaw = math.atan2(dy, dx) - math.pi / 2
        pitch = math.atan2(math.hypot(dx, dy), -dz)
        if move == "shake":
            return (pitch + shake * jitter[f][0], 0.0, yaw + shake * jitter[f][1])
        if move == "pan":
            return (pitch, 0.0, yaw + 0.004 * speed * f)
        return (pitch, 0.0, yaw)

    _key_every_frame(cam, "location", frames, cam_pose)
    _key_every_frame(cam, "rotation_euler", frames, cam_rot)
    desc["camera"] = {"move": move, "lens_mm": cam.data.lens, "speed": speed}
    if detail:
        from .detail import add_detail

        desc["detail"] = add_detail(seed, az, desc.get("room_size"), frames, _key_every_frame)
    if fur:
        from .fur import add_fur

        desc["fur"] = add_fur(seed, az, desc.get("room_size"), frames, _key_every_frame)
    if contact:
        from .contact import add_contact

        desc["contact"] = add_contact(seed, az, desc.get("room_size"), frames, _key_every_frame)
    return desc


def hair_fingerprint():
    """A digest of where every particle-hair strand of the current scene stands (None without
    hair). Blender 4.5 distributes hair afresh in each build, whatever the particle seed, so
    two runs of the same `--seed` can differ in their hair alone; the manifest keeps this so a
    resumed render or a combined reference never mixes two realisations."""
    import hashlib

    dg = bpy.context.evaluated_depsgraph_get()
    digest, found = hashlib.sha1(), False
    for obj in sorted(bpy.context.scene.objects, key=lambda o: o.name):
        for psys in obj.evaluated_get(dg).particle_systems:
            found = True
            digest.update(f"{obj.name}/{psys.name}/{len(psys.particles)}".encode())
            for p in psys.particles:  # the root in the emitter's space: the same at every frame
                root = p.hair_keys[0].co if len(p.hair_keys) else p.location
                digest.update(("%.4f %.4f %.4f;" % tuple(root)).encode())
    return digest.hexdigest()[:16] if found else None


def has_hair(desc) -> bool:
    """Whether a built scene carries particle hair (fur)."""
    return any(o.get("hair") for o in desc["objects"])


GLASS_HEAVY_MIN = 3
"""Glass objects from which a scene counts as glass-heavy: enough transmissive objects that
caustics through glass cover much of the floor (the held-aside test scene 3 000 002 has five)."""


def is_glass_heavy(desc) -> bool:
    """Whether a built scene has at least `GLASS_HEAVY_MIN` glass objects."""
    return sum(o.get("material") == "glass" for o in desc["objects"]) >= GLASS_HEAVY_MIN


def seeds_where(first_seed: int, count: int, wanted, what: str, frames=(1, 9), resolution=(256, 256),
                layout=None, search=2000):
    """The first `count` seeds from `first_seed` on whose scene (`build`, not rendered) satisfies
    `wanted(desc)`: data for what the generator gives only now and then (hair in about one scene in
    six). Seeds stay in their split's range, so such a scene is never in two splits."""
    found = []
    for seed in range(first_seed, first_seed + search):
        desc = build(seed, frames=frames, resolution=resolution, layout=layout)
        if wanted(desc):
            found.append(seed)
            if len(found) == count:
                return found
    raise ValueError(f"only {len(found)} of the {search} seeds from {first_seed} have {what}; {count} were asked")


def seeds_with_hair(first_seed: int, count: int, frames=(1, 9), resolution=(256, 256), layout=None,
                    search=2000):
    """The first `count` seeds from `first_seed` on whose scene carries particle hair."""
    return seeds_where(first_seed, count, has_hair, "hair", frames, resolution, layout, search)


def seeds_with_glass(first_seed: int, count: int, frames=(1, 9), resolution=(256, 256), layout=None,
                     search=2000):
    """The first `count` seeds from `first_seed` on whose scene is glass-heavy (`is_glass_heavy`):
    validation and training data for caustics through glass."""
    return seeds_where(first_seed, count, is_glass_heavy, "glass", frames, resolution, layout, search)


def has_wires_in_motion(desc) -> bool:
    """Whether a built scene has the bundle of thin wires and a moving camera: static thin lines
    that move across the frame by fractions of a pixel, the case of the held-aside test scene
    3 000 000 (wires under a panning camera), where warping blurs what a spatial denoiser keeps."""
    wires = any(o.get("primitive") == "wires" for o in desc["objects"])
    return wires and desc["camera"]["move"] != "static"


def seeds_with_wires(first_seed: int, count: int, frames=(1, 9), resolution=(256, 256), layout=None,
                     search=2000):
    """The first `count` seeds from `first_seed` on whose scene has thin wires under a moving
    camera (`has_wires_in_motion`): validation data for one-pixel detail through subpixel motion."""
    return seeds_where(first_seed, count, has_wires_in_motion, "wires under a moving camera", frames,
                       resolution, layout, search)


def build_calibration(frames=(1, 2), resolution=(64, 48), step_px=(2.0, 1.0)):
    """A test scene with exactly known motion: an orthographic camera (10 px per unit) looking
    down at a textured plane that moves `step_px` pixels per frame (x right, y up)."""
    scene = reset()
    scene.frame_start, scene.frame_end = frames
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = resolution[0] / 10.0
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.location = (0, 0, 10)
    bpy.ops.mesh.primitive_plane_add(size=1.6, location=(0, 0, 0))
    obj = bpy.context.active_object
    rng = random.Random(5)
    obj.data.materials.append(make_material(rng, "diffuse", "checker"))
    _key_every_frame(obj, "location", frames, lambda f: (0.1 * step_px[0] * f - 0.1 * step_px[0] * frames[0],
                                                        0.1 * step_px[1] * f - 0.1 * step_px[1] * frames[0], 0.0))
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    world.node_tree.nodes.get("Background").inputs["Color"].default_value = (0.6, 0.6, 0.6, 1.0)
    lamp = bpy.data.objects.new("area", bpy.data.lights.new("area", "AREA"))
    lamp.data.energy = 200
    lamp.data.size = 1.0
    lamp.location = (2, 2, 4)
    scene.collection.objects.link(lamp)
    return {"seed": 0, "layout": "calibration", "step_px": list(step_px)}
