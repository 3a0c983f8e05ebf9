// Picking: one invocation per ray; closest hit, any hit, or all hits up to max_hits.
// Stackless, ordered traversal of the median-cut tree with parent links and a three-state
// automaton (Hapala et al. 2011); Möller–Trumbore per triangle, or the watertight test of
// Woop, Benthin and Wald (2013). Face culling and layer masks per ray. In an instanced scene
// (params.top_nodes > 0) the same automaton walks two levels with no stack: at a leaf of the
// top tree it moves the ray into the instance's frame and descends into the mesh's bottom tree;
// leaving the bottom root it climbs back to the instance's leaf and the world ray.
// CPU twin, line for line: src/cpu/ray_box.rs, src/cpu/ray_triangle.rs, src/cpu/traverse.rs.
// Shared struct layouts: src/layout.rs (checked by tests/layout.rs).

struct GpuNode {
    min: vec3<f32>,
    parent_kind: u32,
    max: vec3<f32>,
    first: u32,
}

struct GpuTriangle {
    v0: array<f32, 3>,
    v1: array<f32, 3>,
    v2: array<f32, 3>,
}

struct GpuRay {
    origin: vec3<f32>,
    tmin: f32,
    dir: vec3<f32>,
    tmax: f32,
    mask: u32,
    flags: u32,
    origin_lo: vec2<u32>,
}

struct GpuHitEntry {
    t: f32,
    prim: u32,
    u: f32,
    v: f32,
}

struct GpuHit {
    t: f32,
    prim: u32,
    u: f32,
    v: f32,
    box_tests: u32,
    triangle_tests: u32,
    count: u32,
    overflow: u32,
}

struct GpuParams {
    ray_count: u32,
    node_count: u32,
    iteration_cap: u32,
    row_pitch: u32,
    max_hits: u32,
    use_masks: u32,
    watertight: u32,
    top_nodes: u32,
    opaque: vec3<u32>,
    pad: u32,
}

struct GpuInstance {
    l0: vec3<f32>,
    cx: f32,
    l1: vec3<f32>,
    cy: f32,
    l2: vec3<f32>,
    cz: f32,
    c_lo: array<f32, 3>,
    root: u32,
    prim_base: u32,
    mask: u32,
    flags: u32,
    mesh: u32,
}

@group(0) @binding(0) var<uniform> params: GpuParams;
@group(0) @binding(1) var<storage, read> nodes: array<GpuNode>;
@group(0) @binding(2) var<storage, read> triangles: array<GpuTriangle>;
@group(0) @binding(3) var<storage, read> rays: array<GpuRay>;
@group(0) @binding(4) var<storage, read_write> hits: array<GpuHit>;
@group(0) @binding(5) var<storage, read_write> hit_lists: array<GpuHitEntry>;
@group(0) @binding(6) var<storage, read> triangle_masks: array<u32>;
@group(0) @binding(7) var<storage, read> triangle_ids: array<u32>;
@group(0) @binding(8) var<storage, read> instances: array<GpuInstance>;

const KIND_INNER: u32 = 16u;
const KIND_BITS: u32 = 5u;
const KIND_MASK: u32 = 31u;
const NO_HIT: u32 = 0xffffffffu;
const CAP_REACHED: u32 = 0xfffffffeu;
const UNFINISHED: u32 = 0xfffffffdu;
const MODE_CLOSEST: u32 = 0u;
const MODE_ANY: u32 = 1u;
const MODE_ALL: u32 = 2u;
const CULL_SHIFT: u32 = 2u;
const CULL_BACK: u32 = 1u;
const CULL_FRONT: u32 = 2u;
// `inside` while the walk is in the top tree (or the scene has no instances).
const NO_INSTANCE: u32 = 0xffffffffu;
// Relative widening of each box's [t_near, t_far] so rounding never culls a box the ray touches.
const BOX_PAD: f32 = 1e-6;
// Direction components smaller than this are treated as this (no infinities in WGSL).
const MIN_DIR: f32 = 1e-30;
// Stands in for infinity in slab intervals.
const HUGE: f32 = 3.0e38;

