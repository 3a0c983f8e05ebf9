#!/usr/bin/env bash
# One run, one machine: raypick's in-process `pick` (`raypick bench --ray-file`: the CPU engine at
# 1 and 2 threads, the reference twin at 2) against Open3D's RaycastingScene.cast_rays at 2
# threads (benches/open3d_peer.py), on the same 1M camera and 1M incoherent rays
# (benches/make_ray_sets.py) of each scene. Prints one table row per scene and ray set.
#
# Needs: a release build (`cargo build --release`), and a Python with open3d==0.20.0 and numpy:
#   apt-get install -y libusb-1.0-0 libgomp1
#   python3 -m venv /work/venv-open3d && /work/venv-open3d/bin/pip install open3d==0.20.0 numpy
# Usage: benches/engine_vs_open3d.sh [PYTHON] [RAY_DIR]   (scenes from ../shared/data)
# SCENES="path ..." picks other scene files, e.g. the peers bench's 2M terrain and soup:
#   cargo run --release --example write_peer_scenes -- target/peer-scenes
#   SCENES="target/peer-scenes/terrain_2m.asc target/peer-scenes/soup_200k.obj" benches/engine_vs_open3d.sh
set -Eeuo pipefail
# A step that fails says which, instead of ending the table without a word.
trap 'echo "engine_vs_open3d.sh: line $LINENO failed (exit $?): $BASH_COMMAND" >&2' ERR
cd "$(dirname "$0")/.."
python="${1:-/work/venv-open3d/bin/python}"
dir="${2:-target/ray-sets}"
data=../shared/data
count="${COUNT:-1000000}"
passes="${PASSES:-5}"
mkdir -p "$dir"
rate() { grep -o "$1=[0-9.]*" | tail -1 | cut -d= -f2; }
printf '%-28s %-11s %12s %12s %12s %12s %9s %9s\n' scene rays "cpu 1t" "cpu 2t" "ref 2t" "open3d 2t" "cpu/o3d" "cpu/ref"
echo '(M rays/s: raypick pick = bench --ray-file, best of passes; Open3D cast_rays, best of passes)'
scenes="${SCENES:-$data/bunny.obj $data/dragon_res2.obj $data/jacksboro_fault_dem_utm.asc}"
for scene in $scenes; do
    stem="$(basename "$scene")"
    stem="${stem%%.*}"
    if [ ! -f "$dir/$stem-camera.txt" ]; then
        "$python" benches/make_ray_sets.py --scene "$scene" --count "$count" --out-prefix "$dir/$stem"
    fi
    for set in camera incoherent; do
        rays="$dir/$stem-$set.txt"
        bench() { ./target/release/raypick bench --scene "$scene" --ray-file "$rays" --repeat "$passes" "$@" 2>/dev/null | rate pick_rays_per_s; }
        cpu1=$(bench --backend cpu --threads 1)
        cpu2=$(bench --backend cpu --threads 2)
        ref2=$(bench --backend reference --threads 2)
        o3d=$("$python" benches/open3d_peer.py --scene "$scene" --rays "$rays" --threads 2 --passes "$passes" | rate open3d_rays_per_s)
        awk -v s="$stem" -v r="$set" -v c1="$cpu1" -v c2="$cpu2" -v f="$ref2" -v o="$o3d" 'BEGIN {
            printf "%-28s %-11s %12.2f %12.2f %12.2f %12.2f %9.2f %9.2f\n", s, r, c1/1e6, c2/1e6, f/1e6, o/1e6, c2/o, c2/f }'
    done
done
