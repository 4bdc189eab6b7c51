"""The corridor walks of the bounded-memory and tracking benchmarks.

Writes, into DIR, corridor.toml (a floor, a wall along +x on the +z side, and
a box, turned 17 degrees more each time, and a post every 3 m) and two TUM
pose files for the simulated sensor at 10 cm a frame: straight.txt (LENGTH
metres on, looking ahead at the wall) and there-and-back.txt (LENGTH/2 out,
then, in one frame, turned round to walk back past what it saw). The
camera looks at the wall turned 35 degrees towards +x on the way out and,
on the way back, by atan(BACK) towards -x (default 0.7: 35 degrees, a turn
of 70 degrees).

Usage: python3 bench/corridor_walk.py LENGTH DIR [BACK]
"""
import math, sys
length, work = float(sys.argv[1]), sys.argv[2]
back_tan = float(sys.argv[3]) if len(sys.argv) > 3 else 0.7
with open(f"{work}/corridor.toml", "w") as f:
    f.write(f'name = "corridor"\n[[object]]\nshape = "plane"\nsize = [{length + 10}, 8.0]\n'
            f'translation = [{length / 2}, 0.0, 0.0]\nfloor = true\n'
            f'[[object]]\nshape = "box"\nsize = [{length + 10}, 3.0, 0.1]\ntranslation = [{length / 2}, 1.5, 2.0]\n')
    for i in range(int(length / 3)):
        x = 1.5 + 3 * i
        f.write(f'[[object]]\nshape = "box"\nsize = [0.6, 0.5, 0.4]\ntranslation = [{x}, 0.25, 1.5]\n'
                f'rotation = [0.0, {17 * i}, 0.0]\n'
                f'[[object]]\nshape = "cylinder"\nradius = 0.1\nheight = 1.2\ntranslation = [{x + 1.2}, 0.6, 1.2]\n')
def norm(v):
    n = math.sqrt(sum(c * c for c in v)); return [c / n for c in v]
def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
def looking(ahead):
    """Quaternion (x, y, z, w) of a camera looking along `ahead` (x right, y down, z ahead)."""
    z = norm(ahead); x = norm(cross(z, [0, 1, 0])); y = cross(z, x)
    m = [[x[i], y[i], z[i]] for i in range(3)]  # columns: camera axes in world
    w = math.sqrt(max(0.0, 1 + m[0][0] + m[1][1] + m[2][2])) / 2
    return [(m[2][1] - m[1][2]) / (4 * w), (m[0][2] - m[2][0]) / (4 * w), (m[1][0] - m[0][1]) / (4 * w), w]
out, back = looking([0.7, -0.5, 1.0]), looking([-back_tan, -0.5, 1.0])
frames = int(length / 0.1)
with open(f"{work}/straight.txt", "w") as f:
    for i in range(frames):
        f.write(f"{i} {0.1 * i} 1.3 -0.5 {' '.join(map(str, out))}\n")
with open(f"{work}/there-and-back.txt", "w") as f:
    half = frames // 2
    for i in range(frames):
        x, q = (0.1 * i, out) if i < half else (0.1 * (2 * half - 1 - i), back)
        f.write(f"{i} {x} 1.3 -0.5 {' '.join(map(str, q))}\n")

