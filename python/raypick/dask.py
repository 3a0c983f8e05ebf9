"""raypick on Dask: ``raypick.dask.pick(scene, rays, **query)``.

``scene`` is a path or a list of paths (what ``raypick.Scene.load`` reads, an ``.rpk`` included)
and ``rays`` a dask array (N, 6) float64 chunked by rows. The answer is a dict of dask arrays with
the keys ``Scene.pick`` gives for the same query. Nothing is computed until you ask::

    import dask, dask.array as da, raypick.dask
    from distributed import Client

    client = Client("tcp://scheduler:8786")        # or Client(LocalCluster(...)), SSHCluster, KubeCluster
    rays = da.from_array(numpy_rays, chunks=(1_000_000, 6))
    hits = raypick.dask.pick("/data/city.rpk", rays, mode="closest")
    hit, position = dask.compute(hits["hit"], hits["position"])

How it runs:

- One task per chunk of rays (and one per answer key and chunk to hand its array out), so
  chunks of about 1M rays keep the scheduler's share small: with 250k-ray chunks it was
  noticeable next to the picks (BENCHMARKS.md).
- Each worker process loads the scene the first time one of its tasks needs it and keeps it (a
  few scenes at most, the most recently used), so every worker process loads a scene once,
  however many chunks it answers. (A worker that holds a scene does not read its files again:
  give a changed file a new name.)
- The paths must name the same files on every worker: a shared file system, or the same files
  copied to the same place. Relative paths are made absolute here, on the client. Save a large
  scene once with ``scene.save("city.rpk")`` and give the ``.rpk``: workers then map it instead
  of parsing and building it.
- A worker process traces its tasks with as many threads as it has Dask threads
  (``dask worker --nthreads``), so several worker processes on one machine share its cores
  instead of each taking them all.
- Keys and dtypes come from one tiny task run before the graph is built (it also loads the scene
  on one worker and checks the query's arguments, so a bad argument fails here, not at compute).
- ``mode="all"``: ``offsets`` is the running sum of the hits per ray across chunks; the per-hit
  arrays have unknown chunk sizes until computed (``.compute_chunk_sizes()`` finds them).

Extra keyword arguments ``masks``, ``builder`` and ``leaf_size`` are passed to
``Scene.load`` on the workers (``builder`` and ``leaf_size`` only when given: a saved ``.rpk``
refuses them); all others to ``Scene.pick``.
"""

import operator
import os
import threading
import uuid
from collections import Counter, OrderedDict

import numpy as np

from . import Scene, _set_threads

__all__ = ["pick"]

# Scenes loaded in this (worker) process, most recently used last.
_SCENES: "OrderedDict[tuple, Scene]" = OrderedDict()
_SCENES_KEPT = 4
_LOCK = threading.Lock()
_THREADS_SET = False
# How many times this process loaded each scene (the tests check: once).
_LOADS: "Counter[tuple]" = Counter()


def _scene_key(scene, masks, builder, leaf_size):
    """A hashable, picklable description of what to load: absolute paths and load options."""
    if isinstance(scene, Scene):
        raise ValueError(
            "raypick.dask.pick needs the scene's path or paths (each worker loads it); "
            "save a Scene with scene.save('scene.rpk') and give that path"
        )
    if isinstance(scene, (str, os.PathLike)):
        paths = [scene]
    else:
        try:
            paths = list(scene)
        except TypeError:
            raise ValueError(
                f"scene must be a path or a list of paths; got {type(scene).__name__}"
            ) from None
    if not paths:
        raise ValueError("scene is an empty list; give at least one scene file")
    paths = tuple(os.path.abspath(os.fspath(p)) for p in paths)
    if masks is not None and not isinstance(masks, int):
        masks = tuple(masks)
    return (paths, masks, builder, leaf_size)


