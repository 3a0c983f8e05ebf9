"""The Python API: loading, picking in every mode, the columns and their miss values, the ray
forms, the backends, masks, culling, ranges, .rpk round trips, cameras, line of sight,
viewsheds, threads and the GIL."""

import json
import os
import shutil
import signal
import threading
import time
import warnings

import numpy as np
import pytest

import raypick
from conftest import BUNNY, DATA, DEM, assert_same_answers, incoherent_rays, rays_at, same_bits

CLOSEST_KEYS = ["hit", "t", "object", "triangle", "u", "v", "position", "normal", "invalid"]
GRID_KEYS = ["hit", "t", "object", "triangle", "u", "v", "position", "normal", "row", "col", "invalid"]
ALL_KEYS = ["hit", "invalid", "overflow", "offsets", "ray", "rank", "t", "object", "triangle",
            "u", "v", "position", "normal"]


def read_obj(path):
    vertices, triangles = [], []
    for line in open(path):
        parts = line.split()
        if parts[:1] == ["v"]:
            vertices.append([float(x) for x in parts[1:4]])
        elif parts[:1] == ["f"]:
            triangles.append([int(x.split("/")[0]) - 1 for x in parts[1:4]])
    return np.array(vertices), np.array(triangles)


def test_load_reads_the_clis_formats(bunny, dem):
    assert bunny.triangle_count == 3674
    assert bunny.objects == [{"id": 0, "name": str(BUNNY), "triangles": 3674,
                              "mask": 0xFFFFFFFF, "grid": None}]
    assert dem.objects[0]["grid"] == (344, 403)
    assert "1 object" in repr(dem)
    for name in ["jacksboro_fault_dem_utm_int16.tif", "jacksboro_fault_dem_utm_f32_deflate.tif"]:
        tif = raypick.Scene.load(DATA / name)
        assert tif.objects[0]["grid"] == (344, 403)
        assert tif.triangle_count == dem.triangle_count
    # quad.ply's third face has two vertices: said as a UserWarning naming the file.
    with pytest.warns(UserWarning, match=r"quad\.ply: 1 face\(s\) with fewer than 3 vertices"):
        both = raypick.Scene.load([DATA / "formats" / "quad.ply", str(DATA / "formats" / "tetra.stl")])
    assert [o["id"] for o in both.objects] == [0, 1]
    lo, hi = bunny.bounds
    assert lo.dtype == np.float64 and (lo < hi).all()


def test_closest_columns_dtypes_and_misses(bunny):
    rays = rays_at(bunny, 5000)
    hits = bunny.pick(rays)
    assert list(hits) == CLOSEST_KEYS
    n = len(rays)
    for key, dtype, shape in [("hit", bool, (n,)), ("t", np.float64, (n,)),
                              ("object", np.int64, (n,)), ("triangle", np.int64, (n,)),
                              ("u", np.float64, (n,)), ("v", np.float64, (n,)),
                              ("position", np.float64, (n, 3)), ("normal", np.float64, (n, 3)),
                              ("invalid", bool, (n,))]:
        assert hits[key].dtype == dtype and hits[key].shape == shape, key
    hit = hits["hit"]
    assert 0 < hit.sum() < n
    miss = ~hit
    for key in ["t", "u", "v", "position", "normal"]:
        assert np.isnan(hits[key][miss]).all() and np.isfinite(hits[key][hit]).all(), key
    for key in ["object", "triangle"]:
        assert (hits[key][miss] == -1).all() and (hits[key][hit] >= 0).all(), key
    assert (hits["triangle"][hit] < 3674).all()
    expected = rays[hit, :3] + hits["t"][hit, None] * rays[hit, 3:]
    assert np.allclose(hits["position"][hit], expected, atol=1e-9)
    assert np.allclose(np.linalg.norm(hits["normal"][hit], axis=1), 1.0)
    assert not hits["invalid"].any()


