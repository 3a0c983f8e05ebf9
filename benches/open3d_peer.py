#!/usr/bin/env python3
"""Open3D peer benchmark for raypick: closest-hit ray casting with RaycastingScene.

This script owns one thing: measuring how fast Open3D's
``open3d.t.geometry.RaycastingScene`` (Embree underneath, float32) answers
closest-hit queries on the same scene and ray files that raypick reads, so the
two can be compared in the same run on the same machine.  It reads the scene
(OBJ or ESRI ASCII grid) and raypick's ray file itself, shifts both to the
scene's bounding-box centre in float64 (as raypick does) before going to
float32, builds the scene (timed), then times ``cast_rays`` over several passes.

Usage:
    python benches/open3d_peer.py --scene MESH --rays RAYFILE [--threads N] [--passes K]

    MESH     an .obj file or an ESRI ASCII grid (.asc)
    RAYFILE  one ray per line: ``ox oy oz dx dy dz [tmax]``, whitespace separated,
             ``#`` starts a comment, blank lines are skipped
    N        threads for build and casting (0 = Open3D's automatic choice; default 0)
    K        timed passes after one warm-up pass (default 5)

Output (one ``key=value`` per line; the last line is exactly
``open3d_rays_per_s=<best>`` for scripts to read):
    open3d_version, triangles, rays, threads, build_s, hits,
    cast_s_best, cast_s_median, open3d_rays_per_s_best,
    open3d_rays_per_s_median, open3d_rays_per_s

Bad arguments or unreadable/malformed files: one sentence on stderr, exit 2.

Needs only numpy and open3d (tested with open3d 0.20.0 on Python 3.11).
"""

import argparse
import os
import statistics
import sys
import time

import numpy as np


