#!/usr/bin/env python3
"""Writes the two ray sets of the CPU-engine comparison as raypick ray files.

This script owns the ray sets only (the scene readers are benches/open3d_peer.py's):
- camera: a pinhole camera's SIDE x SIDE pixel grid from the south-east above the scene, looking
  at the centre of its bounding box (40 degrees field of view), as `synthetic::rays(Camera)`;
- incoherent: origins on a sphere of twice the bounding radius around the box centre, each aimed
  at a uniform random point inside the box (the issue's "incoherent rays").

Usage: python benches/make_ray_sets.py --scene MESH --count N --out-prefix PREFIX [--seed S]
writes PREFIX-camera.txt and PREFIX-incoherent.txt (full f64 precision).
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from open3d_peer import load_scene  # noqa: E402


def write(path, origins, dirs):
    data = np.hstack([origins, dirs])
    np.savetxt(path, data, fmt="%.17g")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", required=True)
    p.add_argument("--count", type=int, default=1_000_000)
    p.add_argument("--out-prefix", required=True)
    p.add_argument("--seed", type=int, default=1)
    a = p.parse_args()
    vertices, _ = load_scene(a.scene)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = (lo + hi) / 2
    radius = max(np.linalg.norm(hi - lo) / 2, 1e-3)
    rng = np.random.default_rng(a.seed)

    side = int(np.ceil(np.sqrt(a.count)))
    eye = centre + np.array([0.4, -1.0, 1.6]) / np.linalg.norm([0.4, -1.0, 1.6]) * radius * 2.5
    forward = (centre - eye) / np.linalg.norm(centre - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = np.tan(np.radians(20.0))
    k = np.arange(a.count)
    sx = ((k % side) + 0.5) / side * 2 - 1
    sy = 1 - ((k // side) + 0.5) / side * 2
    dirs = forward + np.outer(sx * half, right) + np.outer(sy * half, up)
    write(f"{a.out_prefix}-camera.txt", np.tile(eye, (a.count, 1)), dirs)

    u = rng.normal(size=(a.count, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    origins = centre + u * radius * 2
    targets = lo + (hi - lo) * rng.random((a.count, 3))
    write(f"{a.out_prefix}-incoherent.txt", origins, targets - origins)


if __name__ == "__main__":
    main()
