"""A pose for every frame START..END-1 of a TUM trajectory whose lost frames
are missing: a lost frame gets the last good pose before it (what Open3D's
dense SLAM keeps for a frame it cannot track), so that both tools' errors
score every frame. Writes the filled trajectory to standard output.

Usage: python3 bench/fill_lost_poses.py TRAJECTORY START END
"""
import sys

path, start, end = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
poses = {}
for line in open(path):
    if line.strip() and not line.startswith('#'):
        poses[int(float(line.split()[0]))] = line.split(None, 1)[1]
last = None
for frame in range(start, end):
    last = poses.get(frame, last)
    print(f"{frame} {last}", end='')