def test_grid_scenes_add_row_and_col(dem):
    rays = rays_at(dem, 3000, spread=0.05)
    hits = dem.pick(rays)
    assert list(hits) == GRID_KEYS
    hit = hits["hit"]
    assert hit.mean() > 0.9
    k = hits["triangle"][hit] // 2
    assert (hits["row"][hit] == k // 402).all() and (hits["col"][hit] == k % 402).all()
    assert (hits["row"][~hit] == -1).all() and (hits["col"][~hit] == -1).all()
    miss = dem.pick(np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 1.0]]))
    assert miss["row"][0] == -1 and miss["col"][0] == -1


def test_from_arrays_answers_as_the_loaded_file(bunny):
    vertices, triangles = read_obj(BUNNY)
    rays = rays_at(bunny, 4000)
    expected = bunny.pick(rays)
    for tri in [triangles, triangles.astype(np.int32), triangles.astype(np.uint32),
                triangles.astype(np.uint64)]:
        scene = raypick.Scene.from_arrays(vertices, tri)
        assert scene.objects[0]["name"] == "arrays"
        assert_same_answers(expected, scene.pick(rays))
    sah = raypick.Scene.from_arrays(vertices, triangles, builder="sah", leaf_size=4)
    assert_same_answers(expected, sah.pick(rays))


def test_rays_as_tuple_list_and_strided_arrays(bunny):
    rays = rays_at(bunny, 2000)
    expected = bunny.pick(rays)
    assert_same_answers(expected, bunny.pick((rays[:, :3].copy(), rays[:, 3:].copy())))
    assert_same_answers(expected, bunny.pick((rays[:, :3], rays[:, 3:])))
    assert_same_answers(expected, bunny.pick(np.asfortranarray(rays)))
    wide = np.zeros((len(rays), 12))
    wide[:, ::2] = rays
    assert_same_answers(expected, bunny.pick(wide[:, ::2]))
    assert_same_answers(bunny.pick(rays[:3]), bunny.pick(rays[:3].tolist()))
    empty = bunny.pick(np.empty((0, 6)))
    assert list(empty) == CLOSEST_KEYS and empty["position"].shape == (0, 3)


def test_any_and_all_agree_with_closest(bunny):
    rays = np.vstack([rays_at(bunny, 3000), incoherent_rays(bunny, 3000)])
    closest = bunny.pick(rays)
    anyhit = bunny.pick(rays, mode="any")
    assert list(anyhit) == ["hit", "invalid"]
    assert same_bits(anyhit["hit"], closest["hit"])
    every = bunny.pick(rays, mode="all", max_hits=64)
    assert list(every) == ALL_KEYS
    offsets = every["offsets"]
    assert offsets.shape == (len(rays) + 1,) and offsets[0] == 0
    assert (np.diff(offsets) >= 0).all() and offsets[-1] == len(every["ray"])
    assert same_bits(every["hit"], closest["hit"])
    assert not every["overflow"].any()
    firsts = offsets[:-1][closest["hit"]]
    assert (every["ray"][firsts] == np.flatnonzero(closest["hit"])).all()
    assert (every["rank"][firsts] == 0).all()
    for key in ["t", "object", "triangle", "u", "v", "position", "normal"]:
        assert same_bits(every[key][firsts], closest[key][closest["hit"]]), key
    ranks = np.arange(len(every["ray"])) - offsets[every["ray"]]
    assert (every["rank"] == ranks).all()
    t, ray = every["t"], every["ray"]
    assert ((t[1:] >= t[:-1]) | (ray[1:] != ray[:-1])).all()
    one = bunny.pick(rays, mode="all", max_hits=1)
    assert (one["overflow"] == (np.diff(offsets) > 1)).all()
    assert (np.diff(one["offsets"]) == closest["hit"]).all()


def test_backends_give_the_same_bits(bunny):
    rays = np.vstack([rays_at(bunny, 2000), incoherent_rays(bunny, 2000)])
    expected = bunny.pick(rays, backend="cpu")
    for backend in ["auto", "reference", "CPU"]:
        assert_same_answers(expected, bunny.pick(rays, backend=backend))
    try:
        gpu = bunny.pick(rays, backend="gpu")
    except ValueError as e:
        pytest.skip(f"no GPU adapter here: {e}")
    assert_same_answers(expected, gpu)


