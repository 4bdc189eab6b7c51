#!/usr/bin/env python3
"""Reference-free trajectory accuracy: how well a trajectory registers depth frames to each other.

The usual trajectory figure (ATE / RPE against the dataset's poses) is only as
good as the reference, and the 7-Scenes reference poses have glitches of their
own: a short jump in the reference makes every tracker look wrong there.  This
script needs no reference.  For each trajectory it takes pairs of depth frames
(i, j = i + gap), maps frame j's points into frame i's camera with the
trajectory's relative pose inv(P_i) . P_j, and measures how far they land from
frame i's surface:

  * both frames are back-projected with a 4-pixel stride, keeping depths in
    (0, 3.0] m;
  * frame i's cloud gets normals (radius 0.05 m, at most 30 neighbours,
    oriented towards the camera);
  * each moved point of frame j is matched to its nearest point q of frame i;
    matches farther than 3 cm are dropped (non-overlapping or occluded parts);
  * the pair's figure is the mean point-to-plane distance |(p - q) . n_q| in
    mm.

Pairs start every 10 frames and the figures are averaged per gap. Every
trajectory is scored on the same pairs: a pair counts only when every
trajectory matches more than 200 points in it, and the pairs a trajectory
failed that way are reported beside its figures, so a trajectory cannot look
better by dropping the pairs it registers badly.  Sensor
noise and the sampling give a floor of a few mm that every trajectory shares,
so the numbers are for comparing trajectories on the same frames: the one that
registers the depth frames more consistently has the lower figures.  A gap
that is wrong in one trajectory stands out at the gaps whose pairs span it;
for example a reference trajectory with a jump between two frames shows
higher figures at the gaps spanning the jump, and only there.

Usage:
  PY bench/trajectory_consistency.py FOLDER TRAJ [TRAJ ...]
        [--frames N] [--gaps 20,50,100,150,200,250] [--intrinsics fx,fy,cx,cy] [--json]

  FOLDER  a 7-Scenes style frames folder: frame-XXXXXX.depth.png (16-bit,
          millimetres, 0 = no depth), frame-XXXXXX.pose.txt (4x4
          camera-to-world) and camera-intrinsics.txt (3x3), or the
          intrinsics given as --intrinsics fx,fy,cx,cy.
  TRAJ    a TUM trajectory file (`timestamp tx ty tz qx qy qz qw`, the
          timestamp being the frame index, `#` starts a comment line), or the
          word `folder` for the folder's own pose files.

PY is a Python with numpy and open3d; scipy is used for the nearest-neighbour
search when present (Open3D's search otherwise).  Frames 0..N-1 are used
(default N = 300), fewer if a trajectory or the folder stops earlier.  The
output is one row per gap with the pairs used of those tried and, for each
trajectory, the mean figure (mm), the mean number of matched points and the
pairs it failed, then the mean over the gaps per trajectory; `--json` prints
one JSON object instead.
"""
import argparse
import json
import os
import sys

import numpy as np

try:
    import open3d as o3d
except ImportError:  # pragma: no cover - reported as a clear error below
    o3d = None

try:
    from scipy.spatial import cKDTree
except ImportError:
    cKDTree = None

PAIR_STEP = 10          # a pair starts every PAIR_STEP frames
PIXEL_STRIDE = 4        # back-projection stride in pixels (both axes)
MAX_DEPTH = 3.0         # m; farther depths are dropped
NORMAL_RADIUS = 0.05    # m
NORMAL_MAX_NN = 30
MATCH_DIST = 0.03       # m; farther nearest neighbours are not matches
MIN_MATCHES = 200       # a pair needs more matches than this, in every trajectory, to count


class InputError(Exception):
    """A problem with the command-line inputs, reported without a traceback."""


# --------------------------------------------------------------------------- inputs

def depth_path(folder, i):
    return os.path.join(folder, f'frame-{i:06d}.depth.png')


def pose_path(folder, i):
    return os.path.join(folder, f'frame-{i:06d}.pose.txt')