// Traversal states: how we arrived at `current`.
const FROM_PARENT: u32 = 0u;  // descending into the near child
const FROM_SIBLING: u32 = 1u; // moving across to the far child
const FROM_CHILD: u32 = 2u;   // climbing back up after a subtree is done

// ---- products the compiler must not fuse ----
// The CPU twin rounds every product before it is added; a GPU compiler may fuse `a * b + c`
// into one fused multiply-add, which rounds once, and answers would then differ in the last
// bit (they did on NVIDIA's Vulkan driver). Each product that meets an add goes through its
// bits and back, OR-ed with `params.opaque` (zeros the compiler cannot see), so no float
// rewrite can reach across it. `dot3` and `cross3` add in the twin's (glam's) order.

// 1: products and quotients are rounded as the twin rounds them, by the kernel itself; 0: by the
// hardware (set by the host, `GpuPicker::with_options`: 0 only on llvmpipe, which already
// rounds as the CPU does, but for the sum `mul_unfused` keeps apart).
override EXACT_ARITHMETIC: u32 = 1u;

fn mul(a: f32, b: f32) -> f32 {
    if EXACT_ARITHMETIC == 0u {
        return a * b;
    }
    return bitcast<f32>(bitcast<u32>(a * b) | params.opaque.x);
}

fn mul3(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    if EXACT_ARITHMETIC == 0u {
        return a * b;
    }
    return bitcast<vec3<f32>>(bitcast<vec3<u32>>(a * b) | params.opaque);
}

// `mul`, kept unfused on every adapter, llvmpipe included: Möller–Trumbore's `u + v` of two
// products was fused into a multiply-add there, and a ray through the midpoint of a shared
// edge (u + v = 1) missed the triangle the twin hits (tests/suite/gpu_pipeline.rs).
fn mul_unfused(a: f32, b: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(a * b) | params.opaque.x);
}

fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    let p = mul3(a, b);
    return (p.x + p.y) + p.z;
}

fn cross3(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return mul3(a.yzx, b.zxy) - mul3(a.zxy, b.yzx);
}

// ---- division, rounded as the CPU rounds it ----
// Vulkan lets a GPU divide to 2.5 ulp (NVIDIA's driver does, and answers then differed from the
// twin's in the last bit of a shear constant or of 1/det), so every division in the kernel is
// this one: the IEEE quotient rounded to nearest even, worked out on the significands with
// exact integer steps, subnormals and the special values included.

const SIGN_BIT: u32 = 0x80000000u;
const INF_BITS: u32 = 0x7f800000u;

// The significand of finite nonzero `bits` (leading bit at 23) and its exponent (unbiased + 127,
// below 1 for a subnormal).
fn unpack_significand(bits: u32) -> vec2<i32> {
    var e = i32((bits >> 23u) & 255u);
    var m = bits & 0x7fffffu;
    if e == 0 {
        e = 1;
        while (m & 0x800000u) == 0u {
            m = m << 1u;
            e -= 1;
        }
    } else {
        m = m | 0x800000u;
    }
    return vec2<i32>(i32(m), e);
}

