#!/usr/bin/env bash
# Whole-process picks against Embree's C pipeline (issue 14; BENCHMARKS.md "Whole process:
# load, build, pick"): `raypick pick --backend cpu` of 4,096 incoherent rays on each mesh,
# paired run by run with benches/embree_pipeline.c doing the same job (parse, build, trace),
# timed from outside by farm-bench. Also the load rates of each scene file (`raypick bench`
# prints its load time). Needs libembree-dev, the release binary and target/ray-sets
# (benches/make_ray_sets.py).
#
#   bash benches/whole_process.sh [RUNS]
set -euo pipefail
cd "$(dirname "$0")/.."
runs="${1:-9}"
data=../shared/data
cc -O2 -o target/embree_pipeline benches/embree_pipeline.c -lembree3
cargo build --release --quiet
# The full Stanford dragon's size (871k triangles, 33 MB) from the 202k one, subdivided.
[ -s target/dragon_x4.obj ] || python3 benches/subdivide_obj.py "$data/dragon_res2.obj" target/dragon_x4.obj
for pair in "target/dragon_x4.obj dragon_res2" "$data/dragon_res2.obj dragon_res2" "$data/bunny.obj bunny"; do
    set -- $pair
    mesh=$1
    head -n 4096 "target/ray-sets/$2-incoherent.txt" > "target/$2-4096.txt"
    echo "== $mesh, 4096 incoherent rays: raypick (A) vs Embree C pipeline (B)"
    farm-bench -n "$runs" --timeout 600 \
        --vs "target/embree_pipeline $mesh target/$2-4096.txt" \
        -- target/release/raypick pick --scene "$mesh" --rays "target/$2-4096.txt" \
        --backend cpu --out /dev/null
done
# The same scene saved (`raypick build`) and picked from the .rpk, loaded in place.
target/release/raypick --quiet build --scene target/dragon_x4.obj --out target/dragon_x4.rpk
echo "== target/dragon_x4.rpk, 4096 incoherent rays: raypick (A) vs Embree C pipeline on the OBJ (B)"
farm-bench -n "$runs" --timeout 600 \
    --vs "target/embree_pipeline target/dragon_x4.obj target/dragon_res2-4096.txt" \
    -- target/release/raypick pick --scene target/dragon_x4.rpk --rays target/dragon_res2-4096.txt \
    --backend cpu --out /dev/null
echo "== load rates (raypick bench's load time; file size / time)"
for file in target/dragon_x4.obj target/dragon_x4.rpk $data/dragon_res2.obj $data/bunny.obj $data/jacksboro_fault_dem_utm.asc \
    $data/jacksboro_fault_dem_utm_f32_deflate.tif $data/jacksboro_fault_dem_utm_int16.tif; do
    bytes=$(stat -c %s "$file")
    best=
    for _ in 1 2 3 4 5; do
        ms=$(target/release/raypick bench --scene "$file" --rays 1000 --repeat 1 2>/dev/null \
            | sed -n 's/.*loaded in \([0-9.]*\) ms.*/\1/p')
        best=$(python3 -c "print(min(x for x in [$ms, ${best:-1e9}]))")
    done
    python3 -c "print(f'$file: {$bytes/1e6:.1f} MB, best load {$best:.0f} ms, {$bytes/1e6/max($best,0.5)*1e3:.0f} MB/s')"
done