def quat_to_matrix(qx, qy, qz, qw):
    """Rotation matrix of a (not necessarily normalised) quaternion."""
    q = np.array([qx, qy, qz, qw], dtype=np.float64)
    n = np.linalg.norm(q)
    if n == 0:
        raise ValueError('zero quaternion')
    x, y, z, w = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def read_tum(path):
    """{frame index: 4x4 camera-to-world} from a TUM file whose timestamps are frame indices."""
    if not os.path.isfile(path):
        raise InputError(f'{path}: trajectory file not found')
    poses = {}
    with open(path) as f:
        for lineno, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith('#'):
                continue
            fields = line.split()
            try:
                if len(fields) < 8:
                    raise ValueError(f'expected 8 fields, got {len(fields)}')
                values = [float(v) for v in fields[:8]]
                T = np.eye(4)
                T[:3, :3] = quat_to_matrix(*values[4:8])
                T[:3, 3] = values[1:4]
            except ValueError as e:
                raise InputError(f'{path}:{lineno}: not a TUM pose line ({e})') from None
            poses[int(round(values[0]))] = T
    if not poses:
        raise InputError(f'{path}: no poses in trajectory file')
    return poses


class FolderPoses:
    """The folder's own frame-XXXXXX.pose.txt files, read on demand, as a read-only mapping."""

    def __init__(self, folder):
        self.folder = folder
        self.cache = {}

    def __contains__(self, i):
        return i in self.cache or os.path.isfile(pose_path(self.folder, i))

    def __getitem__(self, i):
        if i not in self.cache:
            path = pose_path(self.folder, i)
            try:
                T = np.loadtxt(path).reshape(4, 4)
            except (OSError, ValueError) as e:
                raise InputError(f'{path}: cannot read a 4x4 pose ({e})') from None
            if not np.all(np.isfinite(T)):
                raise InputError(f'{path}: pose is not finite')
            self.cache[i] = T
        return self.cache[i]


def read_intrinsics(folder, given):
    """The 3x3 camera matrix: --intrinsics if given, else the folder's camera-intrinsics.txt."""
    if given is not None:
        fx, fy, cx, cy = given
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    path = os.path.join(folder, 'camera-intrinsics.txt')
    if not os.path.isfile(path):
        raise InputError(f'{path}: not found; give the camera as --intrinsics fx,fy,cx,cy')
    try:
        K = np.loadtxt(path).reshape(3, 3)
    except (OSError, ValueError) as e:
        raise InputError(f'{path}: cannot read a 3x3 intrinsics matrix ({e})') from None
    return K


def trajectory_names(args):
    """File-name stems (or `folder`), made unique by a #2, #3 ... suffix when repeated."""
    names, seen = [], {}
    for a in args:
        stem = 'folder' if a == 'folder' else os.path.splitext(os.path.basename(a))[0]
        seen[stem] = seen.get(stem, 0) + 1
        names.append(stem if seen[stem] == 1 else f'{stem}#{seen[stem]}')
    return names


def usable_frames(folder, trajectories, frames):
    """Length of the prefix 0..n-1 (n <= frames) that the folder and every trajectory have.

    Returns n and a note naming what limited it (None when nothing did)."""
    n, limit = frames, None
    for i in range(frames):
        if not os.path.isfile(depth_path(folder, i)):
            n, limit = i, depth_path(folder, i)
            break
    for name, arg, poses in trajectories:
        for i in range(n):
            if i not in poses:
                n, limit = i, (pose_path(folder, i) if arg == 'folder' else arg)
                break
    return n, limit


# --------------------------------------------------------------------------- clouds

class Frame:
    """One frame's back-projected cloud with normals and a nearest-neighbour index."""

    def __init__(self, points, normals):
        self.points = points
        self.normals = normals
        if cKDTree is not None:
            self._tree = cKDTree(points)
        else:
            self._nns = o3d.core.nns.NearestNeighborSearch(o3d.core.Tensor(points))
            self._nns.knn_index()

    def nearest(self, queries):
        """Index of and distance to the nearest point of this frame for each query point."""
        if cKDTree is not None:
            dist, idx = self._tree.query(queries, k=1, distance_upper_bound=MATCH_DIST)
            idx = np.minimum(idx, len(self.points) - 1)  # misses come back as len(points), dist inf
            return idx, dist
        idx, dist2 = self._nns.knn_search(o3d.core.Tensor(queries), 1)
        return idx.numpy()[:, 0].astype(np.int64), np.sqrt(dist2.numpy()[:, 0])


