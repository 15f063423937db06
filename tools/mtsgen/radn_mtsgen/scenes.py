"""Scene families for Mitsuba 3, from a seed: interiors, exteriors with vegetation, product
shots and close-ups, fur balls (curves), smoke (a homogeneous medium). A scene is a list of
objects with per-frame transforms and a camera path; `dict_at(frame)` gives Mitsuba's scene
dictionary for a frame and `to_world(key, frame)` the transform motion vectors need."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from . import textures

FAMILIES = ("interior", "exterior", "product", "closeup", "fur")


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    x, y, z = axis
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
                  [y * x * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
                  [z * x * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)]])
    m = np.eye(4)
    m[:3, :3] = r
    return m


def _trs(pos, axis=(0, 0, 1), angle=0.0, scale=(1, 1, 1)):
    t = np.eye(4)
    t[:3, 3] = pos
    return t @ _rot(axis, angle) @ np.diag([*np.broadcast_to(scale, 3), 1.0])


@dataclass
class Obj:
    """A shape with its material and its transform as a function of the frame's phase (0 … 1)."""

    key: str
    shape: dict
    bsdf: Optional[dict]
    transform: Callable[[float], np.ndarray]
    extra: dict = field(default_factory=dict)


@dataclass
class SceneSpec:
    """One animated scene: objects, lights, camera path, film and sampler."""

    seed: int
    family: str
    frames: int
    width: int
    height: int
    sampler: str
    objects: list
    emitters: dict
    cam_from: Callable[[float], np.ndarray]
    cam_to: Callable[[float], np.ndarray]
    fov: float
    volume: bool = False
    description: dict = field(default_factory=dict)

    def phase(self, frame: int) -> float:
        return (frame - 1) / max(self.frames - 1, 1)

    def to_world(self, key: str, frame: int) -> np.ndarray:
        """The object's 4×4 transform at `frame` (from 1)."""
        for o in self.objects:
            if o.key == key:
                return o.transform(self.phase(frame))
        raise KeyError(key)

    def camera(self, frame: int) -> tuple:
        """(origin, target) at `frame`."""
        p = self.phase(frame)
        return np.asarray(self.cam_from(p), float), np.asarray(self.cam_to(p), float)

    def environment(self) -> np.ndarray:
        """The radiance a ray that hits nothing sees (RGB)."""
        sky = self.emitters.get("sky")
        return np.asarray(sky["radiance"]["value"], float) if sky else np.zeros(3)

    def emission(self, key: str) -> Optional[np.ndarray]:
        """The radiance of an emitting object (RGB), None for others."""
        for o in self.objects:
            if o.key == key and "emitter" in o.extra:
                return np.asarray(o.extra["emitter"]["radiance"]["value"], float)
        return None

    def dict_at(self, frame: int, aovs: bool = True, variance: bool = False) -> dict:
        """Mitsuba's scene dictionary at `frame`; with `variance`, the integrator wrapped in
        Mitsuba's `moment` integrator (it also records its samples' second moment)."""
        from .backend import mitsuba

        mi = mitsuba()

        origin, target = self.camera(frame)
        inner = {"type": "volpath" if self.volume else "path", "max_depth": 8}
        d = {
            "type": "scene",
            "integrator": {"type": "aov", "aovs": "albedo:albedo,nn:sh_normal", "img": inner} if aovs else inner,
            "sensor": {
                "type": "perspective",
                "fov": self.fov,
                "fov_axis": "x",
                "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=target.tolist(), up=[0, 0, 1]),
                "sampler": {"type": self.sampler, "sample_count": 4},
                "film": {"type": "hdrfilm", "width": self.width, "height": self.height,
                         "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            },
        }
        if variance:
            d["integrator"] = {"type": "moment", "m": d["integrator"]}
        d.update(self.emitters)
        for o in self.objects:
            s = dict(o.shape)
            s["to_world"] = mi.ScalarTransform4f(o.transform(self.phase(frame)).tolist())
            if o.bsdf is not None:
                s["bsdf"] = o.bsdf
            s.update(o.extra)
            d[o.key] = s
        return d


class _Builder:
    def __init__(self, seed: int, tex_dir: str):
        self.rng = np.random.default_rng(seed)
        self.seed = seed
        self.family = ""
        self.tex_dir = tex_dir
        self.objects: list = []
        self.n = 0

    def texture(self, kind=None, scale=1.0):
        from .backend import mitsuba

        mi = mitsuba()

        kind = kind or self.rng.choice(list(textures.KINDS))
        arr = textures.make(kind, self.rng)
        os.makedirs(self.tex_dir, exist_ok=True)
        path = os.path.join(self.tex_dir, f"{self.seed}_{self.family}_tex{self.n:03d}_{kind}.exr")
        self.n += 1
        mi.Bitmap(arr.astype(np.float32)).write(path)
        return {"type": "bitmap", "filename": path, "filter_type": "bilinear",
                "to_uv": mi.ScalarTransform4f().scale([scale, scale, 1])}

    def material(self, textured=0.5):
        r = self.rng
        kind = r.choice(["diffuse", "roughplastic", "plastic", "conductor", "roughconductor", "dielectric"],
                        p=[0.35, 0.2, 0.1, 0.1, 0.15, 0.1])
        color = r.uniform(0.05, 0.85, 3).tolist()
        base = self.texture(scale=float(r.uniform(1, 4))) if r.uniform() < textured else {"type": "rgb", "value": color}
        if kind == "diffuse":
            return {"type": "diffuse", "reflectance": base}
        if kind in ("plastic", "roughplastic"):
            m = {"type": kind, "diffuse_reflectance": base}
            if kind == "roughplastic":
                m["alpha"] = float(r.uniform(0.05, 0.4))
            return m
        if kind in ("conductor", "roughconductor"):
            m = {"type": kind, "material": str(r.choice(["Au", "Cu", "Al", "Ag", "Cr"]))}
            if kind == "roughconductor":
                m["alpha"] = float(r.uniform(0.03, 0.3))
            return m
        return {"type": "dielectric", "int_ior": float(r.uniform(1.3, 1.6))}

    def add(self, shape, bsdf, transform, **extra):
        key = f"obj{len(self.objects):03d}"
        self.objects.append(Obj(key, shape, bsdf, transform, extra))
        return key

    def static(self, m):
        return lambda p, m=m: m

    def moving(self, pos, axis=(0, 0, 1), scale=(1, 1, 1), still=0.5):
        """A transform that translates and spins over the shot (or stays still)."""
        r = self.rng
        pos = np.asarray(pos, float)
        if r.uniform() < still:
            return self.static(_trs(pos, axis, r.uniform(0, 6.3), scale))
        dpos = r.normal(0, 0.25, 3) * [1, 1, 0.3]
        a0, da = r.uniform(0, 6.3), r.uniform(-0.6, 0.6)
        return lambda p: _trs(pos + dpos * p, axis, a0 + da * p, scale)


def _camera_path(r, centre, dist, height, mode=None):
    """A pan, dolly or orbit around `centre`."""
    mode = mode or r.choice(["pan", "dolly", "orbit"])
    a0 = r.uniform(0, 2 * np.pi)
    da = r.uniform(0.15, 0.5) * r.choice([-1, 1])
    centre = np.asarray(centre, float)
    if mode == "orbit":
        def frm(p):
            a = a0 + da * p
            return centre + [dist * np.cos(a), dist * np.sin(a), height]
        return frm, (lambda p: centre), mode
    base = centre + [dist * np.cos(a0), dist * np.sin(a0), height]
    fwd = (centre - base) / np.linalg.norm(centre - base)
    side = np.cross(fwd, [0, 0, 1])
    if mode == "pan":
        sweep = r.uniform(0.3, 1.0) * dist * r.choice([-1, 1])
        return (lambda p: base), (lambda p: centre + side * sweep * (p - 0.5)), mode
    step = r.uniform(0.2, 0.45) * dist
    return (lambda p: base + fwd * step * p), (lambda p: centre + side * 0.1 * p), mode


def build(seed: int, frames: int, res: tuple, family: Optional[str] = None, tex_dir: str = "/tmp",
          sampler: Optional[str] = None) -> SceneSpec:
    """The scene of `seed` (its family drawn from the seed unless given)."""
    b = _Builder(seed, tex_dir)
    r = b.rng
    family = family or str(r.choice(FAMILIES))
    b.family = family
    sampler = sampler or str(r.choice(["independent", "ldsampler"]))
    emitters: dict = {}
    volume = False
    rect = {"type": "rectangle"}
    if family == "interior":
        w, dpt, h = r.uniform(4, 8), r.uniform(4, 8), r.uniform(2.5, 3.5)
        b.add(rect, {"type": "diffuse", "reflectance": b.texture(r.choice(["planks", "checks", "noise"]), 4)},
              b.static(_trs([0, 0, 0], scale=[w / 2, dpt / 2, 1])))
        b.add(rect, {"type": "diffuse", "reflectance": b.texture(r.choice(["bricks", "stripes", "noise"]), 3)},
              b.static(_trs([0, dpt / 2, h / 2], (1, 0, 0), np.pi / 2, [w / 2, h / 2, 1])))
        b.add(rect, {"type": "diffuse", "reflectance": {"type": "rgb", "value": r.uniform(0.3, 0.8, 3).tolist()}},
              b.static(_trs([-w / 2, 0, h / 2], (0, 1, 0), np.pi / 2, [h / 2, dpt / 2, 1])))
        b.add(rect, {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.7, 0.7]}},
              b.static(_trs([0, 0, h], (1, 0, 0), np.pi, [w / 2, dpt / 2, 1])))
        b.add(rect, None, b.static(_trs([r.uniform(-1, 1), r.uniform(-1, 1), h - 0.01], (1, 0, 0), np.pi, [0.5, 0.5, 1])),
              emitter={"type": "area", "radiance": {"type": "rgb", "value": (r.uniform(5, 15) * np.array([1, 0.9, 0.8])).tolist()}})
        # a window: light from outside through the right wall
        b.add(rect, None, b.static(_trs([w / 2, r.uniform(-1, 1), h * 0.55], (0, 1, 0), -np.pi / 2, [0.6, 0.8, 1])),
              emitter={"type": "area", "radiance": {"type": "rgb", "value": (r.uniform(3, 12) * np.array([0.8, 0.9, 1.1])).tolist()}})
        for _ in range(int(r.integers(3, 7))):
            pos = [r.uniform(-w / 3, w / 3), r.uniform(-dpt / 3, dpt / 3), 0]
            kind = r.choice(["cube", "sphere", "cylinder"])
            s = r.uniform(0.2, 0.6)
            pos[2] = s
            shape = {"type": kind} if kind != "cylinder" else {"type": "cylinder", "radius": 1.0}
            b.add(shape, b.material(), b.moving(pos, scale=[s, s, s]))
        if r.uniform() < 0.5:  # thin wires before the back wall
            for i in range(int(r.integers(6, 20))):
                x = -w / 3 + i * 0.12
                b.add({"type": "cylinder", "radius": 1.0}, {"type": "roughconductor", "material": "Al", "alpha": 0.2},
                      b.static(_trs([x, dpt / 2 - 0.3, 0], scale=[0.006, 0.006, h * 0.8])))
        if r.uniform() < 0.5:  # a label with small text
            b.add(rect, {"type": "diffuse", "reflectance": b.texture("glyphs")},
                  b.static(_trs([r.uniform(-1, 1), dpt / 2 - 0.02, h * 0.45], (1, 0, 0), np.pi / 2, [0.6, 0.4, 1])))
        if r.uniform() < 0.25:  # smoke in the room
            volume = True
            b.add({"type": "cube"}, {"type": "null"}, b.static(_trs([0, 0, h / 2], scale=[w / 3, dpt / 3, h / 2.5])),
                  interior={"type": "homogeneous", "albedo": 0.8, "sigma_t": float(r.uniform(0.05, 0.4))})
        cf, ct, mode = _camera_path(r, [0, 0, 0.6], min(w, dpt) * 0.35, r.uniform(0.6, 1.4))
        fov = r.uniform(55, 80)
    elif family == "exterior":
        b.add(rect, {"type": "diffuse", "reflectance": b.texture(r.choice(["noise", "checks", "bricks"]), 12)},
              b.static(_trs([0, 0, 0], scale=[40, 40, 1])))
        emitters["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": (r.uniform(0.3, 1.2) * np.array([0.6, 0.75, 1.0])).tolist()}}
        sun = r.normal(0, 1, 3)
        sun[2] = -abs(sun[2]) - 0.5
        emitters["sun"] = {"type": "directional", "direction": (sun / np.linalg.norm(sun)).tolist(),
                           "irradiance": {"type": "rgb", "value": (r.uniform(2, 6) * np.array([1, 0.95, 0.85])).tolist()}}
        leaf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.1, r.uniform(0.25, 0.5), 0.08]}}
        for t in range(int(r.integers(3, 7))):
            x, y = r.uniform(-6, 6), r.uniform(-6, 6)
            hgt = r.uniform(1.5, 3.5)
            b.add({"type": "cylinder", "radius": 1.0}, {"type": "diffuse", "reflectance": b.texture("planks", 2)},
                  b.static(_trs([x, y, 0], scale=[0.12, 0.12, hgt])))
            sway = r.uniform(0, 0.25)
            for _ in range(int(r.integers(40, 120))):  # leaves: small rectangles around the crown
                c = np.array([x, y, hgt]) + r.normal(0, 0.6, 3)
                ax, a = r.normal(0, 1, 3), r.uniform(0, 6.3)
                s = r.uniform(0.05, 0.14)
                ds = r.normal(0, 1, 3) * 0.05
                b.add(rect, leaf, (lambda p, c=c, ax=ax, a=a, s=s, ds=ds, sway=sway:
                                   _trs(c + ds * np.sin(p * 3) * sway * 4, ax, a + sway * p, [s, s * 0.5, 1])))
        for _ in range(int(r.integers(2, 6))):
            s = r.uniform(0.2, 0.7)
            b.add({"type": "sphere"}, b.material(0.6), b.moving([r.uniform(-4, 4), r.uniform(-4, 4), s], scale=[s, s, s]))
        cf, ct, mode = _camera_path(r, [0, 0, 1.0], r.uniform(5, 9), r.uniform(0.8, 2.5))
        fov = r.uniform(45, 75)
    else:  # product, close-up, fur: objects on a backdrop under studio lights
        b.add(rect, {"type": "diffuse", "reflectance": {"type": "rgb", "value": r.uniform(0.2, 0.9, 3).tolist()}},
              b.static(_trs([0, 0, 0], scale=[6, 6, 1])))
        b.add(rect, {"type": "diffuse", "reflectance": b.texture(r.choice(list(textures.KINDS)), 2)},
              b.static(_trs([0, 3, 3], (1, 0, 0), np.pi / 2, [6, 3, 1])))
        for i in range(int(r.integers(2, 4))):
            a = r.uniform(0, 2 * np.pi)
            pos = [3 * np.cos(a), 3 * np.sin(a) - 1, r.uniform(2, 4)]
            look = -np.asarray(pos) / np.linalg.norm(pos)
            axis = np.cross([0, 0, -1], look)
            ang = np.arccos(np.clip(np.dot([0, 0, -1], look), -1, 1))
            b.add(rect, None, b.static(_trs(pos, axis if np.linalg.norm(axis) > 1e-6 else (1, 0, 0), ang, [0.5, 0.5, 1])),
                  emitter={"type": "area", "radiance": {"type": "rgb", "value": (r.uniform(4, 14) * r.uniform(0.7, 1, 3)).tolist()}})
        spin = r.uniform(0.3, 1.2) * r.choice([-1, 1])
        n = 1 if family == "closeup" else int(r.integers(1, 4))
        for i in range(n):
            s = r.uniform(0.3, 0.6)
            pos = np.array([(i - (n - 1) / 2) * 1.4, 0, s])
            kind = r.choice(["sphere", "cube", "cylinder"])
            shape = {"type": kind} if kind != "cylinder" else {"type": "cylinder", "radius": 1.0}
            b.add(shape, b.material(0.5), (lambda p, pos=pos, s=s, a0=r.uniform(0, 6.3):
                                           _trs(pos, (0, 0, 1), a0 + spin * p, [s, s, s])))
        if family == "fur":
            path = os.path.join(tex_dir, f"{seed}_fur.txt")
            _write_fur(r, path, int(r.integers(1500, 4000)))
            colour = r.uniform(0.2, 0.8, 3).tolist()
            b.add({"type": "linearcurve", "filename": path}, {"type": "diffuse", "reflectance": {"type": "rgb", "value": colour}},
                  (lambda p, a0=r.uniform(0, 6.3): _trs([0, -0.9, 0.45], (0, 0, 1), a0 + spin * p, [1, 1, 1])))
        dist = r.uniform(1.2, 2.0) if family == "closeup" else r.uniform(3, 5)
        cf, ct, mode = _camera_path(r, [0, 0, 0.4], dist, r.uniform(0.3, 1.5), mode=r.choice(["dolly", "orbit", "pan"]))
        fov = r.uniform(30, 50) if family == "closeup" else r.uniform(35, 60)
    return SceneSpec(seed=seed, family=family, frames=frames, width=res[0], height=res[1], sampler=sampler,
                     objects=b.objects, emitters=emitters, cam_from=cf, cam_to=ct, fov=float(fov), volume=volume,
                     description={"family": family, "sampler": sampler, "camera": mode, "objects": len(b.objects),
                                  "volume": volume})


def _write_fur(r, path, strands):
    """A ball of short hair: linear curves (x y z radius per line, a blank line between strands)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    lines = []
    for _ in range(strands):
        d = r.normal(0, 1, 3)
        d /= np.linalg.norm(d)
        if d[2] < -0.3:
            continue
        p = d * 0.35
        bend = r.normal(0, 0.25, 3)
        for k in range(4):
            q = p + d * 0.06 * k + bend * (0.06 * k) ** 2 * 10
            lines.append(f"{q[0]:.5f} {q[1]:.5f} {q[2]:.5f} {0.004 * (1 - k / 4):.5f}")
        lines.append("")
    with open(path, "w") as f:
        f.write("\n".join(lines))
