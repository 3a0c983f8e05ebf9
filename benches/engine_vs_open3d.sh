#!/usr/bin/env bash
# One run, one machine: raypick's in-process `pick` (`raypick bench --ray-file`: the CPU engine at
# 1 and 2 threads, the reference twin at 2) against Open3D's RaycastingScene.cast_rays at 2
# threads (benches/open3d_peer.py), on the same 1M camera and 1M incoherent rays
# (benches/make_ray_sets.py) of each scene. Prints one table row per scene and ray set.
# Each scene and set is timed in ROUNDS rounds (default 3), each round running the four
# processes in turn, so that a slow spell of a shared machine falls on raypick and Open3D alike;
# a row gives each column's median over the rounds and the range of the rounds' own cpu/o3d.
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
rounds="${ROUNDS:-3}"
mkdir -p "$dir"
rate() { grep -o "$1=[0-9.]*" | tail -1 | cut -d= -f2; }
printf '%-28s %-11s %12s %12s %12s %12s %9s %9s  %s\n' scene rays "cpu 1t" "cpu 2t" "ref 2t" "open3d 2t" "cpu/o3d" "cpu/ref" "cpu/o3d by round"
echo "(M rays/s: raypick pick = bench --ray-file, best of $passes passes; Open3D cast_rays, best of $passes passes; medians of $rounds rounds)"
# The median of the numbers given.
med() { printf '%s\n' "$@" | sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }
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
        c1=() c2=() f2=() o=() ratios=()
        for _ in $(seq "$rounds"); do
            c1+=("$(bench --backend cpu --threads 1)")
            c2+=("$(bench --backend cpu --threads 2)")
            f2+=("$(bench --backend reference --threads 2)")
            o+=("$("$python" benches/open3d_peer.py --scene "$scene" --rays "$rays" --threads 2 --passes "$passes" | rate open3d_rays_per_s)")
            ratios+=("$(awk -v c="${c2[-1]}" -v o="${o[-1]}" 'BEGIN { printf "%.2f", c / o }')")
        done
        awk -v s="$stem" -v r="$set" -v c1="$(med "${c1[@]}")" -v c2="$(med "${c2[@]}")" -v f="$(med "${f2[@]}")" -v o="$(med "${o[@]}")" -v rs="${ratios[*]}" 'BEGIN {
            printf "%-28s %-11s %12.2f %12.2f %12.2f %12.2f %9.2f %9.2f  %s\n", s, r, c1/1e6, c2/1e6, f/1e6, o/1e6, c2/o, c2/f, rs }'
    done
done
