"""Exact motion vectors and depth: rays through pixel centres find the visible surface point;
each point moves with its object's transforms to the neighbouring frame and is projected with
that frame's camera. Points that hit nothing are directions (the sky), moved by the camera's
rotation only. Units and signs are radn's: pixels, +Y down, from this frame towards the other."""

from __future__ import annotations

import numpy as np

from .backend import mitsuba

#: depth written where a ray hits nothing
FAR = 1.0e4


def camera_matrices(spec, frame):
    """(camera-to-world, camera-to-sample) 4×4 matrices of the shot's camera at `frame`."""
    mi = mitsuba()
    origin, target = spec.camera(frame)
    to_world = np.array(mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=target.tolist(), up=[0, 0, 1]).matrix)
    size = mi.ScalarVector2i(spec.width, spec.height)
    proj = mi.perspective_projection(size, size, mi.ScalarVector2i(0, 0), spec.fov, 1e-2, 1e4)
    m = np.array(proj.matrix).reshape(4, 4, -1)[..., 0]
    return to_world.reshape(4, 4), m


def project(spec, frame, points):
    """Pixel positions (x, y; +Y down, pixel centres at .5) of world `points` (N × 3) at `frame`."""
    to_world, to_sample = camera_matrices(spec, frame)
    h = np.concatenate([points, np.ones((len(points), 1))], axis=1)
    cam = h @ np.linalg.inv(to_world).T
    s = cam @ to_sample.T
    s = s[:, :3] / s[:, 3:4]
    return np.stack([s[:, 0] * spec.width, s[:, 1] * spec.height], axis=1)


def visible_points(spec, frame, scene):
    """Per pixel (row-major): the hit point, the key of the object hit ('' for none) and the
    distance along the ray, from rays through the pixel centres of `frame`'s camera."""
    mi = mitsuba()
    import drjit as dr

    w, h = spec.width, spec.height
    idx = dr.arange(mi.UInt32, w * h)
    x, y = mi.Float(idx % w), mi.Float(idx // w)
    pos = mi.Point2f((x + 0.5) / w, (y + 0.5) / h)
    ray, _ = scene.sensors()[0].sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    valid = np.array(si.is_valid()).astype(bool)
    p = np.array(si.p).reshape(3, -1).T
    d = np.array(ray.d).reshape(3, -1).T
    o = np.array(ray.o).reshape(3, -1).T
    dist = np.where(valid, np.array(si.t), FAR)
    keys = np.full(w * h, "", dtype=object)
    for shape in scene.shapes():
        hit = np.array(si.shape == mi.ShapePtr(shape)).astype(bool) & valid
        keys[hit] = shape.id()
    # the sky: a point far along the ray, which only the camera's rotation moves
    p = np.where(valid[:, None], p, o + d * 1.0e6)
    return p, keys, dist


def motion_to(spec, frame, other, points, keys):
    """Motion (pixels, +Y down) of every pixel of `frame` towards the same surface in `other`."""
    moved = points.copy()
    for key in set(keys) - {""}:
        sel = keys == key
        m = spec.to_world(key, other) @ np.linalg.inv(spec.to_world(key, frame))
        hp = np.concatenate([points[sel], np.ones((sel.sum(), 1))], axis=1)
        moved[sel] = (hp @ m.T)[:, :3]
    sky = keys == ""
    if sky.any():  # keep directions at infinity relative to the new camera position
        o_now, _ = spec.camera(frame)
        o_other, _ = spec.camera(other)
        moved[sky] = points[sky] - o_now + o_other
    w, h = spec.width, spec.height
    centres = np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5), -1).reshape(-1, 2)
    return (project(spec, other, moved) - centres).reshape(h, w, 2)
