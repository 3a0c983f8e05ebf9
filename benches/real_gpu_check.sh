#!/usr/bin/env bash
# The checks a real GPU gets when a session is lent one (BENCHMARKS.md, "A real GPU at …"): the
# test modules that compare the GPU with the other paths, `raypick verify --random 1000000` on
# the bunny, the dragon and the Jacksboro DEM, byte-identical `pick` CSV across the GPU, the
# engine and the twin on 1M camera and incoherent rays, and the GPU's and the engine's
# throughput there. Two halves, because the GPU's machine has no Rust toolchain and no network:
#
#   bash benches/real_gpu_check.sh bundle     # here: builds, strips and packs devcheck/
#   bash benches/real_gpu_check.sh run        # there, in the repository root, with devcheck/
#                                             # and .gl/ (the Vulkan loader and glvnd .debs)
#                                             # carried; writes $OUT/summary.txt and logs
#                                             # (QUICK=1: without the throughput runs)
#
# The .gl/ packages: libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2, fetched
# with `apt-get download` (NVIDIA's Vulkan driver needs glvnd's libraries beside the loader).
set -uo pipefail
cd "$(dirname "$0")/.."
# Modules of the one integration-test binary (tests/suite), run one by one.
tests="csv_identity engine equivalence instances modes precision refit semantics transforms watertight gpu_pipeline render workgroup_size gpu_limits server_edits"
scenes="tests/data/bunny.obj d/dragon_res2.obj tests/data/jacksboro_fault_dem_utm.asc"

bundle() {
    set -e
    local dir
    dir=$(mktemp -d)
    cargo test --release --no-run --message-format=json 2>/dev/null |
        python3 -c 'import json,sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["target"]["kind"] == ["test"]:
        print(m["target"]["name"], m["executable"])' >"$dir/tests.txt"
    strip -o "$dir/suite" "$(awk '$1 == "suite" {print $2}' "$dir/tests.txt")"
    cargo build --release --quiet
    strip -o "$dir/raypick" target/release/raypick
    cp ../shared/data/dragon_res2.obj "$dir/"
    rm "$dir/tests.txt"
    mkdir -p devcheck
    (cd "$dir" && tar -cJf - .) >devcheck/devcheck.tar.xz
    rm -r "$dir"
    grep -qx '/devcheck/' .git/info/exclude || echo '/devcheck/' >>.git/info/exclude
    ls -l devcheck/devcheck.tar.xz
}

run() {
    local logs=/tmp/logs summary=$OUT/summary.txt
    mkdir -p $logs
    say() { echo "$*" | tee -a "$summary"; }
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    export XDG_RUNTIME_DIR=/tmp
    local icd
    icd=$(find /usr/local/nvidia /usr/share/vulkan /etc/vulkan -name '*nvidia*.json' 2>/dev/null | grep -i icd | head -1)
    [ -n "$icd" ] && export VK_DRIVER_FILES=$icd VK_ICD_FILENAMES=$icd
    export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
    mkdir -p /work/shared/data d target/release target/tmp && tar -C d -xJf devcheck/devcheck.tar.xz
    # The test binaries look for the checkout and ../shared where they were built.
    [ -e /work/main ] || ln -s "$PWD" /work/main
    cp d/dragon_res2.obj tests/data/bunny.obj tests/data/jacksboro_fault_dem_utm.asc /work/shared/data/
    cp d/raypick target/release/raypick
    say "$(nvidia-smi -L) cores=$(nproc) rev=$(git log -1 --format=%h 2>/dev/null)"
    # The 1M ray sets, made while the tests run.
    (for s in $scenes; do
        python3 benches/make_ray_sets.py --scene "$s" --count 1000000 --out-prefix "/tmp/rs-$(basename "${s%.*}")"
    done; touch /tmp/rs.done) >$logs/raysets.log 2>&1 &
    for t in $tests; do
        local start=$SECONDS
        (cd /work/main && timeout 100 d/suite "$t::" >"$logs/$t.log" 2>&1)
        say "$t rc=$? $((SECONDS - start))s $(grep -E '^test result' "$logs/$t.log" | tail -1)"
    done
    say "marker: $(cat target/tmp/gpu-tests-ran)"
    for s in $scenes; do
        local log=$logs/verify-$(basename "$s").log
        timeout 120 target/release/raypick verify --scene "$s" --random 1000000 >"$log" 2>&1
        say "verify $s rc=$?: $(grep -E 'brute force|rays, ' "$log" | tr '\n' ' ')"
    done
    while [ ! -e /tmp/rs.done ]; do sleep 1; done
    for s in $scenes; do
        for kind in camera incoherent; do
            local rays=/tmp/rs-$(basename "${s%.*}")-$kind.txt
            for b in gpu cpu reference; do
                timeout 60 target/release/raypick pick --scene "$s" --rays "$rays" --backend $b --out /tmp/p-$b.csv -q 2>>$logs/pick.log
            done
            say "csv $s $kind: gpu=cpu $(cmp -s /tmp/p-gpu.csv /tmp/p-cpu.csv && echo yes || echo NO)" \
                "cpu=ref $(cmp -s /tmp/p-cpu.csv /tmp/p-reference.csv && echo yes || echo NO) lines=$(wc -l </tmp/p-gpu.csv)"
            [ -n "${QUICK:-}" ] && continue
            for b in gpu cpu; do
                timeout 60 target/release/raypick bench --scene "$s" --ray-file "$rays" --backend $b --repeat 3 >$logs/bench-$b.log 2>&1
                say "  bench $b: $(grep -E 'trace alone|pick_rays_per_s' $logs/bench-$b.log | tr '\n' ' ')"
            done
        done
    done
    tar -C $logs -czf "$OUT/logs.tar.gz" .
}

case "${1:-}" in
bundle) bundle ;;
run) run ;;
*)
    echo "usage: bash benches/real_gpu_check.sh bundle|run" >&2
    exit 2
    ;;
esac