def test_masks_ray_masks_and_invalid_rays():
    scene = raypick.Scene.load([str(BUNNY), str(BUNNY)], masks=[1, None])
    assert [o["mask"] for o in scene.objects] == [1, 0xFFFFFFFF]
    rays = rays_at(scene, 2000)
    both = scene.pick(rays)
    assert (both["object"][both["hit"]] == 0).all()  # equal t: the lower id wins
    second = scene.pick(rays, ray_mask=2)
    assert (second["object"][second["hit"]] == 1).all()
    assert same_bits(second["t"], both["t"])
    none = scene.pick(rays, ray_mask=0)
    assert not none["hit"].any() and not none["invalid"].any()
    bad = rays[:4].copy()
    bad[0, 0] = np.nan
    bad[1, 3:] = 0.0
    bad[2, 5] = np.inf
    answers = scene.pick(bad)
    assert list(answers["invalid"]) == [True, True, True, False]
    assert not answers["hit"][:3].any()
    single = raypick.Scene.load(BUNNY, masks=4)
    assert single.objects[0]["mask"] == 4


def test_cull_and_range(bunny):
    rays = np.vstack([rays_at(bunny, 3000), incoherent_rays(bunny, 3000)])
    none = bunny.pick(rays)
    back = bunny.pick(rays, cull="back")
    front = bunny.pick(rays, cull="front")
    for culled in [back, front]:
        assert culled["hit"].sum() <= none["hit"].sum()
        assert (culled["t"][culled["hit"]] >= none["t"][culled["hit"]]).all()
    # Rays from outside meet front faces first: culling them finds the far side.
    assert (front["t"][front["hit"]] > none["t"][front["hit"]]).any()
    # The nearest of the two culled answers is the unculled one.
    nearest = np.fmin(back["t"], front["t"])
    assert same_bits(nearest[none["hit"]], none["t"][none["hit"]])
    assert not bunny.pick(rays, tmax=1e-9)["hit"].any()
    cut = np.nanmedian(none["t"])
    beyond = bunny.pick(rays, tmin=cut)
    assert (beyond["t"][beyond["hit"]] > cut).all()
    kept = none["t"] > cut
    assert same_bits(beyond["t"][kept], none["t"][kept])
    short = bunny.pick(rays, tmax=cut)
    assert same_bits(short["hit"], none["hit"] & (none["t"] <= cut))
    mt = bunny.pick(rays, intersector="moller-trumbore")
    assert np.allclose(mt["t"], none["t"], equal_nan=True)


def test_rpk_round_trip_and_descriptions(bunny, dem, tmp_path):
    rays = rays_at(dem, 2000, spread=0.05)
    dem.save(tmp_path / "dem.rpk")
    loaded = raypick.Scene.load(tmp_path / "dem.rpk")
    assert loaded.objects[0]["grid"] == (344, 403)
    assert_same_answers(dem.pick(rays), loaded.pick(rays))
    shutil.copy(BUNNY, tmp_path / "bunny.obj")
    (tmp_path / "scene.json").write_text(
        json.dumps({"objects": [{"file": "bunny.obj", "mask": 2}, {"file": "bunny.obj"}]}))
    described = raypick.Scene.load(str(tmp_path / "scene.json"))
    assert [o["mask"] for o in described.objects] == [2, 0xFFFFFFFF]
    rays = rays_at(bunny, 1000)
    assert same_bits(described.pick(rays, ray_mask=2)["t"], bunny.pick(rays)["t"])


def test_camera_rays():
    camera = json.loads((DATA.parent.parent / "docs" / "bunny_camera.json").read_text())
    every = raypick.camera_rays(camera)
    assert every.shape == (480 * 360, 6) and every.dtype == np.float64
    assert np.allclose(every[:, :3], [5.5, 8.5, 18.5])
    assert np.allclose(np.linalg.norm(every[:, 3:], axis=1), 1.0)
    pixels = np.array([[0, 0], [479, 359], [240, 180]])
    some = raypick.camera_rays(camera, pixels)
    assert same_bits(some, every[pixels[:, 1] * 480 + pixels[:, 0]])
    assert same_bits(raypick.camera_rays(json.dumps(camera), pixels.astype(np.float32)), some)
    assert same_bits(raypick.camera_rays(camera, pixels.tolist()), some)
    ortho = {"orthographic": {"eye": [0, 0, 10], "target": [0, 0, 0], "up": [0, 1, 0],
                              "view_height": 2, "width": 2, "height": 2}}
    rays = raypick.camera_rays(ortho)
    assert np.allclose(rays[:, 3:], [0, 0, -1]) and np.allclose(rays[:, 2], 10)
    assert np.allclose(np.abs(rays[:, :2]), 0.5)


