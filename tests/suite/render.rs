//! Ray-cast rendering through the public API: the built-in example scene rendered on the CPU and
//! the GPU picker (lavapipe on machines without a GPU; never skipped) gives the same image for
//! object shading and nearly the same for normal and depth shading; a top-down view of the tower
//! shows the tower's colour; rays into the sky show the sky; the sun lights the north-west; near
//! is light in depth shading; PNG output decodes back to the same pixels.

use crate::common;

use glam::DVec3;
use raypick::apps::camera::Camera;
use raypick::apps::render::{Image, SKY, Shade, object_color, render};
use raypick::check::synthetic::{box_mesh, example_scene, hills};
use raypick::{BuildOptions, BuiltScene, CpuPicker, GpuPicker, Picker, Scene};
use std::sync::{Arc, OnceLock};

const SHADES: [Shade; 3] = [Shade::Normal, Shade::Depth, Shade::Object];

/// The example scene, built once.
fn example() -> Arc<BuiltScene> {
    static BUILT: OnceLock<Arc<BuiltScene>> = OnceLock::new();
    BUILT
        .get_or_init(|| {
            Arc::new(BuiltScene::new(example_scene(), &BuildOptions::default()).expect("build"))
        })
        .clone()
}

/// The default "frame the scene" camera over the example, at a small size.
fn framing_camera(width: u32, height: u32) -> Camera {
    let (min, max) = example().scene.bounds().expect("bounds");
    Camera::frame_bounds(min, max, width, height)
}

fn cpu() -> CpuPicker {
    CpuPicker::new(example())
}

fn gpu() -> GpuPicker {
    GpuPicker::new(common::gpu(), example()).expect("gpu picker")
}

/// The pixels of `a` and `b` whose channels differ by more than `tolerance`, as
/// `(index, a, b)`.
fn differing(a: &Image, b: &Image, tolerance: u8) -> Vec<(usize, [u8; 4], [u8; 4])> {
    assert_eq!((a.width, a.height), (b.width, b.height));
    a.rgba
        .chunks(4)
        .zip(b.rgba.chunks(4))
        .enumerate()
        .filter(|(_, (p, q))| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > tolerance))
        .map(|(i, (p, q))| (i, [p[0], p[1], p[2], p[3]], [q[0], q[1], q[2], q[3]]))
        .collect()
}

fn luminance(p: [u8; 4]) -> f64 {
    0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2])
}

#[test]
fn image_has_the_camera_size_and_opaque_pixels() {
    let camera = framing_camera(64, 48);
    for shade in SHADES {
        let image = render(&mut cpu(), &camera, shade).expect("render");
        assert_eq!((image.width, image.height), (64, 48));
        assert_eq!(image.rgba.len(), 64 * 48 * 4);
        assert!(image.rgba.chunks(4).all(|p| p[3] == 255), "{shade:?}");
        let sky = image.rgba.chunks(4).filter(|p| *p == SKY).count();
        assert!(
            sky > 0 && sky < 64 * 48,
            "{shade:?}: the framing view shows both scene and sky ({sky} sky pixels)"
        );
    }
}

#[test]
fn cpu_and_gpu_render_the_same_image() {
    let camera = framing_camera(64, 48);
    let (mut cpu, mut gpu) = (cpu(), gpu());
    for shade in SHADES {
        let on_cpu = render(&mut cpu, &camera, shade).expect("cpu render");
        let on_gpu = render(&mut gpu, &camera, shade).expect("gpu render");
        if shade == Shade::Object {
            assert_eq!(
                differing(&on_cpu, &on_gpu, 0),
                vec![],
                "object shading must be identical on both backends"
            );
        } else {
            // Both paths refine hits in f64 against the same triangles, so pixels agree; allow a
            // couple of levels of rounding, and a rare pixel whose ray grazes an edge shared by
            // triangles of different slope.
            let off = differing(&on_cpu, &on_gpu, 2);
            assert!(
                off.len() <= 64 * 48 / 200,
                "{shade:?}: {} of {} pixels differ by more than 2 levels: {:?}",
                off.len(),
                64 * 48,
                &off[..off.len().min(5)]
            );
        }
        eprintln!(
            "{shade:?}: {} pixels differ at all between CPU and GPU",
            differing(&on_cpu, &on_gpu, 0).len()
        );
    }
}

#[test]
fn top_down_view_of_the_tower_shows_the_tower() {
    // The tower stands on x 30..38, y 40..48.
    let (x, y) = (34.0, 44.0);
    let camera = Camera::perspective(
        DVec3::new(x, y, 200.0),
        DVec3::new(x, y, hills(x, y)),
        DVec3::Y,
        10.0,
        64,
        48,
    )
    .expect("camera");
    for (name, picker) in [
        ("cpu", &mut cpu() as &mut dyn Picker),
        ("gpu", &mut gpu() as &mut dyn Picker),
    ] {
        let image = render(picker, &camera, Shade::Object).expect("render");
        assert_eq!(image.pixel(32, 24), Some(object_color(1)), "{name}");
        assert_eq!(image.pixel(0, 0), Some(object_color(0)), "{name}: terrain");
        assert_ne!(object_color(0), object_color(1));
        // Normal shading: the tower's flat roof faces the sky, so it is lit, not sky coloured.
        let image = render(picker, &camera, Shade::Normal).expect("render");
        let roof = image.pixel(32, 24).expect("pixel");
        assert_ne!(roof, SKY, "{name}");
        assert!(luminance(roof) > 100.0, "{name}: roof {roof:?}");
    }
}

