"""Shared fixtures: the repository's test data, loaded scenes, seeded rays, and the CLI binary
(for the CSV equivalence tests)."""

import os
import pathlib
import subprocess

import numpy as np
import pytest

import raypick

REPO = pathlib.Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data"
BUNNY = DATA / "bunny.obj"
DEM = DATA / "jacksboro_fault_dem_utm.asc"


@pytest.fixture(scope="session")
def bunny():
    return raypick.Scene.load(str(BUNNY))


@pytest.fixture(scope="session")
def dem():
    return raypick.Scene.load(str(DEM))


def rays_at(scene, n, seed=1, spread=0.3):
    """`n` seeded rays from above the scene's box, aimed down into it, about half of them hits."""
    lo, hi = scene.bounds
    rng = np.random.default_rng(seed)
    origins = lo + (hi - lo) * rng.random((n, 3))
    origins[:, 2] = hi[2] + 0.1 * (hi - lo).max()
    dirs = np.tile([0.0, 0.0, -1.0], (n, 1)) + rng.normal(scale=spread, size=(n, 3))
    return np.hstack([origins, dirs])


def incoherent_rays(scene, n, seed=2):
    """`n` seeded rays from a sphere around the scene, aimed at random points in its box."""
    lo, hi = scene.bounds
    rng = np.random.default_rng(seed)
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    origins = centre + 2 * radius * u
    targets = lo + (hi - lo) * rng.random((n, 3))
    return np.hstack([origins, targets - origins])


def same_bits(a, b):
    """Whether two arrays are identical: dtype, shape and every bit (NaNs included)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def assert_same_answers(expected, got):
    assert list(expected) == list(got)
    for key in expected:
        assert same_bits(expected[key], got[key]), key


@pytest.fixture(scope="session")
def cli():
    """The `raypick` command line: $RAYPICK_CLI, else `cargo build --release` (a no-op when the
    release build is fresh, as in CI after `cargo run --release`)."""
    given = os.environ.get("RAYPICK_CLI")
    if given:
        return given
    subprocess.run(
        ["cargo", "build", "--release", "--quiet", "--bin", "raypick"], cwd=REPO, check=True
    )
    target = os.environ.get("CARGO_TARGET_DIR", str(REPO / "target"))
    return str(pathlib.Path(target, "release", "raypick"))