def test_line_of_sight(bunny):
    lo, hi = bunny.bounds
    centre = (lo + hi) / 2
    above, below = centre + [0, 0, 10], centre - [0, 0, 10]
    beside = centre + [20, 0, 0]
    seen = bunny.los(np.array([above, above]), np.array([below, beside + [0, 0, 10]]))
    assert seen.dtype == bool and list(seen) == [False, True]
    assert list(bunny.los(above, [below, beside])) == [False, True]
    assert list(bunny.los([below, beside], above)) == [False, True]
    rays = rays_at(bunny, 2000)
    hits = bunny.pick(rays)
    # From each ray's origin to just short of its hit: nothing in between.
    ends = rays[:, :3] + (hits["t"] * 0.999)[:, None] * rays[:, 3:]
    h = hits["hit"]
    assert bunny.los(rays[h, :3], ends[h]).all()
    past = rays[:, :3] + (hits["t"] * 1.001)[:, None] * rays[:, 3:]
    assert not bunny.los(rays[h, :3], past[h]).any()
    with pytest.warns(RuntimeWarning, match="1 pair"):
        assert list(bunny.los([above, above], [above, below])) == [False, False]


def test_viewshed(dem):
    lo, hi = dem.bounds
    observer = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2] + 50]
    grid = dem.viewshed(observer)
    assert list(grid) == ["position", "object", "row", "col", "visible"]
    n = 344 * 403
    assert grid["position"].shape == (n, 3) and grid["visible"].shape == (n,)
    assert 0 < grid["visible"].sum() < n
    assert grid["row"].max() == 343 and grid["col"].max() == 402 and (grid["object"] == 0).all()
    lifted = dem.viewshed(observer, target_height=100.0)
    assert lifted["visible"].sum() > grid["visible"].sum()
    assert np.allclose(lifted["position"][:, 2], grid["position"][:, 2] + 100.0)
    some = grid["position"][:1000]
    given = dem.viewshed(observer, some)
    assert same_bits(given["visible"], grid["visible"][:1000])
    assert (given["row"] == -1).all() and (given["object"] == -1).all()
    assert same_bits(given["visible"], dem.los(np.array(observer, dtype=float), some))


def test_the_ends_own_surfaces_never_block_a_sight_line(tmp_path):
    """A target on the ground, in a frame rounding coarser than ε of the segment, was hidden by
    its own triangle (the traversal's f32 t fell inside (ε, 1 − ε)); judged now in f64, as the
    CLI does. Only the cell behind the spike's slope is hidden."""
    grid = tmp_path / "spike.asc"
    grid.write_text("ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 30\n500 0 0\n0 2 3\n0 4 0\n")
    scene = raypick.Scene.load(str(grid))
    seen = scene.viewshed([45.0, 45.0, 3.7])
    assert "".join(str(int(v)) for v in seen["visible"]) == "111111011"
    # An observer on the ground: its own surface at t = 0 is looked past.
    flat = tmp_path / "flat.asc"
    flat.write_text("ncols 4\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 10\n0 0 0 0\n0 0 9 0\n0 0 0 0\n")
    ground = raypick.Scene.load(str(flat))
    a = np.array([[5.0, 15, 0], [5, 15, 0]])
    b = np.array([[15.0, 15, 0.5], [35, 15, 0]])
    assert list(ground.los(a, b)) == [True, False]