def _worker_threads():
    """This process's Dask worker thread count, or None outside a worker."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return None
    state = getattr(worker, "state", None)
    return getattr(state, "nthreads", None) or getattr(worker, "nthreads", None)


def _loaded(key, caller_pid):
    """The scene for `key`, loaded once per process. In a worker process of its own (not the
    caller's: a threads-only cluster shares the caller's process), tracing first gets as many
    threads as the worker has."""
    global _THREADS_SET
    with _LOCK:
        if not _THREADS_SET and os.getpid() != caller_pid:
            threads = _worker_threads()
            if threads:
                _set_threads(int(threads))
            _THREADS_SET = True
        scene = _SCENES.get(key)
        if scene is None:
            paths, masks, builder, leaf_size = key
            masks = list(masks) if isinstance(masks, tuple) else masks
            scene = Scene.load(list(paths), masks=masks, builder=builder, leaf_size=leaf_size)
            _LOADS[key] += 1
            _SCENES[key] = scene
            while len(_SCENES) > _SCENES_KEPT:
                _SCENES.popitem(last=False)
        else:
            _SCENES.move_to_end(key)
        return scene


def _pick_chunk(rays, key, query, first_ray, caller_pid):
    """Answers one chunk of rays; in all-hits mode, `ray` is made global and `offsets` becomes
    `count` (hits per ray), summed into offsets across chunks by the caller."""
    answers = _loaded(key, caller_pid).pick(rays, **query)
    if "offsets" in answers:
        answers["count"] = np.diff(answers.pop("offsets"))
        answers["ray"] = answers["ray"] + first_ray
    return answers


def _layout(key, query, caller_pid):
    """Each answer key's (dtype, trailing shape, per-ray or per-hit), from zero rays."""
    answers = _loaded(key, caller_pid).pick(np.empty((0, 6)), **query)
    per_ray = {"hit", "invalid", "overflow", "offsets"} if "offsets" in answers else set(answers)
    return [
        (name, array.dtype.str, array.shape[1:], name in per_ray)
        for name, array in answers.items()
    ]


def pick(scene, rays, *, masks=None, builder=None, leaf_size=None, **query):
    """Answers the dask array `rays` (N, 6) against the scene at `scene` (a path or a list of
    paths) on the current Dask scheduler; returns a dict of dask arrays with the keys
    ``raypick.Scene.pick`` gives for `query`."""
    import dask
    import dask.array as da
    from dask.highlevelgraph import HighLevelGraph

    key = _scene_key(scene, masks, builder, leaf_size)
    if not isinstance(rays, da.Array):
        raise ValueError(
            f"rays must be a dask array of shape (N, 6); got {type(rays).__name__} "
            "(wrap a numpy array with dask.array.from_array(rays, chunks=(1_000_000, 6)))"
        )
    if rays.ndim != 2 or rays.shape[1] != 6:
        raise ValueError(f"rays must be a dask array of shape (N, 6); got shape {rays.shape}")
    if rays.dtype != np.float64:
        raise ValueError(
            f"rays must be float64; got dtype {rays.dtype} (convert it with .astype(numpy.float64))"
        )
    if any(np.isnan(c) for c in rays.chunks[0]):
        raise ValueError("rays has unknown chunk sizes; call rays.compute_chunk_sizes() first")
    if len(rays.chunks[1]) != 1:
        rays = rays.rechunk({1: 6})
    # Empty chunks (rays filtered by a mask, say) are left out: dask's cumsum of the all-hits
    # counts fails on an empty chunk before the last.
    kept = tuple(c for c in rays.chunks[0] if c) or (0,)
    if kept != rays.chunks[0]:
        rays = rays.rechunk({0: kept})

    pid = os.getpid()
    layout = dask.delayed(_layout, pure=False)(key, query, pid).compute()

    # The graph, written out: one pick task per chunk, and for each answer key one getitem
    # task per chunk that takes its array out of the chunk's answers. (Built through
    # dask.delayed and from_delayed, it has twice the tasks, and on 250k-ray chunks the
    # scheduler's time per task was a third of the pick's.)
    token = uuid.uuid4().hex  # fresh keys: the files may change between calls
    picks = f"raypick-pick-{token}"
    starts = np.concatenate([[0], np.cumsum(rays.chunks[0])[:-1]]).astype(np.int64)
    pick_layer = {
        (picks, i): (_pick_chunk, (rays.name, i, 0), key, query, int(start), pid)
        for i, start in enumerate(starts)
    }
    layers = {picks: pick_layer}
    dependencies = {picks: {rays.name}}

    def column(name, chunks, trailing, dtype):
        """The dask array of answer key `name` (`count` for the hits per ray)."""
        out = f"raypick-{name}-{token}"
        layers[out] = {
            (out, i) + (0,) * len(trailing): (operator.getitem, (picks, i), name)
            for i in range(len(starts))
        }
        dependencies[out] = {picks}
        graph = HighLevelGraph.merge(
            HighLevelGraph(dict(layers), {k: set(v) for k, v in dependencies.items()}), rays.dask
        )
        return da.Array(graph, out, chunks=(chunks,) + tuple((d,) for d in trailing), dtype=dtype)

    per_hit = tuple(np.nan for _ in starts)
    answers = {}
    for name, dtype, trailing, per_ray in layout:
        if name == "offsets":
            counts = column("count", rays.chunks[0], (), np.int64)
            answers[name] = da.concatenate([da.zeros(1, dtype=np.int64), da.cumsum(counts)])
        else:
            chunks = rays.chunks[0] if per_ray else per_hit
            answers[name] = column(name, chunks, tuple(trailing), np.dtype(dtype))
    return answers