fn div(a: f32, b: f32) -> f32 {
    if EXACT_ARITHMETIC == 0u {
        return a / b;
    }
    let ua = bitcast<u32>(a);
    let ub = bitcast<u32>(b);
    let sign = (ua ^ ub) & SIGN_BIT;
    let abs_a = ua & 0x7fffffffu;
    let abs_b = ub & 0x7fffffffu;
    if abs_a > INF_BITS || abs_b > INF_BITS || (abs_a == INF_BITS && abs_b == INF_BITS) || (abs_a == 0u && abs_b == 0u) {
        return bitcast<f32>(0x7fc00000u);
    }
    if abs_a == INF_BITS || abs_b == 0u {
        return bitcast<f32>(sign | INF_BITS);
    }
    if abs_a == 0u || abs_b == INF_BITS {
        return bitcast<f32>(sign);
    }
    let na = unpack_significand(abs_a);
    let nb = unpack_significand(abs_b);
    var r = u32(na.x);
    let d = u32(nb.x);
    var e = na.y - nb.y + 127;
    if r < d {
        r = r << 1u;
        e -= 1;
    }
    // 25 quotient bits (24 of significand, one guard bit); what remains is the sticky bit.
    var q = 0u;
    for (var i = 0; i < 25; i += 1) {
        q = q << 1u;
        if r >= d {
            r -= d;
            q = q | 1u;
        }
        r = r << 1u;
    }
    var sticky = r != 0u;
    if e >= 1 {
        var m = q >> 1u;
        if (q & 1u) != 0u && (sticky || (m & 1u) != 0u) {
            m += 1u;
        }
        if m == 0x1000000u {
            m = m >> 1u;
            e += 1;
        }
        if e >= 255 {
            return bitcast<f32>(sign | INF_BITS);
        }
        return bitcast<f32>(sign | (u32(e) << 23u) | (m & 0x7fffffu));
    }
    // A subnormal quotient: `shift` more bits go below the last place.
    let shift = u32(1 - e);
    if shift > 25u {
        return bitcast<f32>(sign);
    }
    let m = q >> (shift + 1u);
    let guard = (q >> shift) & 1u;
    sticky = sticky || (q & ((1u << shift) - 1u)) != 0u;
    var rounded = m;
    if guard != 0u && (sticky || (m & 1u) != 0u) {
        rounded += 1u;
    }
    return bitcast<f32>(sign | rounded);
}

// ---- ray/box (src/cpu/ray_box.rs) ----

fn safe_inverse(dir: vec3<f32>) -> vec3<f32> {
    let magnitude = max(abs(dir), vec3<f32>(MIN_DIR));
    let sign = select(vec3<f32>(-1.0), vec3<f32>(1.0), dir >= vec3<f32>(0.0));
    return vec3<f32>(div(sign.x, magnitude.x), div(sign.y, magnitude.y), div(sign.z, magnitude.z));
}

// Whether the ray's interval over a box (box_interval) meets [tmin, tmax]: the box test.
fn meets(interval: vec2<f32>, tmin: f32, tmax: f32) -> bool {
    return max(interval.x, tmin) <= min(interval.y, tmax);
}

// The ray's slab interval over the box [lo, hi], each end widened by BOX_PAD relative, before
// tmin and tmax cut it.
fn box_interval(lo: vec3<f32>, hi: vec3<f32>, origin: vec3<f32>, dir: vec3<f32>, inv_dir: vec3<f32>) -> vec2<f32> {
    let t0 = (lo - origin) * inv_dir;
    let t1 = (hi - origin) * inv_dir;
    // A ray parallel to a slab and inside it (faces included) is unconstrained by that slab;
    // without this, an origin exactly on a face would give 0 * inverse = 0 and cull the box.
    let free = abs(dir) < vec3<f32>(MIN_DIR) & origin >= lo & origin <= hi;
    let near = select(min(t0, t1), vec3<f32>(-HUGE), free);
    let far = select(max(t0, t1), vec3<f32>(HUGE), free);
    let t_near = max(max(near.x, near.y), near.z);
    let t_far = min(min(far.x, far.y), far.z);
    return vec2<f32>(t_near - mul(abs(t_near), BOX_PAD), t_far + mul(abs(t_far), BOX_PAD));
}

// box_interval over the triangle's own box.
fn triangle_interval(tri: GpuTriangle, origin: vec3<f32>, dir: vec3<f32>, inv_dir: vec3<f32>) -> vec2<f32> {
    let a = vertex(tri.v0);
    let b = vertex(tri.v1);
    let c = vertex(tri.v2);
    return box_interval(min(min(a, b), c), max(max(a, b), c), origin, dir, inv_dir);
}

// The interval a (a triangle's own) cut by b (the instance's leaf box's), by comparisons alone;
// b alone where they do not meet; an empty a stays empty (src/cpu/ray_box.rs, clip).
fn clip(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    let both = vec2<f32>(select(a.x, b.x, b.x > a.x), select(a.y, b.y, b.y < a.y));
    if both.x <= both.y {
        return both;
    }
    if a.x <= a.y {
        return b;
    }
    return a;
}