class FrameCache:
    """Loads each frame once, for all trajectories."""

    def __init__(self, folder, K):
        self.folder = folder
        self.K = K
        self.frames = {}

    def __getitem__(self, i):
        if i not in self.frames:
            self.frames[i] = self._load(i)
        return self.frames[i]

    def _load(self, i):
        path = depth_path(self.folder, i)
        img = o3d.io.read_image(path)
        depth = np.asarray(img)
        if depth.ndim != 2 or depth.size == 0:
            raise InputError(f'{path}: not a single-channel depth image')
        d = depth[::PIXEL_STRIDE, ::PIXEL_STRIDE].astype(np.float64) / 1000.0
        v, u = np.mgrid[0:depth.shape[0]:PIXEL_STRIDE, 0:depth.shape[1]:PIXEL_STRIDE]
        ok = (d > 0) & (d <= MAX_DEPTH)
        z = d[ok]
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        points = np.column_stack(((u[ok] - cx) * z / fx, (v[ok] - cy) * z / fy, z))
        if len(points) == 0:
            return Frame(np.zeros((1, 3)) + np.inf, np.zeros((1, 3)))
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS, max_nn=NORMAL_MAX_NN))
        pcd.orient_normals_towards_camera_location(np.zeros(3))
        return Frame(points, np.asarray(pcd.normals).copy())


def pair_figure(target, source, T):
    """Mean |(p - q) . n_q| (m) and match count of source moved by T onto target."""
    moved = source.points @ T[:3, :3].T + T[:3, 3]
    idx, dist = target.nearest(moved)
    hit = dist < MATCH_DIST
    if not np.any(hit):
        return None, 0
    diff = moved[hit] - target.points[idx[hit]]
    residual = np.abs(np.einsum('ij,ij->i', diff, target.normals[idx[hit]]))
    return float(residual.mean()), int(hit.sum())


# --------------------------------------------------------------------------- main

def evaluate(folder, K, trajectories, frames, gaps):
    """Per gap: pairs tried, and per trajectory the (figure_mm, matches) of
    the pairs every trajectory registered and the count of pairs it failed."""
    cache = FrameCache(folder, K)
    names = [name for name, _, _ in trajectories]
    results = {g: {'tried': 0, 'used': {n: [] for n in names}, 'failed': {n: 0 for n in names}}
               for g in gaps}
    for g in gaps:
        for i in range(0, frames - g, PAIR_STEP):
            j = i + g
            target, source = cache[i], cache[j]
            figures = {}
            for name, _, poses in trajectories:
                T = np.linalg.inv(poses[i]) @ poses[j]
                figures[name] = pair_figure(target, source, T)
            r = results[g]
            r['tried'] += 1
            failed = [n for n, (_, matches) in figures.items() if matches <= MIN_MATCHES]
            for n in failed:
                r['failed'][n] += 1
            if not failed:
                for n, (mean, matches) in figures.items():
                    r['used'][n].append((mean * 1000.0, matches))
    return results


def summarise(results, names, gaps):
    out = {}
    for name in names:
        rows = {}
        for g in gaps:
            pairs = results[g]['used'][name]
            rows[g] = {
                'mean_mm': float(np.mean([m for m, _ in pairs])) if pairs else None,
                'mean_matches': float(np.mean([c for _, c in pairs])) if pairs else None,
                'pairs': len(pairs),
                'pairs_tried': results[g]['tried'],
                'pairs_failed': results[g]['failed'][name],
            }
        means = [r['mean_mm'] for r in rows.values() if r['mean_mm'] is not None]
        out[name] = {'per_gap': rows, 'mean_mm': float(np.mean(means)) if means else None}
    return out