#[test]
fn looking_at_the_sky_shows_the_sky() {
    let up = Camera::perspective(
        DVec3::new(48.0, 48.0, 100.0),
        DVec3::new(48.0, 48.0, 200.0),
        DVec3::Y,
        60.0,
        16,
        12,
    )
    .expect("camera");
    // A horizontal view from above every hill: the upper half sees only sky.
    let horizon = Camera::perspective(
        DVec3::new(48.0, -100.0, 40.0),
        DVec3::new(48.0, 0.0, 40.0),
        DVec3::Z,
        40.0,
        16,
        12,
    )
    .expect("camera");
    for (name, picker) in [
        ("cpu", &mut cpu() as &mut dyn Picker),
        ("gpu", &mut gpu() as &mut dyn Picker),
    ] {
        for shade in SHADES {
            let image = render(picker, &up, shade).expect("render");
            assert!(
                image.rgba.chunks(4).all(|p| p == SKY),
                "{name} {shade:?}: looking up"
            );
            let image = render(picker, &horizon, shade).expect("render");
            for j in 0..6 {
                for i in 0..16 {
                    assert_eq!(image.pixel(i, j), Some(SKY), "{name} {shade:?} ({i}, {j})");
                }
            }
            assert!(
                (0..16).any(|i| image.pixel(i, 11) != Some(SKY)),
                "{name} {shade:?}: the bottom row sees the scene"
            );
        }
    }
}

#[test]
fn the_sun_lights_the_north_west() {
    // A box seen from the south-west and above shows its top, west and south faces. With the
    // sun in the north-west at 45°, the top (cos 45°) is brightest, the west face (cos 60°) next,
    // and the south face gets only ambient light.
    let scene = Scene::from_meshes([(
        "box".to_string(),
        box_mesh(DVec3::ZERO, DVec3::new(10.0, 10.0, 10.0)),
    )])
    .expect("scene");
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).expect("build"));
    let camera = Camera::perspective(
        DVec3::new(-25.0, -30.0, 35.0),
        DVec3::splat(5.0),
        DVec3::Z,
        40.0,
        64,
        48,
    )
    .expect("camera");
    let mut picker = CpuPicker::new(built);
    let image = render(&mut picker, &camera, Shade::Normal).expect("render");
    let rays: Vec<_> = camera.pixel_center_rays().collect();
    let hits = picker.pick(&rays).expect("pick");
    let face_light = |normal: DVec3| {
        let lums: Vec<f64> = hits
            .iter()
            .enumerate()
            .filter(|(_, h)| h.hit && h.normal.dot(normal) > 0.999)
            .map(|(k, _)| luminance(image.pixel(k as u32 % 64, k as u32 / 64).expect("pixel")))
            .collect();
        assert!(lums.len() > 20, "face {normal} is seen");
        lums.iter().sum::<f64>() / lums.len() as f64
    };
    let (top, west, south) = (
        face_light(DVec3::Z),
        face_light(DVec3::NEG_X),
        face_light(DVec3::NEG_Y),
    );
    assert!(
        top > west && west > south,
        "top {top}, west {west}, south {south}"
    );
}

#[test]
fn depth_is_light_near_and_dark_far() {
    let camera = framing_camera(64, 48);
    let image = render(&mut cpu(), &camera, Shade::Depth).expect("render");
    let rays: Vec<_> = camera.pixel_center_rays().collect();
    let hits = cpu().pick(&rays).expect("pick");
    let seen: Vec<(f64, f64)> = hits
        .iter()
        .enumerate()
        .filter(|(_, h)| h.hit)
        .map(|(k, h)| {
            let p = image.pixel(k as u32 % 64, k as u32 / 64).expect("pixel");
            assert!(p[0] == p[1] && p[1] == p[2], "gray: {p:?}");
            (h.t, f64::from(p[0]))
        })
        .collect();
    let nearest = seen
        .iter()
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .expect("hits");
    let farthest = seen
        .iter()
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .expect("hits");
    assert_eq!(nearest.1, 255.0, "the nearest hit is white");
    assert!(
        farthest.1 < 80.0,
        "the farthest hit is dark: {}",
        farthest.1
    );
    // Gray never gets lighter with distance.
    let mut by_t = seen.clone();
    by_t.sort_by(|a, b| a.0.total_cmp(&b.0));
    assert!(by_t.windows(2).all(|w| w[1].1 <= w[0].1));
}