// A hit's t moved into the ray's interval over the triangle's own box (src/cpu/ray_box.rs,
// hit_t): then no box holding a hit at or before the nearest is pruned, whatever the walk.
// The caller drops the hit when the interval is empty.
fn clamp_to(t: f32, interval: vec2<f32>) -> f32 {
    // +0 for a zero lower end, whose sign max and min leave to the hardware.
    let lo = select(interval.x, 0.0, interval.x == 0.0);
    return select(select(t, interval.y, t > interval.y), lo, t < interval.x);
}

// ---- ray/triangle (src/cpu/ray_triangle.rs) ----

// `det` > 0: the triangle is counter-clockwise as seen from the ray (front-facing).
struct TriangleHit {
    hit: bool,
    t: f32,
    u: f32,
    v: f32,
    det: f32,
}

fn vertex(v: array<f32, 3>) -> vec3<f32> {
    return vec3<f32>(v[0], v[1], v[2]);
}

// Möller–Trumbore, as in the paper.
fn ray_triangle(tri: GpuTriangle, origin: vec3<f32>, dir: vec3<f32>) -> TriangleHit {
    let v0 = vertex(tri.v0);
    let v1 = vertex(tri.v1);
    let v2 = vertex(tri.v2);
    let e1 = v1 - v0;
    let e2 = v2 - v0;
    let p = cross3(dir, e2);
    let det = dot3(p, e1);
    if det == 0.0 {
        return TriangleHit(false, 0.0, 0.0, 0.0, 0.0);
    }
    let inv_det = div(1.0, det);
    let to_origin = origin - v0;
    let u = mul_unfused(dot3(p, to_origin), inv_det);
    let q = cross3(to_origin, e1);
    let v = mul_unfused(dot3(q, dir), inv_det);
    let t = dot3(q, e2) * inv_det;
    return TriangleHit(u >= 0.0 && v >= 0.0 && u + v <= 1.0, t, u, v, det);
}

// Per-ray set-up of the watertight test: the axis the ray runs along most (kz), the two others
// (kx, ky, swapped to keep the winding when the ray runs down kz), folded into three rows so that
// a vertex v (relative to the origin) maps to ray space as (dot(v, x), dot(v, y), dot(v, z)):
// x = e_kx − (d_kx/d_kz)·e_kz, y = e_ky − (d_ky/d_kz)·e_kz, z = e_kz / d_kz. Every vertex is
// mapped the same way whichever triangle it belongs to, which is what makes the test watertight.
struct Shear {
    x: vec3<f32>,
    y: vec3<f32>,
    z: vec3<f32>,
}

fn unit_axis(k: u32) -> vec3<f32> {
    return vec3<f32>(select(0.0, 1.0, k == 0u), select(0.0, 1.0, k == 1u), select(0.0, 1.0, k == 2u));
}

fn shear_for(dir: vec3<f32>) -> Shear {
    let a = abs(dir);
    var kz = 2u;
    if a.x >= a.y && a.x >= a.z {
        kz = 0u;
    } else if a.y >= a.z {
        kz = 1u;
    }
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if dir[kz] < 0.0 {
        let swap = kx;
        kx = ky;
        ky = swap;
    }
    let ez = unit_axis(kz);
    return Shear(unit_axis(kx) - div(dir[kx], dir[kz]) * ez, unit_axis(ky) - div(dir[ky], dir[kz]) * ez, vec3<f32>(div(ez.x, dir[kz]), div(ez.y, dir[kz]), div(ez.z, dir[kz])));
}

