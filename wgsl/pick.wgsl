// Closest-hit picking: one invocation per ray.
// Stackless, ordered traversal of the median-cut tree with parent links and a three-state
// automaton (Hapala et al. 2011), Möller–Trumbore per triangle.
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
}

struct GpuHit {
    t: f32,
    prim: u32,
    u: f32,
    v: f32,
    box_tests: u32,
    triangle_tests: u32,
}

struct GpuParams {
    ray_count: u32,
    node_count: u32,
    iteration_cap: u32,
    row_pitch: u32,
}

@group(0) @binding(0) var<uniform> params: GpuParams;
@group(0) @binding(1) var<storage, read> nodes: array<GpuNode>;
@group(0) @binding(2) var<storage, read> triangles: array<GpuTriangle>;
@group(0) @binding(3) var<storage, read> rays: array<GpuRay>;
@group(0) @binding(4) var<storage, read_write> hits: array<GpuHit>;

const KIND_INNER: u32 = 16u;
const KIND_BITS: u32 = 5u;
const KIND_MASK: u32 = 31u;
const NO_HIT: u32 = 0xffffffffu;
const CAP_REACHED: u32 = 0xfffffffeu;
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

// ---- ray/box (src/cpu/ray_box.rs) ----

fn safe_inverse(dir: vec3<f32>) -> vec3<f32> {
    let magnitude = max(abs(dir), vec3<f32>(MIN_DIR));
    let sign = select(vec3<f32>(-1.0), vec3<f32>(1.0), dir >= vec3<f32>(0.0));
    return sign / magnitude;
}

fn ray_box(node: GpuNode, origin: vec3<f32>, dir: vec3<f32>, inv_dir: vec3<f32>, tmin: f32, tmax: f32) -> bool {
    let t0 = (node.min - origin) * inv_dir;
    let t1 = (node.max - origin) * inv_dir;
    // A ray parallel to a slab and inside it (faces included) is unconstrained by that slab;
    // without this, an origin exactly on a face would give 0 * inverse = 0 and cull the box.
    let free = abs(dir) < vec3<f32>(MIN_DIR) & origin >= node.min & origin <= node.max;
    let near = select(min(t0, t1), vec3<f32>(-HUGE), free);
    let far = select(max(t0, t1), vec3<f32>(HUGE), free);
    let t_near = max(max(near.x, near.y), near.z);
    let t_far = min(min(far.x, far.y), far.z);
    return max(t_near - abs(t_near) * BOX_PAD, tmin) <= min(t_far + abs(t_far) * BOX_PAD, tmax);
}

// ---- ray/triangle, Möller–Trumbore (src/cpu/ray_triangle.rs) ----

struct TriangleHit {
    hit: bool,
    t: f32,
    u: f32,
    v: f32,
}

fn ray_triangle(tri: GpuTriangle, origin: vec3<f32>, dir: vec3<f32>) -> TriangleHit {
    let v0 = vec3<f32>(tri.v0[0], tri.v0[1], tri.v0[2]);
    let v1 = vec3<f32>(tri.v1[0], tri.v1[1], tri.v1[2]);
    let v2 = vec3<f32>(tri.v2[0], tri.v2[1], tri.v2[2]);
    let e1 = v1 - v0;
    let e2 = v2 - v0;
    let p = cross(dir, e2);
    let det = dot(p, e1);
    if det == 0.0 {
        return TriangleHit(false, 0.0, 0.0, 0.0);
    }
    let inv_det = 1.0 / det;
    let to_origin = origin - v0;
    let u = dot(p, to_origin) * inv_det;
    let q = cross(to_origin, e1);
    let v = dot(q, dir) * inv_det;
    let t = dot(q, e2) * inv_det;
    return TriangleHit(u >= 0.0 && v >= 0.0 && u + v <= 1.0, t, u, v);
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

fn trace(ray: GpuRay) -> GpuHit {
    var best = GpuHit(ray.tmax, NO_HIT, 0.0, 0.0, 0u, 0u);
    if params.node_count == 0u || !(ray.tmin <= ray.tmax) {
        return best;
    }
    let inv_dir = safe_inverse(ray.dir);
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
            let parent = parent_of(node);
            let parent_node = nodes[parent];
            if current == near_child(parent, parent_node, ray.dir) {
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
        if ray_box(node, ray.origin, ray.dir, inv_dir, ray.tmin, best.t) {
            let kind = kind_of(node);
            if kind >= KIND_INNER {
                descend = true;
            } else {
                for (var i = 0u; i < kind; i += 1u) {
                    let prim = node.first + i;
                    best.triangle_tests += 1u;
                    let h = ray_triangle(triangles[prim], ray.origin, ray.dir);
                    if h.hit && h.t > ray.tmin && h.t <= best.t {
                        best.t = h.t;
                        best.prim = prim;
                        best.u = h.u;
                        best.v = h.v;
                    }
                }
            }
        }
        if descend {
            current = near_child(current, node, ray.dir);
            state = FROM_PARENT;
        } else if current == 0u {
            break;
        } else if state == FROM_PARENT {
            let parent = parent_of(node);
            current = sibling(current, parent, nodes[parent]);
            state = FROM_SIBLING;
        } else {
            current = parent_of(node);
            state = FROM_CHILD;
        }
    }
    return best;
}

@compute @workgroup_size(64)
fn pick(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = gid.y * params.row_pitch + gid.x;
    if index >= params.ray_count {
        return;
    }
    hits[index] = trace(rays[index]);
}