def fail(message):
    """Print one sentence to stderr and exit with status 2 (bad input)."""
    print(message, file=sys.stderr)
    sys.exit(2)


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are a single sentence and exit status 2."""

    def error(self, message):
        fail(f"open3d_peer: bad arguments: {message}.")


# ---------------------------------------------------------------------------
# Scene loading
# ---------------------------------------------------------------------------


def _obj_index(token, nverts):
    """Turn one OBJ face-vertex token (``a``, ``a/t``, ``a//n``, ``a/t/n``)
    into a 0-based vertex index.  Negative indices count back from the
    vertices defined so far (``-1`` is the last one)."""
    i = int(token.split("/", 1)[0])
    if i > 0:
        return i - 1
    if i < 0:
        return nverts + i
    raise ValueError("OBJ index 0 is not valid")


def load_obj(path):
    """Read vertices (``v x y z``) and faces (``f ...``) from an OBJ file.

    Polygons are fan-triangulated: (i0,i1,i2), (i0,i2,i3), ...  Everything
    else (normals, texture coordinates, groups, materials) is ignored.
    Returns (vertices float64 (N,3), triangles int64 (M,3))."""
    with open(path, "r", encoding="utf-8", errors="replace") as fh:
        text = fh.read()

    vert_tokens = []  # 'x y z' strings, parsed with numpy in one go at the end
    tris = []
    nverts = 0
    for line in text.splitlines():
        if line.startswith("v "):
            parts = line.split()
            # Only x y z; an optional w or vertex colour is dropped.
            vert_tokens.append(" ".join(parts[1:4]))
            nverts += 1
        elif line.startswith("f "):
            parts = line.split()[1:]
            if len(parts) < 3:
                raise ValueError("face with fewer than 3 vertices")
            idx = [_obj_index(p, nverts) for p in parts]
            i0 = idx[0]
            for k in range(1, len(idx) - 1):
                tris.append((i0, idx[k], idx[k + 1]))

    if nverts == 0:
        raise ValueError("no vertices")
    vertices = np.array(" ".join(vert_tokens).split(), dtype=np.float64)
    if vertices.size != 3 * nverts:
        raise ValueError("a vertex line has fewer than 3 coordinates")
    vertices = vertices.reshape(-1, 3)
    triangles = np.array(tris, dtype=np.int64).reshape(-1, 3)
    if triangles.size and (triangles.min() < 0 or triangles.max() >= nverts):
        raise ValueError("face index out of range")
    return vertices, triangles


def load_asc(path):
    """Read an ESRI ASCII grid and triangulate it as a height field.

    Vertex (row r, col c) sits at x = xll + c*cellsize,
    y = yll + (nrows-1-r)*cellsize, z = value (rows run north to south).
    With ``xllcorner``/``yllcorner`` the lower-left corner of the grid is
    given, so cellsize/2 is added to put vertices at cell centres; with
    ``xllcenter``/``yllcenter`` the position is used as is.

    Triangulation: each cell between rows r, r+1 and cols c, c+1 is split
    along the diagonal (r,c)-(r+1,c+1) into the two triangles
    [(r,c), (r+1,c), (r+1,c+1)] and [(r,c), (r+1,c+1), (r,c+1)].  Any
    triangle touching a NODATA vertex is skipped.  (The diagonal choice does
    not matter for a speed comparison.)
    Returns (vertices float64 (N,3), triangles int64 (M,3))."""
    with open(path, "r", encoding="utf-8", errors="replace") as fh:
        text = fh.read()
    tokens = text.split()

    # Header: key/value pairs until the first token that is a number.
    header = {}
    pos = 0
    while pos + 1 < len(tokens):
        key = tokens[pos]
        try:
            float(key)
            break  # data starts here
        except ValueError:
            header[key.lower()] = tokens[pos + 1]
            pos += 2

    try:
        ncols = int(header["ncols"])
        nrows = int(header["nrows"])
        cellsize = float(header["cellsize"])
        if "xllcorner" in header:
            xll = float(header["xllcorner"]) + cellsize / 2.0
        else:
            xll = float(header["xllcenter"])
        if "yllcorner" in header:
            yll = float(header["yllcorner"]) + cellsize / 2.0
        else:
            yll = float(header["yllcenter"])
    except KeyError as e:
        raise ValueError(f"missing header key {e}") from None
    nodata = float(header["nodata_value"]) if "nodata_value" in header else None
    if ncols < 2 or nrows < 2:
        raise ValueError("grid needs at least 2 rows and 2 columns")

    z = np.array(tokens[pos:pos + nrows * ncols], dtype=np.float64)
    if z.size != nrows * ncols:
        raise ValueError("fewer values than nrows*ncols")
    z = z.reshape(nrows, ncols)

    rows, cols = np.meshgrid(np.arange(nrows), np.arange(ncols), indexing="ij")
    x = xll + cols * cellsize
    y = yll + (nrows - 1 - rows) * cellsize
    vertices = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)

    # Vertex ids of each cell's four corners, one entry per cell.
    vid = np.arange(nrows * ncols, dtype=np.int64).reshape(nrows, ncols)
    a = vid[:-1, :-1].ravel()  # (r,   c)
    b = vid[1:, :-1].ravel()   # (r+1, c)
    c = vid[1:, 1:].ravel()    # (r+1, c+1)
    d = vid[:-1, 1:].ravel()   # (r,   c+1)
    triangles = np.concatenate([np.stack([a, b, c], axis=1),
                                np.stack([a, c, d], axis=1)])

    if nodata is not None:
        bad = (z.ravel() == nodata)
        triangles = triangles[~bad[triangles].any(axis=1)]
    return vertices, triangles


def load_scene(path):
    """Dispatch on the file extension: ``.asc`` is a grid, anything else OBJ."""
    if path.lower().endswith(".asc"):
        return load_asc(path)
    return load_obj(path)


# ---------------------------------------------------------------------------
# Ray loading
# ---------------------------------------------------------------------------


def load_rays(path):
    """Read raypick's ray file into (rays float64 (R,6), tmax float64 (R,) or None).

    Fast path: the whole text is split and parsed by numpy at once.  The 7th
    column (tmax) is kept only when every ray line has 7 numbers; when lines
    mix 6 and 7 numbers the tmax values are ignored."""
    with open(path, "r", encoding="utf-8", errors="replace") as fh:
        text = fh.read()

    # Strip comments only if there are any (saves a pass over big files).
    if "#" in text:
        text = "\n".join(line.split("#", 1)[0] for line in text.splitlines())

    lines = [ln for ln in text.splitlines() if ln.strip()]
    nrays = len(lines)
    if nrays == 0:
        raise ValueError("no rays")
    values = np.array(text.split(), dtype=np.float64)

    if values.size == 6 * nrays:
        return values.reshape(-1, 6), None
    if values.size == 7 * nrays:
        # 7*n tokens over n lines could in principle hide a 5/8 mix; make sure.
        if all(len(ln.split()) == 7 for ln in lines):
            v = values.reshape(-1, 7)
            return np.ascontiguousarray(v[:, :6]), v[:, 6].copy()

    # Mixed line lengths: parse line by line, keep the first 6 numbers.
    rays = np.empty((nrays, 6), dtype=np.float64)
    for i, ln in enumerate(lines):
        parts = ln.split()
        if len(parts) not in (6, 7):
            raise ValueError(f"ray line {i + 1} has {len(parts)} numbers, not 6 or 7")
        rays[i] = [float(p) for p in parts[:6]]
    return rays, None


# ---------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------


def main():
    parser = _Parser(description="Open3D RaycastingScene peer benchmark for raypick.")
    parser.add_argument("--scene", required=True, help="OBJ or ESRI ASCII grid (.asc)")
    parser.add_argument("--rays", required=True, help="raypick ray file")
    parser.add_argument("--threads", type=int, default=0,
                        help="threads for build and casting; 0 = automatic (default)")
    parser.add_argument("--passes", type=int, default=5,
                        help="timed passes after one warm-up (default 5)")
    args = parser.parse_args()
    if args.threads < 0:
        fail("open3d_peer: --threads must be 0 (automatic) or a positive count.")
    if args.passes < 1:
        fail("open3d_peer: --passes must be at least 1.")

    # Import here so that argument errors do not pay for loading Open3D.
    try:
        import open3d as o3d
    except ImportError as e:
        fail(f"open3d_peer: cannot import open3d ({e}).")

    # --- inputs (not timed) ---
    for label, path in (("scene", args.scene), ("ray", args.rays)):
        if not os.path.isfile(path):
            fail(f"open3d_peer: {label} file {path} does not exist or is not a file.")
    try:
        vertices, triangles = load_scene(args.scene)
    except (OSError, ValueError) as e:
        fail(f"open3d_peer: cannot read scene file {args.scene}: {e}.")
    if triangles.shape[0] == 0:
        fail(f"open3d_peer: scene file {args.scene} has no triangles.")
    try:
        rays64, tmax = load_rays(args.rays)
    except (OSError, ValueError) as e:
        fail(f"open3d_peer: cannot read ray file {args.rays}: {e}.")

    # Like raypick: work in offsets from the scene's bounding-box centre,
    # computed and subtracted in float64, then go to float32.  This keeps
    # float32 precision at map coordinates (e.g. UTM eastings ~5e5).
    used = vertices[np.unique(triangles)]
    centre = (used.min(axis=0) + used.max(axis=0)) * 0.5
    verts32 = np.ascontiguousarray((vertices - centre).astype(np.float32))
    tris32 = np.ascontiguousarray(triangles.astype(np.uint32))
    rays64[:, :3] -= centre
    rays32 = np.ascontiguousarray(rays64.astype(np.float32))
    rays_t = o3d.core.Tensor.from_numpy(rays32)

    # --- build (timed) ---
    # Open3D commits (builds the Embree BVH for) the scene lazily on the
    # first query, so a one-ray cast is part of the build time.
    probe = o3d.core.Tensor.from_numpy(rays32[:1].copy())
    t0 = time.perf_counter()
    scene = o3d.t.geometry.RaycastingScene(nthreads=args.threads)
    scene.add_triangles(o3d.core.Tensor.from_numpy(verts32),
                        o3d.core.Tensor.from_numpy(tris32))
    scene.cast_rays(probe, nthreads=args.threads)
    build_s = time.perf_counter() - t0

    # --- casting (timed): one warm-up pass, then K passes ---
    # Open3D 0.20's cast_rays takes nthreads itself; it has no tmin/tmax, so
    # rays run to infinity and tmax (when the file gives it) only filters the
    # hit count below.  The timed call includes building the result dict
    # (t_hit, ids, uvs, normals), which is what the API returns.
    result = scene.cast_rays(rays_t, nthreads=args.threads)
    times = []
    for _ in range(args.passes):
        t0 = time.perf_counter()
        scene.cast_rays(rays_t, nthreads=args.threads)
        times.append(time.perf_counter() - t0)

    t_hit = result["t_hit"].numpy()
    hit = np.isfinite(t_hit)
    if tmax is not None:
        hit &= t_hit <= tmax
    nrays = rays32.shape[0]
    best = min(times)
    median = statistics.median(times)

    print(f"open3d_version={o3d.__version__}")
    print(f"triangles={triangles.shape[0]}")
    print(f"rays={nrays}")
    print(f"threads={args.threads}")
    print(f"build_s={build_s:.6f}")
    print(f"hits={int(hit.sum())}")
    print(f"cast_s_best={best:.6f}")
    print(f"cast_s_median={median:.6f}")
    print(f"open3d_rays_per_s_best={nrays / best:.0f}")
    print(f"open3d_rays_per_s_median={nrays / median:.0f}")
    print(f"open3d_rays_per_s={nrays / best:.0f}")


if __name__ == "__main__":
    main()