def test_threads_and_the_gil(bunny):
    rays = incoherent_rays(bunny, 400_000)
    expected = bunny.pick(rays)
    try:
        raypick._set_threads(1)
        assert raypick._threads() == 1
        assert_same_answers(expected, bunny.pick(rays))
    finally:
        raypick._set_threads(0)
    assert raypick._threads() >= 1

    # While one thread traces, this one keeps running Python code: the GIL is released.
    done = threading.Event()
    result = {}

    def work():
        result["answers"] = bunny.pick(rays, backend="cpu")
        done.set()

    worker = threading.Thread(target=work)
    ticks, start = 0, time.perf_counter()
    worker.start()
    while not done.is_set():
        ticks += 1
    worker.join()
    elapsed = time.perf_counter() - start
    assert_same_answers(expected, result["answers"])
    assert elapsed < 0.01 or ticks > 1000, (ticks, elapsed)


def test_picks_raise_no_python_warnings(bunny):
    # The automatic backend's notes (no GPU, a software GPU) go to logging, once a process.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bunny.pick(rays_at(bunny, 10))


def test_batches_join_seamlessly(bunny):
    """A large pick is answered in batches (conversion, trace and columns per batch); the
    answers are those of the same rays picked in pieces cut elsewhere."""
    rays = np.vstack([rays_at(bunny, 200_000), incoherent_rays(bunny, 150_001)])
    pieces = [rays[:1], rays[1:100_000], rays[100_000:300_000], rays[300_000:]]
    for mode in ["closest", "any"]:
        whole = bunny.pick(rays, mode=mode)
        parts = [bunny.pick(p, mode=mode) for p in pieces]
        for key in whole:
            assert same_bits(whole[key], np.concatenate([p[key] for p in parts])), (mode, key)
    whole = bunny.pick(rays, mode="all", max_hits=2)
    joined = joined_lists([bunny.pick(p, mode="all", max_hits=2) for p in pieces])
    for key in whole:
        assert same_bits(whole[key], joined[key]), key


def test_unaligned_and_read_only_arrays(bunny):
    rays = rays_at(bunny, 1000)
    expected = bunny.pick(rays)
    raw = np.zeros(rays.nbytes + 1, dtype=np.uint8)
    unaligned = raw[1:].view(np.float64).reshape(rays.shape)
    unaligned[:] = rays
    assert not unaligned.flags.aligned
    assert_same_answers(expected, bunny.pick(unaligned))
    frozen = rays.copy()
    frozen.flags.writeable = False
    assert_same_answers(expected, bunny.pick(frozen))


def joined_lists(parts):
    """The all-hits answers of pieces of rays, joined as one pick's."""
    starts = np.cumsum([0] + [len(p["hit"]) for p in parts])
    hit_starts = np.cumsum([0] + [len(p["ray"]) for p in parts])
    joined = {
        key: np.concatenate([p[key] for p in parts])
        for key in parts[0] if key not in ("offsets", "ray")
    }
    joined["ray"] = np.concatenate([p["ray"] + s for p, s in zip(parts, starts)])
    joined["offsets"] = np.concatenate(
        [[0]] + [p["offsets"][1:] + h for p, h in zip(parts, hit_starts)])
    return joined


def stacked_scene(layers):
    """`layers` copies of the triangle (0, 0), (1, 0), (0, 1), stacked from z = 0 to 1: a ray
    down through the square's other half enters every box of the tree and passes beside every
    triangle, so it costs a test of each (80 µs with 20,000 layers on two cores)."""
    corners = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    vertices = np.tile(corners, (layers, 1))
    vertices[:, 2] = np.repeat(np.arange(layers) / layers, 3)
    return raypick.Scene.from_arrays(vertices, np.arange(3 * layers).reshape(layers, 3))


def beside_rays(n, seed=1, hits=0.0):
    """`n` rays down beside the stack (x + y > 1.1), a share `hits` of them onto its top."""
    rng = np.random.default_rng(seed)
    xy = 0.55 + 0.4 * rng.random((n, 2))
    onto = rng.random(n) < hits
    xy[onto] = 0.45 * rng.random((onto.sum(), 2))
    return np.hstack([xy, np.full((n, 1), 2.0), np.tile([0.0, 0, -1], (n, 1))])


