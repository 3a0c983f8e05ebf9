//! `raypick select` (the objects visible inside a screen rectangle) and `raypick idbuffer` (the
//! object under every pixel of a view).

use super::scene_args::{SceneArgs, parse_mask};
use super::{make_picker, write_output};
use clap::{ArgMatches, Args};
use raypick::apps::camera::Camera;
use raypick::apps::select::{NO_OBJECT, Rect, check_id_buffer_size, marquee, object_id_buffer};
use raypick::{Backend, Error};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

#[derive(Args, Debug)]
pub struct SelectArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Camera file (JSON).
    #[arg(long)]
    pub camera: PathBuf,
    /// The rectangle in pixels, top-left origin: columns X0..X1 and rows Y0..Y1 (X1, Y1 excluded).
    #[arg(long, required = true, num_args = 4, value_names = ["X0", "Y0", "X1", "Y1"])]
    pub rect: Vec<u32>,
    /// Cast a ray through every STEP-th pixel in each direction.
    #[arg(long, default_value_t = 1)]
    pub step: u32,
    #[command(flatten)]
    pub view: ViewArgs,
}

#[derive(Args, Debug)]
pub struct IdBufferArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Camera file (JSON).
    #[arg(long)]
    pub camera: PathBuf,
    #[command(flatten)]
    pub view: ViewArgs,
}

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Layer mask of the rays.
    #[arg(long, value_parser = parse_mask, default_value = "0xffffffff")]
    pub ray_mask: u32,
    /// Which path answers.
    #[arg(long, value_parser = crate::cli::choice::choice::<Backend>(), default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Output file (default: standard output). For idbuffer, a `.png` file gets a 16-bit
    /// grayscale image of object id + 1 (0 = nothing); anything else gets CSV rows of ids
    /// (empty = nothing).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run_select(args: SelectArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    let camera = Camera::from_json_file(&args.camera)?;
    let built = Arc::new(args.scene.build(matches)?);
    let rect = Rect {
        x0: args.rect[0],
        y0: args.rect[1],
        x1: args.rect[2],
        y1: args.rect[3],
    };
    let mut picker = make_picker(args.view.backend, built.clone())?;
    let selected = marquee(
        picker.as_mut(),
        &camera,
        rect,
        args.step,
        args.view.ray_mask,
    )?;
    write_output(args.view.out.as_deref(), |out| {
        writeln!(out, "object,name,pixels")?;
        for s in &selected {
            let name = &built.scene.objects()[s.object as usize].name;
            writeln!(out, "{},{},{}", s.object, csv_field(name), s.pixels)?;
        }
        Ok(())
    })?;
    Ok(ExitCode::SUCCESS)
}

pub fn run_idbuffer(args: IdBufferArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    let camera = Camera::from_json_file(&args.camera)?;
    check_id_buffer_size(camera.width(), camera.height())?;
    let built = Arc::new(args.scene.build(matches)?);
    let mut picker = make_picker(args.view.backend, built.clone())?;
    let ids = object_id_buffer(picker.as_mut(), &camera, args.view.ray_mask)?;
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let png = args
        .view
        .out
        .as_ref()
        .is_some_and(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")));
    if png {
        if built.scene.objects().len() >= u16::MAX as usize {
            return Err(Error::Invalid(
                "too many objects for a 16-bit id image; write CSV instead".into(),
            ));
        }
        let path = args.view.out.as_ref().expect("png implies --out");
        let pixels: Vec<u8> = ids
            .iter()
            .flat_map(|&id| (if id == NO_OBJECT { 0u16 } else { id as u16 + 1 }).to_be_bytes())
            .collect();
        let io_error = |e: std::io::Error| Error::Io {
            path: path.display().to_string(),
            source: e,
        };
        let file = std::fs::File::create(path).map_err(io_error)?;
        let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), w as u32, h as u32);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Sixteen);
        let png_error = |e: png::EncodingError| Error::Invalid(format!("{}: {e}", path.display()));
        encoder
            .write_header()
            .map_err(png_error)?
            .write_image_data(&pixels)
            .map_err(png_error)?;
    } else {
        write_output(args.view.out.as_deref(), |out| {
            for row in ids.chunks(w) {
                let line: Vec<String> = row
                    .iter()
                    .map(|&id| {
                        if id == NO_OBJECT {
                            String::new()
                        } else {
                            id.to_string()
                        }
                    })
                    .collect();
                writeln!(out, "{}", line.join(","))?;
            }
            Ok(())
        })?;
    }
    Ok(ExitCode::SUCCESS)
}

fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}
