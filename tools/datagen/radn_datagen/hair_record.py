"""Which particle-hair realisation a scene folder's frames show. Blender 4.5 distributes hair
afresh in each run, whatever the particle seed, so two runs of the same `--seed` can differ in
their hair alone (the rest of the scene is the same). A run records its hair's fingerprint
before its first frame; a resumed run with other hair, or a combination of renders of two
realisations, is refused instead of mixing them. No bpy here: `combine` uses it too."""
import os

HAIR_FILE = "hair_fingerprint"
"""The file in a scene folder holding its frames' hair fingerprint (absent without hair)."""


def recorded_hair(out_dir):
    """The hair fingerprint recorded in `out_dir` (see `claim_hair`), or None."""
    path = os.path.join(out_dir, HAIR_FILE)
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return f.read().strip()


class HairMismatch(Exception):
    """A resumed render's hair differs from the hair of the frames already in the folder."""


def claim_hair(out_dir, fingerprint):
    """Called before the first frame a run renders into `out_dir`: records the run's hair
    fingerprint, or raises `HairMismatch` where frames of another realisation are already there
    (new frames would show other strands than the old ones)."""
    if fingerprint is None:
        return
    path = os.path.join(out_dir, HAIR_FILE)
    old = recorded_hair(out_dir)
    if old is not None:
        if old != fingerprint:
            raise HairMismatch(
                f"{out_dir}: this run's particle hair ({fingerprint}) differs from the hair of the frames already "
                f"there ({old}; Blender distributes hair afresh in each run), so new frames would not match "
                "them: render the scene again whole into an empty folder")
        return
    os.makedirs(out_dir, exist_ok=True)
    with open(path + ".tmp", "w") as f:
        f.write(fingerprint + "\n")
    os.replace(path + ".tmp", path)


def check_same_hair(scene_dirs):
    """Raises `HairMismatch` where two of `scene_dirs` recorded different hair (folders without
    a record are not compared)."""
    seen = {}
    for d in scene_dirs:
        h = recorded_hair(d)
        if h is not None:
            seen.setdefault(h, d)
    if len(seen) > 1:
        (h1, d1), (h2, d2) = list(seen.items())[:2]
        raise HairMismatch(f"'{d1}' and '{d2}' show different particle hair ({h1} against {h2}): renders of "
                           "two realisations of the scene cannot be combined")
