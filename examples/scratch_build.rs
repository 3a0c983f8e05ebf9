use raypick::synthetic::{hills, terrain};
use raypick::{BuildOptions, Builder, Bvh, GridShape, Scene};
fn main() {
    let n = 1001usize;
    let mut scene = Scene::new();
    scene
        .add_grid_mesh(
            "t",
            terrain(n, n, 500_000.0, 4_100_000.0, 1.0, hills),
            GridShape {
                columns: n as u32,
                rows: n as u32,
            },
        )
        .unwrap();
    for _ in 0..20 {
        std::hint::black_box(
            Bvh::build(
                &scene,
                &BuildOptions {
                    builder: Builder::Grid,
                    ..Default::default()
                },
            )
            .unwrap(),
        );
    }
}
