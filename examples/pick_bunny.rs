//! Library example: load the bunny, build the tree, pick a few rays on the GPU (or the CPU when
//! no adapter is available) and print what is under them.
//!
//! `cargo run --release --example pick_bunny`

use raypick::io::obj::load_obj;
use raypick::{
    BuildOptions, BuiltScene, CpuPicker, DVec3, GpuContext, GpuPicker, Picker, Ray, Scene,
};
use std::path::Path;
use std::sync::Arc;

fn main() -> Result<(), raypick::Error> {
    let mesh = load_obj(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj"))?;
    let scene = Scene::from_meshes([("bunny".to_string(), mesh)])?;
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default())?);
    let mut picker: Box<dyn Picker> = match GpuContext::new() {
        Ok(context) => Box::new(GpuPicker::new(&context, built)?),
        Err(e) => {
            eprintln!("no GPU ({e}); using the CPU path");
            Box::new(CpuPicker::new(built))
        }
    };
    let rays: Vec<Ray> = (0..5)
        .map(|i| Ray::new(DVec3::new(-1.0 + 0.5 * i as f64, 1.5, 20.0), DVec3::NEG_Z))
        .collect();
    for (ray, hit) in rays.iter().zip(picker.pick(&rays)?) {
        if hit.hit {
            println!(
                "{:?} -> triangle {} at {:?} (t = {})",
                ray.origin, hit.triangle, hit.position, hit.t
            );
        } else {
            println!("{:?} -> miss", ray.origin);
        }
    }
    Ok(())
}
