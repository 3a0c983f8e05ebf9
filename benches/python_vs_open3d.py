#!/usr/bin/env python3
"""raypick's Python `scene.pick` against Open3D's `RaycastingScene.cast_rays` (and trimesh's
ray module when it is installed) on the same numpy arrays, against raypick's in-process Rust
pick on the same rays, and raypick.dask's scaling on local worker processes.

Part 1, per scene and ray set (the 1M camera and 1M incoherent rays of
benches/make_ray_sets.py, read from RAY_DIR/<scene>-<set>.txt, cached as .npy beside them):
- python: `scene.pick(rays, backend="cpu")` on the (N, 6) float64 array, answers included (one
  untimed pass, then the best of PASSES);
- rust: `raypick bench --scene FILE --ray-file FILE --backend cpu --repeat PASSES` (the same
  pick in process: pick_rays_per_s), and python ÷ rust (the issue's target: ≥ 0.9);
- open3d: `cast_rays` on the same rays as a float32 tensor, shifted to the scene's centre first
  as benches/open3d_peer.py does (the shift and the conversion not timed), best of PASSES, and
  how many rays' triangles differ from raypick's (the scene built from the same arrays);
- trimesh: `mesh.ray.intersects_first` (Embree through embreex when installed), best of 2.

Part 2 (--dask): 4M rays (a 2000 × 2000 camera over the DEM): one process using both cores
(`scene.pick`) against LocalCluster(processes=True) with 1 worker × 1 thread, 1 × 2 and
2 × 1, rays persisted on the workers first; "kept" leaves the answers on the workers
(persist and wait), "gathered" brings them to this process (dask.compute). Each cluster's runs
alternate with the one-process run (best of ROUNDS each), so a shared machine's load falls on
both sides of each ratio.

Usage: python benches/python_vs_open3d.py [--data ../shared/data] [--rays target/ray-sets]
       [--rust target/release/raypick] [--passes 5] [--scenes bunny ...] [--no-peers]
       [--dask | --dask-only] [--chunk 1000000] [--rounds 4] [--dask-side 2000]
Needs: raypick (pip install ./python[dask]), numpy; optional open3d==0.20.0, trimesh, embreex.
"""

import argparse
import os
import statistics
import re
import subprocess
import sys
import time
import warnings

import numpy as np

import raypick

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
SCENES = {"bunny": "bunny.obj", "dragon_res2": "dragon_res2.obj",
          "jacksboro_fault_dem_utm": "jacksboro_fault_dem_utm.asc"}


def best_of(passes, run):
    """Seconds of the fastest of `passes` timed runs, after one untimed run."""
    run()
    times = []
    for _ in range(passes):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def load_rays(ray_dir, stem, kind):
    cache = os.path.join(ray_dir, f"{stem}-{kind}.npy")
    text = os.path.join(ray_dir, f"{stem}-{kind}.txt")
    if os.path.exists(cache) and os.path.getmtime(cache) >= os.path.getmtime(text):
        return np.load(cache), text
    rays = np.loadtxt(text, dtype=np.float64, usecols=range(6))
    np.save(cache, rays)
    return rays, text


def rust_rate(rust, scene_file, ray_file, passes):
    done = subprocess.run(
        [rust, "bench", "--scene", scene_file, "--ray-file", ray_file, "--backend", "cpu",
         "--repeat", str(passes)], capture_output=True, text=True)
    found = re.findall(r"pick_rays_per_s=([0-9.]+)", done.stdout)
    return float(found[-1]) if found else float("nan")


def open3d_part(o3d, vertices, triangles, rays, passes, reference):
    """Open3D rays/s on `rays`, and the rays whose triangle differs from `reference` (raypick's
    answers for the same triangle order)."""
    shift = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor((vertices - shift).astype(np.float32)),
                        o3d.core.Tensor(triangles.astype(np.uint32)))
    shifted = rays.copy()
    shifted[:, :3] -= shift
    tensor = o3d.core.Tensor(shifted.astype(np.float32))
    answers = {}

    def run():
        answers["r"] = scene.cast_rays(tensor)

    seconds = best_of(passes, run)
    ids = answers["r"]["primitive_ids"].numpy().astype(np.int64)
    ids[ids == scene.INVALID_ID] = -1
    differ = int((ids != reference["triangle"]).sum())
    return len(rays) / seconds, differ


