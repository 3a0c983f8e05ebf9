"""The Python answers are the CLI's: the same rays through `raypick pick` (CSV), `raypick los`
and `raypick viewshed` on the bunny and on the Jacksboro DEM, compared field by field, every
number to the bit (the CSV prints shortest round-trip numbers, so parsing one gives back the
exact f64)."""

import csv
import io
import json
import subprocess
import warnings

import numpy as np
import pytest

import raypick
from conftest import BUNNY, DEM, incoherent_rays, rays_at

FIELDS = ["t", "object", "triangle", "u", "v"]


def run_cli(cli, *args):
    done = subprocess.run([cli, *map(str, args)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return list(csv.DictReader(io.StringIO(done.stdout)))


def write_numbers(path, rows):
    with open(path, "w") as out:
        for row in rows:
            out.write(" ".join(repr(float(x)) for x in row) + "\n")


def number(text):
    return float(text) if text != "" else None


def expect_row(row, answers, i, cells, k=None):
    """Checks one CSV row against ray i's answer (or hit k of the per-hit columns)."""
    j = i if k is None else k
    hit = row["hit"] == "1"
    assert hit == bool(answers["hit"][i])
    assert row["invalid"] == str(int(answers["invalid"][i]))
    if not hit:
        assert all(row[f] == "" for f in FIELDS + ["x", "y", "z", "nx", "ny", "nz"])
        return
    for f in FIELDS:
        assert number(row[f]) == answers[f][j], (f, row[f], answers[f][j])
    assert [number(row[c]) for c in ("x", "y", "z")] == list(answers["position"][j])
    assert [number(row[c]) for c in ("nx", "ny", "nz")] == list(answers["normal"][j])
    if cells:
        for c in ("row", "col"):
            assert (int(row[c]) if row[c] else -1) == answers[c][j]


@pytest.mark.parametrize("which", ["bunny", "dem"])
def test_pick_matches_the_clis_csv(cli, tmp_path, which, request):
    scene = request.getfixturevalue(which)
    path = BUNNY if which == "bunny" else DEM
    rays = np.vstack([rays_at(scene, 1500, spread=0.1), incoherent_rays(scene, 1500)])
    rays[7] = [np.nan, 0, 0, 0, 0, -1]  # an invalid ray
    write_numbers(tmp_path / "rays.txt", rays)
    cells = which == "dem"

    for mode in ["closest", "any"]:
        rows = run_cli(cli, "pick", "-q", "--scene", path, "--rays", tmp_path / "rays.txt",
                       "--mode", mode)
        answers = scene.pick(rays, mode=mode)
        assert len(rows) == len(rays)
        assert answers["invalid"][7]
        for i, row in enumerate(rows):
            assert int(row["ray"]) == i
            if mode == "closest":
                expect_row(row, answers, i, cells)
            else:
                assert row["hit"] == str(int(answers["hit"][i]))

    rows = run_cli(cli, "pick", "-q", "--scene", path, "--rays", tmp_path / "rays.txt",
                   "--mode", "all", "--max-hits", "4")
    answers = scene.pick(rays, mode="all", max_hits=4)
    offsets = answers["offsets"]
    k = 0
    for row in rows:
        i = int(row["ray"])
        assert row["overflow"] == str(int(answers["overflow"][i]))
        if row["hit"] == "0":
            assert offsets[i] == offsets[i + 1] and row["rank"] == ""
            continue
        rank = int(row["rank"])
        assert (answers["ray"][k], answers["rank"][k]) == (i, rank)
        expect_row(row, answers, i, cells, k)
        k += 1
    assert k == len(answers["ray"]) and answers["overflow"].any()


def test_camera_pixels_match_the_cli(cli, dem, tmp_path):
    camera = {"perspective": {"eye": [518775, 4030000, 4000], "target": [518775, 4037310, 300],
                              "up": [0, 0, 1], "fov_y_deg": 40, "width": 64, "height": 48}}
    (tmp_path / "view.json").write_text(json.dumps(camera))
    pixels = np.array([[x, y] for y in range(0, 48, 3) for x in range(0, 64, 3)] + [[10.25, 3.5]])
    write_numbers(tmp_path / "pixels.txt", pixels)
    rows = run_cli(cli, "pick", "-q", "--scene", DEM, "--camera", tmp_path / "view.json",
                   "--pixels", tmp_path / "pixels.txt")
    answers = dem.pick(raypick.camera_rays(camera, pixels))
    assert len(rows) == len(pixels) and answers["hit"].sum() > len(pixels) / 2
    for i, row in enumerate(rows):
        expect_row(row, answers, i, cells=True)


def test_los_and_viewshed_match_the_cli(cli, dem, tmp_path):
    lo, hi = dem.bounds
    rng = np.random.default_rng(3)
    a = lo + (hi - lo) * rng.random((2000, 3))
    b = lo + (hi - lo) * rng.random((2000, 3))
    write_numbers(tmp_path / "pairs.txt", np.hstack([a, b]))
    rows = run_cli(cli, "los", "--scene", DEM, "--pairs", tmp_path / "pairs.txt")
    seen = dem.los(a, b)
    assert [r["visible"] == "1" for r in rows] == list(seen)
    assert 0 < seen.sum() < len(seen)

    observer = [517000.5, 4035000.25, 900.0]
    rows = run_cli(cli, "viewshed", "--scene", DEM, "--observer", *observer, "--target-height", 2)
    shed = dem.viewshed(observer, target_height=2.0)
    assert len(rows) == len(shed["visible"])
    assert [r["visible"] == "1" for r in rows] == list(shed["visible"])
    assert [int(r["row"]) for r in rows] == list(shed["row"])
    assert [int(r["col"]) for r in rows] == list(shed["col"])
    assert [float(r["z"]) for r in rows] == list(shed["position"][:, 2])


def test_a_description_listing_a_file_twice_is_picked_as_the_clis_instances(cli, tmp_path):
    """A description listing the bunny twice, the second 10⁶ out: the CLI's `pick` builds the
    bunny once and places it twice; Python did too little of that (it baked copies into one
    frame 10⁶ wide, warned that 3,046 triangles were too small for it, and 48 of 2,000 rays
    differed). Now every column of every ray is the CLI's, the objects are the listings, and
    `los` answers as the CLI's `los` (which picks the copies, as Python's does)."""
    (tmp_path / "bunny.obj").write_bytes(BUNNY.read_bytes())
    desc = tmp_path / "far.json"
    desc.write_text(json.dumps({"objects": [
        {"file": "bunny.obj"},
        {"file": "bunny.obj", "transform": [[1, 0, 0, 1e6], [0, 1, 0, 0], [0, 0, 1, 0]]},
    ]}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = raypick.Scene.load(desc)
    near = rays_at(raypick.Scene.load(BUNNY), 1000, spread=0.1)
    far = near.copy()
    far[:, 0] += 1e6
    rays = np.vstack([near, far])
    write_numbers(tmp_path / "rays.txt", rays)
    rows = run_cli(cli, "pick", "-q", "--backend", "cpu", "--scenes", desc,
                   "--rays", tmp_path / "rays.txt")
    answers = scene.pick(rays, backend="cpu")
    assert answers["hit"][:1000].sum() > 300
    assert answers["hit"][1000:].sum() == answers["hit"][:1000].sum()
    for i, row in enumerate(rows):
        expect_row(row, answers, i, cells=False)
    assert [o["name"] for o in scene.objects] == [str(tmp_path / "bunny.obj")] * 2
    assert scene.triangle_count == 2 * 3674
    lo, hi = scene.bounds
    assert lo[0] < 0 < 1e6 < hi[0]
    a, b = near[:300, :3], near[:300, :3] + 20 * near[:300, 3:]
    a, b = np.vstack([a, a + [1e6, 0, 0]]), np.vstack([b, b + [1e6, 0, 0]])
    write_numbers(tmp_path / "pairs.txt", np.hstack([a, b]))
    rows = run_cli(cli, "los", "--scenes", desc, "--pairs", tmp_path / "pairs.txt")
    # The copies' frame, 10⁶ wide, is warned about as the CLI's `los` warns about it (once).
    with pytest.warns(UserWarning, match="too small for where they lie"):
        seen = scene.los(a, b)
    assert [r["visible"] == "1" for r in rows] == list(seen)
    assert 0 < seen.sum() < len(seen)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert (scene.los(a, b) == seen).all()


def test_the_copies_for_los_are_checked_against_the_memory_budget(tmp_path):
    """`los` on a scene of instances bakes every instance's triangles: checked before they are
    made (400 bunnies, 1.5M triangles, under a 64 MiB budget), not allocated and then refused."""
    (tmp_path / "bunny.obj").write_bytes(BUNNY.read_bytes())
    desc = tmp_path / "many.json"
    desc.write_text(json.dumps({"objects": [
        {"file": "bunny.obj", "transform": [[1, 0, 0, 20 * k], [0, 1, 0, 0], [0, 0, 1, 0]]}
        for k in range(400)
    ]}))
    default = raypick.max_memory()
    raypick.set_max_memory("64M")
    try:
        scene = raypick.Scene.load(desc)
        assert len(scene.objects) == 400
        with pytest.raises(ValueError, match="baking the instances into copies for los"):
            scene.los([0, 50, 0], [0, -50, 0])
    finally:
        raypick.set_max_memory(default)


def test_a_saved_instanced_scene_loads_as_its_description(cli, tmp_path):
    """`raypick build` saves a description listing a file twice as instances; Python loads that
    `.rpk` as the description loads: the same objects, the same answers to the bit."""
    (tmp_path / "bunny.obj").write_bytes(BUNNY.read_bytes())
    desc = tmp_path / "twice.json"
    desc.write_text(json.dumps({"objects": [
        {"file": "bunny.obj"},
        {"file": "bunny.obj", "mask": 2,
         "transform": [[0, -2, 0, 0.5], [2, 0, 0, 0], [0, 0, 0.5, 0.1]]},
    ]}))
    done = subprocess.run([cli, "build", "--scenes", str(desc), "--out", str(tmp_path / "i.rpk")],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "instances of 1 mesh" in done.stderr
    want = raypick.Scene.load(desc)
    got = raypick.Scene.load(tmp_path / "i.rpk")
    assert got.objects == want.objects
    assert got.triangle_count == want.triangle_count
    rays = rays_at(want, 3000, spread=0.2)
    expected, answers = want.pick(rays), got.pick(rays)
    assert answers["hit"].any()
    for key in expected:
        assert np.array_equal(expected[key], answers[key], equal_nan=True), key


def test_a_grid_listed_twice_with_the_grid_builder(cli, tmp_path):
    """The DEM listed twice with builder="grid": the CLI's `pick` builds one grid tree and
    places it twice; Python refused ("2 objects"). Now the same answers, cells included, and
    `los` answers on the copies (each builder gives the same answers)."""
    scene = raypick.Scene.load([DEM, DEM], builder="grid")
    assert [o["grid"] for o in scene.objects] == [(344, 403)] * 2
    rays = rays_at(scene, 2000, spread=0.1)
    write_numbers(tmp_path / "rays.txt", rays)
    rows = run_cli(cli, "pick", "-q", "--backend", "cpu", "--builder", "grid", "--scene", DEM,
                   "--scene", DEM, "--rays", tmp_path / "rays.txt")
    answers = scene.pick(rays, backend="cpu")
    assert answers["hit"].mean() > 0.9
    for i, row in enumerate(rows):
        expect_row(row, answers, i, cells=True)
    a, b = rays[:500, :3], rays[:500, :3] + 5000 * rays[:500, 3:]
    want = raypick.Scene.load([DEM, DEM]).los(a, b)
    assert (scene.los(a, b) == want).all() and 0 < want.sum() < len(want)