// Watertight ray/triangle test (Woop, Benthin, Wald, JCGT 2013): edge functions in a sheared
// ray space are computed identically for the two triangles sharing an edge, so a ray can never
// slip between them. Edges are inclusive.
fn ray_triangle_watertight(tri: GpuTriangle, origin: vec3<f32>, sh: Shear) -> TriangleHit {
    let a = vertex(tri.v0) - origin;
    let b = vertex(tri.v1) - origin;
    let c = vertex(tri.v2) - origin;
    let ax = dot3(a, sh.x);
    let ay = dot3(a, sh.y);
    let bx = dot3(b, sh.x);
    let by = dot3(b, sh.y);
    let cx = dot3(c, sh.x);
    let cy = dot3(c, sh.y);
    let u_edge = mul(cx, by) - mul(cy, bx);
    let v_edge = mul(ax, cy) - mul(ay, cx);
    let w_edge = mul(bx, ay) - mul(by, ax);
    let outside = (u_edge < 0.0 || v_edge < 0.0 || w_edge < 0.0) && (u_edge > 0.0 || v_edge > 0.0 || w_edge > 0.0);
    let det = u_edge + v_edge + w_edge;
    if outside || det == 0.0 {
        return TriangleHit(false, 0.0, 0.0, 0.0, 0.0);
    }
    let t_scaled = (mul(u_edge, dot3(a, sh.z)) + mul(v_edge, dot3(b, sh.z))) + mul(w_edge, dot3(c, sh.z));
    let inv_det = div(1.0, det);
    return TriangleHit(true, t_scaled * inv_det, v_edge * inv_det, w_edge * inv_det, det);
}

fn facing_allowed(det: f32, cull: u32) -> bool {
    if cull == CULL_BACK {
        return det > 0.0;
    }
    if cull == CULL_FRONT {
        return det < 0.0;
    }
    return true;
}

// ---- stackless ordered traversal (src/cpu/traverse.rs) ----

fn kind_of(node: GpuNode) -> u32 {
    return node.parent_kind & KIND_MASK;
}

fn parent_of(node: GpuNode) -> u32 {
    return node.parent_kind >> KIND_BITS;
}

// The child the ray reaches first: the left (lower) one unless the ray runs down the split axis.
fn near_child(index: u32, node: GpuNode, dir: vec3<f32>) -> u32 {
    let axis = kind_of(node) - KIND_INNER;
    if dir[axis] < 0.0 {
        return node.first;
    }
    return index + 1u;
}

fn sibling(index: u32, parent: u32, parent_node: GpuNode) -> u32 {
    if index == parent + 1u {
        return parent_node.first;
    }
    return parent + 1u;
}

// The spacing of subnormal half floats, 2^-24.
const HALF_SUBNORMAL_STEP: f32 = 5.9604645e-8;

// A finite half float the host wrote (normal, subnormal or 0), exactly as f32; by hand, as
// `unpack2x16float` needs a capability not every adapter has. A subnormal's mantissa times
// 2^-24 is exact (a power of two, and a normal f32).
fn half_to_f32(h: u32) -> f32 {
    let e = (h >> 10u) & 31u;
    if e == 0u {
        let m = f32(h & 0x3ffu) * HALF_SUBNORMAL_STEP;
        return select(m, -m, (h & 0x8000u) != 0u);
    }
    return bitcast<f32>(((h & 0x8000u) << 16u) | ((e + 112u) << 23u) | ((h & 0x3ffu) << 13u));
}

// The rest of the ray's origin after rounding to f32 (three half floats).
fn origin_lo(ray: GpuRay) -> vec3<f32> {
    return vec3<f32>(half_to_f32(ray.origin_lo.x & 0xffffu), half_to_f32(ray.origin_lo.x >> 16u), half_to_f32(ray.origin_lo.y & 0xffffu));
}

// The ray's origin in instance r's frame (src/cpu/traverse.rs, `enter_instance`).
fn instance_origin(r: GpuInstance, hi: vec3<f32>, lo: vec3<f32>) -> vec3<f32> {
    let d = (hi - vec3<f32>(r.cx, r.cy, r.cz)) + (lo - vec3<f32>(r.c_lo[0], r.c_lo[1], r.c_lo[2]));
    return vec3<f32>(dot3(r.l0, d), dot3(r.l1, d), dot3(r.l2, d));
}

fn instance_dir(r: GpuInstance, dir: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot3(r.l0, dir), dot3(r.l1, dir), dot3(r.l2, dir));
}

