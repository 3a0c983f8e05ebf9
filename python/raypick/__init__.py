"""raypick: exact, fast ray picking for 3D scenes — numpy in, numpy out.

>>> import numpy as np, raypick
>>> scene = raypick.Scene.load("tests/data/bunny.obj")            # doctest: +SKIP
>>> hits = scene.pick(np.array([[0, 0.1, 1, 0, 0, -1.0]]))        # doctest: +SKIP
>>> hits["hit"], hits["triangle"], hits["position"]               # doctest: +SKIP

- ``Scene.load(paths, masks=None, builder=None, leaf_size=None)``: the files the CLI reads
  (OBJ, PLY, STL, glTF, ESRI ASCII grid, GeoTIFF, a ``.json`` scene description, a saved
  ``.rpk``); ``builder`` and ``leaf_size`` (by default "auto" and 8) choose how the tree is
  built, and a saved ``.rpk``, already built, refuses them. ``Scene.from_arrays(vertices,
  triangles)``; ``scene.save(path)`` writes an ``.rpk``.
- ``scene.pick(rays, mode="closest", max_hits=16, cull="none", tmin=0.0, tmax=inf,
  ray_mask=0xFFFFFFFF, intersector="watertight", backend="auto")``: ``rays`` is (N, 6) float64
  (origin, direction) or a tuple (origins, directions); the answer is a dict of numpy arrays
  named like the CLI's CSV columns (``hit``, ``t``, ``object``, ``triangle``, ``u``, ``v``,
  ``position``, ``normal``, ``row``/``col`` on terrain grids, ``invalid``). A miss has NaN in
  float fields and -1 in integer fields. ``mode="any"`` answers ``hit`` (and ``invalid``);
  ``mode="all"`` answers per ray ``hit``, ``invalid``, ``overflow`` and ``offsets`` (N + 1),
  and per hit ``ray``, ``rank``, ``t``, ``object``, ``triangle``, ``u``, ``v``, ``position``,
  ``normal`` (and ``row``/``col``): ray i's hits are ``offsets[i]:offsets[i + 1]``.
- ``scene.los(a, b, epsilon=1e-6)``: bool (N,), whether each segment a -> b is unblocked.
- ``scene.viewshed(observer, targets=None, target_height=0.0)``: which targets (default: every
  terrain grid sample) the observer sees.
- ``camera_rays(camera, pixels=None)``: (N, 6) rays through pixels of the CLI's camera JSON.
- ``set_max_memory(size)``: the memory budget for everything sized by files and arguments, in
  bytes or as the CLI's ``--max-memory`` writes it ("8G"); ``max_memory()`` reads it.
- ``raypick.dask.pick(scene_paths, dask_rays, **query)``: the same answers as dask arrays,
  computed on a Dask cluster whose worker processes each load the scene once.

Tracing releases the GIL, and Ctrl-C stops a long pick (KeyboardInterrupt). Bad shapes or
dtypes raise ValueError; unreadable files OSError; an integer argument given something else
(a bool included) TypeError; other refusals ValueError, each with one sentence.
"""

from ._raypick import Scene, _set_threads, _threads, camera_rays, max_memory, set_max_memory

__all__ = ["Scene", "camera_rays", "dask", "max_memory", "set_max_memory"]


def __getattr__(name):
    # `raypick.dask` without an explicit `import raypick.dask` (dask is an optional dependency).
    if name == "dask":
        import importlib

        return importlib.import_module(".dask", __name__)
    raise AttributeError(f"module 'raypick' has no attribute {name!r}")
