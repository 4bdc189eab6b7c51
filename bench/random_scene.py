"""Scenes of the kinds the tracking table is judged on, drawn at random:
new scenes to check the tracker on, which its tuning never saw.

KIND is one of
  table    a table of random size on four legs, with 0-3 cups on it;
  room     four walls and a floor of random size, with 1-4 boxes, balls
           and cylinders inside;
  bunnies  1-4 Stanford bunnies, scaled and turned at random, on a floor
           (run with --bunny);
  clutter  2-6 boxes, balls and cylinders on an open floor.
The helix's heights, margin and turns are drawn too. NUMBER seeds the draw:
the same KIND and NUMBER give the same scene.

A draw is kept only if the camera keeps at least 1 m (horizontally) from
the vertical through the point it looks at, and, in a room, 0.4 m from the
walls. A helix passing over that point looks straight down at the floor
while it turns by tens of degrees a frame, a motion depth alone cannot see
(a view of nothing but floor, or of floor and one cylinder, leaves the turn
free): a scene where no depth tracker can be right says nothing about this
one.

Usage: python3 bench/random_scene.py KIND NUMBER > scene.toml
"""
import math
import random
import sys


def obj(shape, translation, **keys):
    """One [[object]] table: keys in the order given, then the translation."""
    lines = ["[[object]]", f'shape = "{shape}"']
    for key, value in keys.items():
        if isinstance(value, str):
            lines.append(f'{key} = "{value}"')
        elif isinstance(value, bool):
            lines.append(f"{key} = {str(value).lower()}")
        elif isinstance(value, list):
            lines.append(f"{key} = [{', '.join(f'{v:.3f}' for v in value)}]")
        else:
            lines.append(f"{key} = {value:.3f}")
    lines.append(f"translation = [{', '.join(f'{v:.3f}' for v in translation)}]")
    return "\n".join(lines) + "\n"


def helix(rng, heights, look_at_y, margin, turns):
    """The [helix] table; look_at_y: the target's height at start and end."""
    return (
        f"[helix]\nheight = [{rng.uniform(*heights[0]):.2f}, {rng.uniform(*heights[1]):.2f}]\n"
        f"look_at = [[0.0, {look_at_y[0]:.2f}, 0.0], [0.0, {look_at_y[1]:.2f}, 0.0]]\n"
        f"margin = {rng.uniform(*margin):.2f}\nturns = {rng.choice(turns)}\n"
    )


def floor(size, top=0.1):
    """A floor slab `size` metres square whose top is at `top`."""
    return obj("box", [0.0, top - 0.05, 0.0], size=[size, 0.1, size], floor=True)


def primitive(rng, x, z, base):
    """A box (turned about y), ball or cylinder standing at (x, base, z),
    and its footprint's half extents along x and z."""
    kind = rng.choice(["box", "sphere", "cylinder"])
    if kind == "box":
        size = [rng.uniform(0.15, 1.0), rng.uniform(0.15, 0.9), rng.uniform(0.15, 0.7)]
        turn = rng.uniform(0.0, 90.0)
        c, s = abs(math.cos(math.radians(turn))), abs(math.sin(math.radians(turn)))
        half = ((c * size[0] + s * size[2]) / 2, (s * size[0] + c * size[2]) / 2)
        return obj("box", [x, base + size[1] / 2, z], size=size, rotation=[0.0, turn, 0.0]), half
    if kind == "sphere":
        r = rng.uniform(0.05, 0.3)
        return obj("sphere", [x, base + r, z], radius=r), (r, r)
    r, h = rng.uniform(0.03, 0.25), rng.uniform(0.2, 1.2)
    return obj("cylinder", [x, base + h / 2, z], radius=r, height=h), (r, r)


def scatter(rng, counts, spread, base):
    """Between counts[0] and counts[1] primitives standing at `base`, at
    random within ±spread (x, z) of the origin: their text and footprints."""
    text, footprints = "", []
    for _ in range(rng.randint(*counts)):
        x, z = rng.uniform(-spread[0], spread[0]), rng.uniform(-spread[1], spread[1])
        part, half = primitive(rng, x, z, base)
        text += part
        footprints.append((x, z, half))
    return text, footprints