def test_costly_rays_answer_as_pieces():
    """Batches are sized by the time their rays take (a first batch of 4,096 rays, then about
    0.1 s each): on costly rays they are cut at other places than on cheap ones, and the
    answers are still those of the same rays picked in pieces."""
    stack = stacked_scene(2000)
    rays = beside_rays(40_000, hits=0.3)
    pieces = np.array_split(rays, 41)
    whole = stack.pick(rays)
    assert 0 < whole["hit"].sum() < len(rays)
    parts = [stack.pick(p) for p in pieces]
    for key in whole:
        assert same_bits(whole[key], np.concatenate([p[key] for p in parts])), key
    whole = stack.pick(rays, mode="all", max_hits=3)
    assert whole["overflow"].any()
    joined = joined_lists([stack.pick(p, mode="all", max_hits=3) for p in pieces])
    for key in whole:
        assert same_bits(whole[key], joined[key]), key


@pytest.fixture(scope="module")
def stack():
    return stacked_scene(20_000)


@pytest.mark.parametrize("query", ["pick", "los"])
@pytest.mark.parametrize("delay", [0.05, 0.5])
def test_ctrl_c_stops_a_long_pick(stack, query, delay):
    """Tracing ran to its end without the interpreter, so Ctrl-C (SIGINT) waited for the whole
    pick: minutes for a large one. Between batches the pick runs Python's signal handlers, so
    the KeyboardInterrupt comes within a batch's time (about 0.1 s after a first batch of
    0.3 s here) of the signal, whether it comes during the first batch or a later one."""

    def run(rays):
        if query == "pick":
            return stack.pick(rays)
        return stack.los(rays[:, :3], rays[:, :3] - [0, 0, 3.0])

    run(beside_rays(10))
    sample = beside_rays(1000)
    start = time.perf_counter()
    run(sample)
    per_ray = (time.perf_counter() - start) / len(sample)
    rays = beside_rays(int(min(2_000_000, 30 / per_ray)))
    whole = per_ray * len(rays)
    assert whole > 15, f"the whole pick would take only {whole:.1f} s"

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(delay, os.kill, (os.getpid(), signal.SIGINT))
    try:
        start = time.perf_counter()
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            run(rays)
            time.sleep(1)  # a signal that the pick took for nothing would be raised here
        stopped = time.perf_counter() - start
    finally:
        timer.cancel()
        timer.join()
        signal.signal(signal.SIGINT, previous)
    assert stopped < delay + 2.0, f"stopped after {stopped:.1f} s of a {whole:.0f} s pick"


def test_a_signal_handler_may_pick_during_a_gpu_pick(stack):
    """Between batches a pick runs Python's signal handlers; a handler that picked on the same
    scene with the GPU (or automatic) backend waited for the GPU picker the interrupted pick
    held, for ever. It is answered on the CPU engine instead: the same answers."""
    import faulthandler

    few = beside_rays(50)
    want = stack.pick(few, backend="cpu")
    stack.pick(few, backend="gpu")
    start = time.perf_counter()
    stack.pick(beside_rays(1000), backend="gpu")
    per_ray = (time.perf_counter() - start) / 1000
    # A pick of about 3 s, the signal 0.3 s into it.
    rays = np.vstack([few, beside_rays(int(3.0 / per_ray))])
    got = []

    def handler(signum, frame):
        got.append((stack.pick(few, backend="gpu"), time.perf_counter()))

    previous = signal.signal(signal.SIGUSR1, handler)
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGUSR1))
    # A deadlock would hang the test run: end the process instead, with the threads' stacks.
    faulthandler.dump_traceback_later(120, exit=True)
    try:
        timer.start()
        whole = stack.pick(rays, backend="gpu")
        ended = time.perf_counter()
    finally:
        faulthandler.cancel_dump_traceback_later()
        timer.cancel()
        timer.join()
        signal.signal(signal.SIGUSR1, previous)
    assert len(got) == 1 and got[0][1] < ended, "the handler ran during the pick"
    for key in want:
        assert same_bits(got[0][0][key], want[key]), key
    assert same_bits(whole["triangle"][:50], want["triangle"])