def trimesh_part(vertices, triangles, rays):
    try:
        import trimesh
    except ImportError:
        return None, "trimesh not installed"
    mesh = trimesh.Trimesh(vertices=vertices, faces=triangles, process=False)
    kind = type(mesh.ray).__module__.rsplit(".", 1)[-1]
    count = len(rays) if "pyembree" in kind else min(len(rays), 20_000)
    part = rays[:count]
    seconds = best_of(1, lambda: mesh.ray.intersects_first(part[:, :3], part[:, 3:]))
    return count / seconds, f"{kind}, {count} rays"


def part1(args):
    """raypick (Python, then the Rust binary) on every set first, then the peers: Open3D's and
    Embree's worker threads keep spinning for a while after a call, so a peer run just before
    a raypick run would slow it down."""
    rows = {}
    print(f"raypick {raypick.__file__}; threads {raypick._threads()}", flush=True)
    for stem in args.scenes:
        scene_file = os.path.join(args.data, SCENES[stem])
        scene = raypick.Scene.load(scene_file)
        for kind in ["camera", "incoherent"]:
            rays, ray_file = load_rays(args.rays, stem, kind)
            py = len(rays) / best_of(args.passes, lambda: scene.pick(rays, backend="cpu"))
            rust = rust_rate(args.rust, scene_file, ray_file, args.passes) if args.rust else float("nan")
            rows[stem, kind] = [py, rust, float("nan"), "", float("nan"), ""]
            print(f"{stem} {kind}: python {py / 1e6:.2f} M rays/s, rust {rust / 1e6:.2f}, "
                  f"python/rust {py / rust:.2f}", flush=True)
    if not args.no_peers:
        try:
            import open3d as o3d
            from open3d_peer import load_scene
        except ImportError as e:
            print(f"open3d: not measured ({e})")
            o3d = None
        for stem in args.scenes if o3d else []:
            scene_file = os.path.join(args.data, SCENES[stem])
            vertices, triangles = load_scene(scene_file)
            same_order = raypick.Scene.from_arrays(vertices, triangles)
            for kind in ["camera", "incoherent"]:
                rays, _ = load_rays(args.rays, stem, kind)
                reference = same_order.pick(rays, backend="cpu")
                row = rows[stem, kind]
                row[2], row[3] = open3d_part(o3d, vertices, triangles, rays, args.passes, reference)
                tm, row[5] = trimesh_part(vertices, triangles, rays)
                row[4] = float("nan") if tm is None else tm
                print(f"{stem} {kind}: open3d {row[2] / 1e6:.2f} M rays/s, {row[3]} triangles "
                      f"differ; trimesh {row[4] / 1e6:.2f} ({row[5]})", flush=True)
        if o3d:
            print(f"open3d {o3d.__version__}")
    print("| scene | rays | scene.pick | Rust pick | Python ÷ Rust | Open3D cast_rays | "
          "Python ÷ Open3D | Open3D triangles ≠ raypick | trimesh (Embree) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (stem, kind), (py, rust, o3d_rate, differ, tm, _) in rows.items():
        print(f"| {stem} | {kind} | {py / 1e6:.2f} | {rust / 1e6:.2f} | {py / rust:.2f} | "
              f"{o3d_rate / 1e6:.2f} | {py / o3d_rate:.2f} | {differ} | {tm / 1e6:.2f} |")


def dem_camera_rays(dem_file, side):
    scene = raypick.Scene.load(dem_file)
    lo, hi = scene.bounds
    centre = (lo + hi) / 2
    eye = centre + np.array([0.4, -1.0, 1.6]) / np.linalg.norm([0.4, -1.0, 1.6]) * np.linalg.norm(hi - lo) * 1.25
    camera = {"perspective": {"eye": eye.tolist(), "target": centre.tolist(), "up": [0, 0, 1],
                              "fov_y_deg": 40, "width": side, "height": side}}
    return scene, raypick.camera_rays(camera)


def part2(args):
    import dask
    import dask.array as da
    import raypick.dask
    from distributed import Client, LocalCluster, wait

    dem_file = os.path.abspath(os.path.join(args.data, SCENES["jacksboro_fault_dem_utm"]))
    scene, rays = dem_camera_rays(dem_file, args.dask_side)
    n = len(rays)
    print(f"dask: {n} rays ({args.dask_side} x {args.dask_side} camera over the DEM), "
          f"chunks of {args.chunk}; each line's 'one process' (scene.pick here, "
          f"{raypick._threads()} threads) is measured in rounds with its cluster's runs, "
          f"best of {args.rounds}")
    rows = []
    for workers, threads in (tuple(int(x) for x in c.split("x")) for c in args.clusters):
        with LocalCluster(n_workers=workers, threads_per_worker=threads, processes=True,
                          host="127.0.0.1", dashboard_address=None) as cluster, Client(cluster) as client:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                persisted = client.persist(da.from_array(rays, chunks=(args.chunk, 6)))
                wait(persisted)

            def kept():
                answers = raypick.dask.pick(dem_file, persisted)
                futures = client.persist(list(answers.values()))
                wait(futures)
                del futures

            def gathered():
                dask.compute(raypick.dask.pick(dem_file, persisted))

            # Interleaved (one process, kept, gathered) rounds, the best of each: the machine
            # may be shared, and this keeps each comparison to the same moments.
            times = {"one": [], "kept": [], "gathered": []}
            kept(), gathered(), scene.pick(rays)  # warm: every worker loads the scene
            for _ in range(args.rounds):
                for name, run in [("one", lambda: scene.pick(rays)), ("kept", kept),
                                  ("gathered", gathered)]:
                    start = time.perf_counter()
                    run()
                    times[name].append(time.perf_counter() - start)
            one, kept_rate, gathered_rate = (n / min(times[k]) for k in ("one", "kept", "gathered"))
            median = {k: n / statistics.median(v) for k, v in times.items()}
            rows.append((workers, threads, kept_rate, gathered_rate))
            print(f"dask {workers} worker(s) x {threads} thread(s): kept {kept_rate / 1e6:.2f} M rays/s "
                  f"({kept_rate / one:.2f} of one process at {one / 1e6:.2f}), gathered "
                  f"{gathered_rate / 1e6:.2f} ({gathered_rate / one:.2f}); medians: kept "
                  f"{median['kept'] / median['one']:.2f} and gathered "
                  f"{median['gathered'] / median['one']:.2f} of one process", flush=True)
    by_shape = {(w, t): (k, g) for w, t, k, g in rows}
    if (1, 1) in by_shape and (2, 1) in by_shape:
        (k11, g11), (k21, g21) = by_shape[1, 1], by_shape[2, 1]
        print(f"scaling 1 -> 2 worker processes (1 thread each): kept {k21 / k11:.2f}x, "
              f"gathered {g21 / g11:.2f}x")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default=os.path.join(HERE, "..", "..", "shared", "data"))
    p.add_argument("--rays", default=os.path.join(HERE, "..", "target", "ray-sets"))
    p.add_argument("--rust", default=os.path.join(HERE, "..", "target", "release", "raypick"))
    p.add_argument("--passes", type=int, default=5)
    p.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    p.add_argument("--dask", action="store_true", help="also run part 2 (Dask scaling)")
    p.add_argument("--dask-only", action="store_true", help="run part 2 only")
    p.add_argument("--chunk", type=int, default=1_000_000)
    p.add_argument("--rounds", type=int, default=4, help="timed rounds of part 2")
    p.add_argument("--dask-side", type=int, default=2000, help="camera pixels per side (2000: 4M rays)")
    p.add_argument("--clusters", nargs="+", default=["1x1", "1x2", "2x1"],
                   help="LocalClusters of part 2 as WORKERSxTHREADS")
    p.add_argument("--no-peers", action="store_true", help="skip Open3D and trimesh")
    args = p.parse_args()
    if not args.dask_only:
        part1(args)
    if args.dask or args.dask_only:
        part2(args)


if __name__ == "__main__":
    main()