def table(rng):
    length, width = rng.uniform(0.7, 1.6), rng.uniform(0.5, 1.0)
    height, top, leg = rng.uniform(0.6, 0.9), rng.uniform(0.03, 0.1), rng.uniform(0.04, 0.1)
    text = helix(rng, [(0.6, 1.0), (1.1, 1.7)], (height * 0.5, height * 0.8), (2.5, 4.5), [1.0, 1.5, 2.0])
    text += floor(10.0)
    text += obj("box", [0.0, 0.1 + height - top / 2, 0.0], size=[length, top, width])
    for sx in (-1, 1):
        for sz in (-1, 1):
            at = [sx * (length / 2 - leg / 2 - 0.02), 0.1 + (height - top) / 2, sz * (width / 2 - leg / 2 - 0.02)]
            text += obj("box", at, size=[leg, height - top, leg])
    for _ in range(rng.randint(0, 3)):
        r, h = rng.uniform(0.025, 0.06), rng.uniform(0.06, 0.2)
        at = [rng.uniform(-length / 2 + 0.1, length / 2 - 0.1), 0.1 + height + h / 2,
              rng.uniform(-width / 2 + 0.1, width / 2 - 0.1)]
        text += obj("cylinder", at, radius=r, height=h)
    return text, [(0.0, 0.0, (length / 2, width / 2))], None


def room(rng):
    half_x, half_z = rng.uniform(2.2, 3.5), rng.uniform(2.2, 3.5)
    text = helix(rng, [(1.0, 1.3), (1.4, 1.8)], (0.5, 0.7), (1.2, min(half_x, half_z) - 0.6), [1.0])
    text += obj("box", [0.0, -0.05, 0.0], size=[2 * half_x, 0.1, 2 * half_z], floor=True)
    for sign in (-1, 1):
        text += obj("box", [0.0, 1.25, sign * (half_z + 0.05)], size=[2 * half_x, 2.5, 0.1], floor=True)
        text += obj("box", [sign * (half_x + 0.05), 1.25, 0.0], size=[0.1, 2.5, 2 * half_z], floor=True)
    objects, footprints = scatter(rng, (1, 4), (1.0, 1.0), 0.0)
    return text + objects, footprints, (half_x, half_z)


def bunnies(rng):
    text = helix(rng, [(0.6, 0.9), (0.95, 1.4)], (0.4, 0.6), (2.5, 4.5), [1.0, 1.5, 2.0])
    text += floor(10.0)
    for _ in range(rng.randint(1, 4)):
        scale = rng.uniform(0.7, 1.3)
        text += obj("mesh", [rng.uniform(-1.5, 1.5), -0.2 * scale, rng.uniform(-1.0, 1.0)],
                    path="${bunny}", scale=scale, rotation=[0.0, rng.uniform(0.0, 360.0), 0.0])
    # A mesh's extent is its file's: the path test below does not apply.
    return text, None, None


def clutter(rng):
    text = helix(rng, [(0.6, 1.0), (1.1, 1.7)], (0.3, 0.5), (2.5, 4.5), [1.0, 1.5, 2.0])
    text += floor(10.0)
    objects, footprints = scatter(rng, (2, 6), (1.2, 1.0), 0.1)
    return text + objects, footprints, None


def path_sees_enough(text, footprints, walls):
    """Whether the simulator's helix around `footprints` (x, z and half
    extents) keeps 1 m from the look-at vertical (x = z = 0) and 0.4 m
    inside `walls`."""
    if footprints is None:
        return True
    margin = float(text.split("margin = ")[1].split()[0])
    lo_x = min(x - r[0] for x, _, r in footprints)
    hi_x = max(x + r[0] for x, _, r in footprints)
    lo_z = min(z - r[1] for _, z, r in footprints)
    hi_z = max(z + r[1] for _, z, r in footprints)
    centre = ((lo_x + hi_x) / 2, (lo_z + hi_z) / 2)
    radius = ((hi_x - lo_x + margin) / 2, (hi_z - lo_z + margin) / 2)
    for degree in range(360):
        a = math.radians(degree)
        x, z = centre[0] + radius[0] * math.sin(a), centre[1] + radius[1] * math.cos(a)
        if math.hypot(x, z) < 1.0:
            return False
        if walls and (abs(x) > walls[0] - 0.4 or abs(z) > walls[1] - 0.4):
            return False
    return True


def main():
    kinds = {"table": table, "room": room, "bunnies": bunnies, "clutter": clutter}
    if len(sys.argv) != 3 or sys.argv[1] not in kinds or not sys.argv[2].isdigit():
        sys.exit(f"usage: random_scene.py {{{'|'.join(kinds)}}} NUMBER")
    kind, number = sys.argv[1], int(sys.argv[2])
    rng = random.Random(f"{kind}-{number}")
    while True:
        text, footprints, walls = kinds[kind](rng)
        if path_sees_enough(text, footprints, walls):
            break
    print(f'name = "{kind}-{number}"\n{text}', end="")


main()