fn trace(ray: GpuRay, list_base: u32) -> GpuHit {
    var best = GpuHit(ray.tmax, NO_HIT, 0.0, 0.0, 0u, 0u, 0u, 0u);
    if params.node_count == 0u || !(ray.tmin <= ray.tmax) {
        return best;
    }
    let mode = ray.flags & 3u;
    // Culling needs no change in an instance's frame: a mirroring instance's faces are stored
    // so that front faces stay front faces in the world (src/instance/mod.rs).
    let cull = (ray.flags >> CULL_SHIFT) & 3u;
    let instanced = params.top_nodes != 0u;
    // The ray as the current tree sees it: the world's, or an instance's.
    let world_inv_dir = safe_inverse(ray.dir);
    let world_shear = shear_for(ray.dir);
    var origin = ray.origin;
    var dir = ray.dir;
    var inv_dir = world_inv_dir;
    var shear = world_shear;
    var inside = NO_INSTANCE;
    var instance: GpuInstance;
    var instance_leaf = 0u;
    // The world ray's interval over the entered instance's leaf box: its hits' t stay in it.
    var leaf_interval = vec2<f32>(0.0);
    // Hits need t in (tmin, limit]; limit shrinks to the nearest hit (closest), or to the
    // farthest kept hit once the all-hits list is full and has overflowed.
    var limit = ray.tmax;
    var done = false;
    var current = 0u;
    var state = FROM_PARENT;
    var iterations = 0u;
    loop {
        if iterations == params.iteration_cap {
            best.prim = CAP_REACHED;
            break;
        }
        iterations += 1u;
        let node = nodes[current];
        if state == FROM_CHILD {
            if current == 0u {
                break;
            }
            if inside != NO_INSTANCE && current == instance.root {
                // The instance's tree is done: back to its leaf and the world ray.
                current = instance_leaf;
                inside = NO_INSTANCE;
                origin = ray.origin;
                dir = ray.dir;
                inv_dir = world_inv_dir;
                shear = world_shear;
                continue;
            }
            let parent = parent_of(node);
            let parent_node = nodes[parent];
            if current == near_child(parent, parent_node, dir) {
                current = sibling(current, parent, parent_node);
                state = FROM_SIBLING;
            } else {
                current = parent;
                state = FROM_CHILD;
            }
            continue;
        }
        // Arrived from the parent or the sibling: test this node's box.
        best.box_tests += 1u;
        var descend = false;
        let node_interval = box_interval(node.min, node.max, origin, dir, inv_dir);
        if meets(node_interval, ray.tmin, limit) {
            let kind = kind_of(node);
            if kind >= KIND_INNER {
                descend = true;
            } else if instanced && inside == NO_INSTANCE {
                // A leaf of the top tree: enter its instance, unless the masks share no bit.
                let r = instances[node.first];
                if (r.mask & ray.mask) != 0u {
                    instance = r;
                    inside = node.first;
                    instance_leaf = current;
                    // In the top tree the ray is the world's: its interval over this leaf.
                    leaf_interval = node_interval;
                    origin = instance_origin(r, ray.origin, origin_lo(ray));
                    dir = instance_dir(r, ray.dir);
                    inv_dir = safe_inverse(dir);
                    shear = shear_for(dir);
                    current = r.root;
                    state = FROM_PARENT;
                    continue;
                }
            } else {
                for (var i = 0u; i < kind; i += 1u) {
                    let leaf_prim = node.first + i;
                    if params.use_masks != 0u && (triangle_masks[leaf_prim] & ray.mask) == 0u {
                        continue;
                    }
                    best.triangle_tests += 1u;
                    let tri = triangles[leaf_prim];
                    var h: TriangleHit;
                    if params.watertight != 0u {
                        h = ray_triangle_watertight(tri, origin, shear);
                    } else {
                        h = ray_triangle(tri, origin, dir);
                    }
                    if !h.hit || !facing_allowed(h.det, cull) {
                        continue;
                    }
                    var interval = triangle_interval(tri, origin, dir, inv_dir);
                    if inside != NO_INSTANCE {
                        interval = clip(interval, leaf_interval);
                    }
                    if !(interval.x <= interval.y) {
                        continue;
                    }
                    let t = clamp_to(h.t, interval);
                    if !(t > ray.tmin) || !(t <= limit) {
                        continue;
                    }
                    var prim = leaf_prim;
                    if inside != NO_INSTANCE {
                        prim = instance.prim_base + triangle_ids[leaf_prim];
                    }
                    if mode == MODE_ALL {
                        limit = insert_hit(&best, list_base, GpuHitEntry(t, prim, h.u, h.v), ray.tmax);
                    } else {
                        if !closest_accepts(best, t, prim) {
                            continue;
                        }
                        best.t = t;
                        best.prim = prim;
                        best.u = h.u;
                        best.v = h.v;
                        limit = t;
                        if mode == MODE_ANY {
                            done = true;
                            break;
                        }
                    }
                }
            }
        }
        if done {
            break;
        }
        if descend {
            current = near_child(current, node, dir);
            state = FROM_PARENT;
        } else if current == 0u {
            break;
        } else if inside != NO_INSTANCE && current == instance.root {
            // Missed the instance's root box: back to its leaf and the world ray.
            current = instance_leaf;
            inside = NO_INSTANCE;
            origin = ray.origin;
            dir = ray.dir;
            inv_dir = world_inv_dir;
            shear = world_shear;
            state = FROM_CHILD;
        } else if state == FROM_PARENT {
            let parent = parent_of(node);
            current = sibling(current, parent, nodes[parent]);
            state = FROM_SIBLING;
        } else {
            current = parent_of(node);
            state = FROM_CHILD;
        }
    }
    // The walk's own ends leave it at the root (its subtree done), done (any-hit mode) or at
    // the cap; anywhere else the driver cut the loop short (llvmpipe's iteration limit, shared
    // by a group of lanes: UNFINISHED in src/layout.rs), and the host finishes it on the twin.
    if current != 0u && !done && best.prim != CAP_REACHED {
        best.prim = UNFINISHED;
        return best;
    }
    if mode == MODE_ALL && best.count > 0u && best.prim != CAP_REACHED {
        let nearest = hit_lists[list_base];
        best.t = nearest.t;
        best.prim = nearest.prim;
        best.u = nearest.u;
        best.v = nearest.v;
    }
    return best;
}

