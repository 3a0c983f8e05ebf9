"""raypick.dask on a LocalCluster of two worker processes (loopback): the answers are
Scene.pick's in one process, bit for bit, for 1M rays; each worker process loads a scene once
and traces on its own thread."""

import logging

import dask
import dask.array as da
import numpy as np
import pytest
from distributed import Client, LocalCluster

import raypick
import raypick.dask
from conftest import BUNNY, DEM, assert_same_answers


@pytest.fixture(scope="module")
def client():
    with LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=logging.ERROR,
    ) as cluster, Client(cluster) as client:
        yield client


def dask_rays(scene, n, chunk, seed=42, spread=0.05, above=100.0):
    """`n` rays from above the scene aimed down, made on the workers, seeded per chunk."""
    lo, hi = scene.bounds
    rng = da.random.default_rng(seed)
    origins = lo + (hi - lo) * rng.random((n, 3), chunks=(chunk, 3))
    origins = da.concatenate(
        [origins[:, :2], da.full((n, 1), hi[2] + above, chunks=(chunk, 1))], axis=1)
    dirs = rng.normal(scale=spread, size=(n, 3), chunks=(chunk, 3)) + np.array([0, 0, -1.0])
    return da.concatenate([origins, dirs], axis=1)


def test_a_million_rays_are_the_same_as_in_one_process(client, dem):
    rays = dask_rays(dem, 1_000_000, 125_000)
    answers = raypick.dask.pick(str(DEM), rays)
    assert list(answers) == list(dem.pick(np.empty((0, 6))))
    assert all(isinstance(a, da.Array) for a in answers.values())
    rays, got = dask.compute(rays, answers)
    assert rays.shape == (1_000_000, 6)
    expected = dem.pick(rays)
    assert expected["hit"].mean() > 0.9
    assert_same_answers(expected, got)
    # Every worker process loaded the DEM once at most, and traced on its one thread.
    loads = client.run(lambda: dict(raypick.dask._LOADS))
    assert all(count == 1 for counts in loads.values() for count in counts.values()), loads
    assert set(client.run(raypick._threads).values()) == {1}


def test_all_hits_and_any_hit(client, bunny):
    rays = dask_rays(bunny, 60_000, 7_000, seed=5, spread=0.3, above=1.0)
    every = raypick.dask.pick([BUNNY], rays, mode="all", max_hits=3)
    anyhit = raypick.dask.pick(BUNNY, rays, mode="any", backend="cpu")
    rays, every, anyhit = dask.compute(rays, every, anyhit)
    assert_same_answers(bunny.pick(rays, mode="all", max_hits=3), every)
    assert every["overflow"].any() and len(every["ray"]) > len(rays)
    assert_same_answers(bunny.pick(rays, mode="any"), anyhit)


def test_masks_and_builder_reach_the_workers(client):
    scene = raypick.Scene.load([str(BUNNY), str(BUNNY)], masks=[1, 2], builder="sah")
    rays = dask_rays(scene, 20_000, 5_000, seed=9, spread=0.3, above=1.0)
    answers = raypick.dask.pick([BUNNY, BUNNY], rays, masks=[1, 2], builder="sah", ray_mask=2)
    rays, got = dask.compute(rays, answers)
    expected = scene.pick(rays, ray_mask=2)
    assert_same_answers(expected, got)
    assert got["hit"].mean() > 0.3 and (got["object"][got["hit"]] == 1).all()


def test_threads_scheduler_without_a_cluster(bunny):
    rays = np.random.default_rng(4).normal(size=(10_000, 6))
    rays[:, 2] += 20
    answers = raypick.dask.pick(BUNNY, da.from_array(rays, chunks=(3_000, 6)))
    got, = dask.compute(answers, scheduler="threads")
    assert_same_answers(bunny.pick(rays), got)


def test_rays_filtered_into_empty_chunks(bunny):
    """Rays filtered by a mask leave empty chunks: mode all failed in dask's cumsum of the
    hit counts when one came before the last (`operands could not be broadcast`)."""
    rays = np.random.default_rng(6).normal(size=(9_000, 6))
    rays[:, 2] += 20
    rays[:3_000, 5] = 1.0  # the first chunk's rays all point up: filtered out below
    x = da.from_array(rays, chunks=(3_000, 6))
    down = x[x[:, 5] < 0].compute_chunk_sizes()
    assert down.chunks[0][0] == 0
    kept, = dask.compute(down, scheduler="threads")
    for mode in ["all", "closest"]:
        got, = dask.compute(raypick.dask.pick(BUNNY, down, mode=mode), scheduler="threads")
        assert_same_answers(bunny.pick(kept, mode=mode), got)
    nothing = x[x[:, 0] > 1e9].compute_chunk_sizes()
    got, = dask.compute(raypick.dask.pick(BUNNY, nothing, mode="all"), scheduler="threads")
    assert list(got["offsets"]) == [0] and len(got["ray"]) == 0


def test_refusals(client, bunny):
    rays = da.zeros((10, 6), chunks=(5, 6))
    with pytest.raises(ValueError, match="needs the scene's path"):
        raypick.dask.pick(bunny, rays)
    with pytest.raises(ValueError, match="must be a dask array"):
        raypick.dask.pick(BUNNY, np.zeros((10, 6)))
    with pytest.raises(ValueError, match="must be float64"):
        raypick.dask.pick(BUNNY, rays.astype(np.float32))
    with pytest.raises(ValueError, match=r"shape \(N, 6\)"):
        raypick.dask.pick(BUNNY, da.zeros((10, 3), chunks=(5, 3)))
    with pytest.raises(ValueError, match="mode: unknown value nearest"):
        raypick.dask.pick(BUNNY, rays, mode="nearest")
    with pytest.raises(FileNotFoundError):
        raypick.dask.pick("no/such/scene.obj", rays)
