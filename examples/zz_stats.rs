use raypick::io::obj::load_obj;
use raypick::io::ray_file::load_rays;
use raypick::picker::Tracer;
use raypick::{BuildOptions, BuiltScene, CpuPicker, Query, Ray, Scene};
use std::path::Path;
use std::sync::Arc;
fn main() -> Result<(), raypick::Error> {
    let args: Vec<String> = std::env::args().collect();
    let rays: Vec<Ray> = load_rays(Path::new(&args[2]))?
        .into_iter()
        .map(|r| Ray::new(r.origin, r.dir).with_range(0.0, r.tmax.unwrap_or(f64::INFINITY)))
        .collect();
    let scene = Scene::from_meshes([("mesh".to_string(), load_obj(Path::new(&args[1]))?)])?;
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default())?);
    let mut picker = CpuPicker::new(built.clone());
    let query = Query::default();
    let (local, _) = raypick::frame::scene_rays(built.frame(), &rays, &query);
    let (found, _) = picker.trace(&local, &built.settings(&query))?;
    let n = found.len() as f64;
    let b: f64 = found.iter().map(|f| f.box_tests as f64).sum::<f64>() / n;
    let i: f64 = found.iter().map(|f| f.triangle_tests as f64).sum::<f64>() / n;
    let w = built.wide()?;
    println!(
        "box tests {b:.1}, triangle tests {i:.1} per ray; wide nodes {}, depth {}",
        w.nodes.len(),
        w.depth
    );
    Ok(())
}