// The tie rule (src/cpu/traverse.rs, `comes_before`): a smaller t first; equal t, the lower scene
// triangle id first, so that no answer depends on the walk or the tree.
// An instanced scene's hit ids are their own keys (they run instance by instance, file order).
fn tie_key(prim: u32) -> u32 {
    if params.top_nodes != 0u {
        return prim;
    }
    return triangle_ids[prim];
}

fn comes_before(a: GpuHitEntry, b: GpuHitEntry) -> bool {
    return a.t < b.t || (a.t == b.t && tie_key(a.prim) < tie_key(b.prim));
}

// Closest and any-hit modes: whether a hit at t <= limit replaces `best` under the tie rule.
fn closest_accepts(best: GpuHit, t: f32, prim: u32) -> bool {
    return best.prim == NO_HIT || t < best.t || tie_key(prim) < tie_key(best.prim);
}

// Inserts a hit into the ray's list, kept sorted under the tie rule; when the list is full the
// last entry is dropped and the ray is flagged as overflowing. Returns the new limit for t.
fn insert_hit(best: ptr<function, GpuHit>, base: u32, entry: GpuHitEntry, tmax: f32) -> f32 {
    let max_hits = params.max_hits;
    var slot = (*best).count;
    if slot == max_hits {
        (*best).overflow = 1u;
        slot = max_hits - 1u;
        if !comes_before(entry, hit_lists[base + slot]) {
            return hit_lists[base + slot].t;
        }
    } else {
        (*best).count += 1u;
    }
    while slot > 0u && comes_before(entry, hit_lists[base + slot - 1u]) {
        hit_lists[base + slot] = hit_lists[base + slot - 1u];
        slot -= 1u;
    }
    hit_lists[base + slot] = entry;
    if (*best).overflow != 0u {
        return hit_lists[base + max_hits - 1u].t;
    }
    return tmax;
}

// Invocations per workgroup, set by the host through the pipeline's override constants
// (src/gpu/picker.rs, `GpuPicker::with_workgroup_size`); the dispatch's row pitch follows it.
override WORKGROUP_SIZE: u32 = 64u;

@compute @workgroup_size(WORKGROUP_SIZE)
fn pick(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = gid.y * params.row_pitch + gid.x;
    if index >= params.ray_count {
        return;
    }
    hits[index] = trace(rays[index], index * params.max_hits);
}