#[test]
fn png_round_trip_decodes_to_the_same_pixels() {
    let image = render(&mut cpu(), &framing_camera(64, 48), Shade::Normal).expect("render");
    let bytes = image.to_png().expect("encode");
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .expect("png header");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("png data");
    assert_eq!((info.width, info.height), (64, 48));
    assert_eq!(
        (info.color_type, info.bit_depth),
        (png::ColorType::Rgba, png::BitDepth::Eight)
    );
    assert_eq!(&buf[..info.buffer_size()], &image.rgba[..]);

    let path = std::env::temp_dir().join(format!("raypick-render-{}.png", std::process::id()));
    image.save_png(&path).expect("save");
    let saved = std::fs::read(&path).expect("read back");
    std::fs::remove_file(&path).ok();
    assert_eq!(saved, image.to_png().expect("encode"));
}

#[test]
fn malformed_images_and_unwritable_paths_are_errors() {
    let bad = Image {
        width: 4,
        height: 4,
        rgba: vec![0; 4 * 4 * 4 - 1],
    };
    assert!(matches!(bad.to_png(), Err(raypick::Error::Invalid(_))));
    let empty = Image {
        width: 0,
        height: 4,
        rgba: Vec::new(),
    };
    assert!(empty.to_png().is_err());
    let good = Image {
        width: 1,
        height: 1,
        rgba: vec![1, 2, 3, 255],
    };
    let missing = std::path::Path::new("/nonexistent-raypick-dir/out.png");
    match good.save_png(missing) {
        Err(raypick::Error::Io { path, .. }) => assert!(path.contains("nonexistent")),
        other => panic!("expected an I/O error, got {other:?}"),
    }
}

/// The image and the id buffer (their rays made on all cores) show each pixel's own answer, in
/// rows: object shading and the id buffer against the hits of `pixel_center_rays` picked row by
/// row, on a view of odd sides.
#[test]
fn each_pixel_shows_its_own_rays_answer() {
    use raypick::apps::select::{NO_OBJECT, object_id_buffer};
    let (width, height) = (37, 23);
    let camera = framing_camera(width, height);
    let mut picker = cpu();
    let rows: Vec<_> = camera.pixel_center_rays().collect();
    let hits = picker.pick(&rows).expect("pick");
    assert!(hits.iter().any(|h| h.hit) && hits.iter().any(|h| !h.hit));
    let image = render(&mut picker, &camera, Shade::Object).expect("render");
    let expected: Vec<u8> = hits
        .iter()
        .flat_map(|h| if h.hit { object_color(h.object) } else { SKY })
        .collect();
    assert_eq!(image.rgba, expected);
    let ids = object_id_buffer(&mut picker, &camera, u32::MAX).expect("id buffer");
    let expected: Vec<u32> = hits
        .iter()
        .map(|h| if h.hit { h.object } else { NO_OBJECT })
        .collect();
    assert_eq!(ids, expected);
}

/// A marquee samples every `step`-th pixel from its first column and row up to its last,
/// counted from the id buffer of the same view: a range of 7 pixels at step 2 samples 4 of
/// them (a mutation round rounded the count down and no test saw it).
#[test]
fn a_marquee_counts_the_pixels_it_samples() {
    use raypick::apps::select::{NO_OBJECT, Rect, marquee, object_id_buffer};
    use std::collections::BTreeMap;
    let (width, height) = (37, 23);
    let camera = framing_camera(width, height);
    let mut picker = cpu();
    let ids = object_id_buffer(&mut picker, &camera, u32::MAX).expect("id buffer");
    // How many of a rect's sampled pixels show an object, and how many of those lie in its last
    // sampled column or row, which a count rounded down leaves out.
    let mut in_last_lines = 0;
    for (x0, x1, y0, y1, step) in [
        (16, 19, 0, 23, 2),
        (10, 17, 5, 18, 2),
        (1, 37, 0, 23, 3),
        (0, 37, 2, 21, 4),
        (12, 25, 10, 11, 1),
    ] {
        let mut expected: BTreeMap<u32, u32> = BTreeMap::new();
        for y in (y0..y1).step_by(step as usize) {
            for x in (x0..x1).step_by(step as usize) {
                let id = ids[(y * width + x) as usize];
                if id != NO_OBJECT {
                    *expected.entry(id).or_default() += 1;
                    let last = |a: u32, a1: u32| a + step >= a1;
                    in_last_lines += usize::from(last(x, x1) || last(y, y1));
                }
            }
        }
        let rect = Rect { x0, x1, y0, y1 };
        let got: BTreeMap<u32, u32> = marquee(&mut picker, &camera, rect, step, u32::MAX)
            .expect("marquee")
            .into_iter()
            .map(|s| (s.object, s.pixels))
            .collect();
        assert!(
            !expected.is_empty(),
            "{x0}..{x1} × {y0}..{y1} sees something"
        );
        assert_eq!(got, expected, "{x0}..{x1} × {y0}..{y1} step {step}");
    }
    assert!(in_last_lines > 0, "the last sampled lines show objects");
}