def print_table(summary, gaps, frames, limit):
    names = list(summary)
    width = max(22, max(len(n) for n in names) + 2)
    print(f'frames 0..{frames - 1}, pairs every {PAIR_STEP} frames, the same pairs for every trajectory; '
          f'per trajectory: mean point-to-plane mm / mean matches / pairs it failed'
          + (f' (limited by {limit})' if limit else ''))
    print('gap  pairs used/tried' + ''.join(f'{n:>{width}}' for n in names))
    for g in gaps:
        first = summary[names[0]]['per_gap'][g]
        cells = []
        for n in names:
            r = summary[n]['per_gap'][g]
            cell = '-' if r['mean_mm'] is None else f"{r['mean_mm']:6.2f} {r['mean_matches']:6.0f}"
            cell += f" {r['pairs_failed']:3d}"
            cells.append(f'{cell:>{width}}')
        print(f"{g:<5d}{first['pairs']:>5d}/{first['pairs_tried']:<5d}     " + ''.join(cells))
    for n in names:
        m = summary[n]['mean_mm']
        print(f'mean over gaps  {n}: ' + ('-' if m is None else f'{m:.2f} mm'))


def parse_gaps(text):
    try:
        gaps = [int(x) for x in text.split(',') if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a comma-separated list of integers: {text!r}') from None
    if not gaps or any(g <= 0 for g in gaps):
        raise argparse.ArgumentTypeError(f'gaps must be positive integers: {text!r}')
    return gaps


def parse_intrinsics(text):
    try:
        values = [float(x) for x in text.split(',')]
    except ValueError:
        values = []
    if len(values) != 4 or not all(np.isfinite(values)) or values[0] <= 0 or values[1] <= 0:
        raise argparse.ArgumentTypeError(f'expected fx,fy,cx,cy with positive focal lengths: {text!r}')
    return values


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('folder', help='7-Scenes style frames folder')
    ap.add_argument('traj', nargs='+', help='TUM trajectory file (timestamp = frame index), or `folder`')
    ap.add_argument('--frames', type=int, default=300, help='use frames 0..N-1 (default 300)')
    ap.add_argument('--gaps', type=parse_gaps, default=[20, 50, 100, 150, 200, 250],
                    help='comma-separated frame gaps (default 20,50,100,150,200,250)')
    ap.add_argument('--intrinsics', type=parse_intrinsics,
                    help='fx,fy,cx,cy, when the folder has no camera-intrinsics.txt')
    ap.add_argument('--json', action='store_true', help='print one JSON object instead of the table')
    args = ap.parse_args(argv)

    try:
        if o3d is None:
            raise InputError('open3d is not importable in this Python')
        if not os.path.isdir(args.folder):
            raise InputError(f'{args.folder}: frames folder not found')
        if args.frames <= 0:
            raise InputError(f'--frames must be positive, got {args.frames}')
        K = read_intrinsics(args.folder, args.intrinsics)
        names = trajectory_names(args.traj)
        trajectories = [(name, a, FolderPoses(args.folder) if a == 'folder' else read_tum(a))
                        for name, a in zip(names, args.traj)]
        frames, limit = usable_frames(args.folder, trajectories, args.frames)
        if frames <= min(args.gaps):
            if limit is None:
                raise InputError(f'--frames {frames} leaves no pair for the smallest gap ({min(args.gaps)})')
            raise InputError(f'{limit}: frame {frames} is missing, but frames 0..{min(args.gaps)} '
                             f'are needed for the smallest gap ({min(args.gaps)})')
        results = evaluate(args.folder, K, trajectories, frames, args.gaps)
    except InputError as e:
        print(f'trajectory_consistency: {e}', file=sys.stderr)
        return 1

    summary = summarise(results, names, args.gaps)
    if args.json:
        print(json.dumps({
            'folder': os.path.abspath(args.folder),
            'frames': frames,
            'limited_by': limit,
            'gaps': args.gaps,
            'pair_step': PAIR_STEP,
            'trajectories': {n: {'mean_mm': s['mean_mm'],
                                 'per_gap': {str(g): r for g, r in s['per_gap'].items()}}
                             for n, s in summary.items()},
        }, sort_keys=True))
    else:
        if limit:
            print(f'note: only frames 0..{frames - 1} used (missing: {limit})', file=sys.stderr)
        print_table(summary, args.gaps, frames, limit)
    return 0


if __name__ == '__main__':
    sys.exit(main())
