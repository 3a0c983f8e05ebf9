//! `raypick select` (the objects visible inside a screen rectangle) and `raypick idbuffer` (the
//! object under every pixel of a view). Both look through `--camera`, or without one through the
//! framing camera that `render` uses.

use super::camera_args::{CameraArgs, warn_invalid_rays};
use super::scene_args::{SceneArgs, parse_mask};
use super::{csv_only, make_picker, write_output};
use clap::{ArgMatches, Args};
use raypick::apps::render::{Image, SKY, object_color};
use raypick::apps::select::{NO_OBJECT, Rect, check_id_buffer_size, marquee, object_id_buffer};
use raypick::{Backend, Error};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

#[derive(Args, Debug)]
pub struct SelectArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub view: CameraArgs,
    /// The rectangle in pixels, top-left origin: columns X0..X1 and rows Y0..Y1 (X1, Y1
    /// excluded), inside the view.
    #[arg(long, required = true, num_args = 4, value_names = ["X0", "Y0", "X1", "Y1"])]
    pub rect: Vec<u32>,
    /// Cast a ray through every STEP-th pixel in each direction.
    #[arg(long, default_value_t = 1)]
    pub step: u32,
    #[command(flatten)]
    pub rays: RayArgs,
    /// Output file for the CSV rows `object,name,pixels` (default, or `-`: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct IdBufferArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub view: CameraArgs,
    #[command(flatten)]
    pub rays: RayArgs,
    /// Output file (default, or `-`: standard output). A `.png` file gets a colour picture, one colour
    /// per object (those of `render --shade object`) and the sky where nothing is hit; anything
    /// else gets CSV rows of ids, one row per image row (empty = nothing).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// With a `.png` --out: write the ids themselves instead of colours, as a 16-bit grayscale
    /// image of object id + 1 (0 = nothing), for programs to read.
    #[arg(long)]
    pub raw_ids: bool,
}

#[derive(Args, Debug)]
pub struct RayArgs {
    /// Layer mask of the rays.
    #[arg(long, value_parser = parse_mask, default_value = "0xffffffff")]
    pub ray_mask: u32,
    /// Which path answers.
    #[arg(long, value_parser = crate::cli::choice::choice::<Backend>(), default_value_t = Backend::Auto)]
    pub backend: Backend,
}

pub fn run_select(args: SelectArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    csv_only("select", args.out.as_deref())?;
    let view = args.view.view()?;
    let built = Arc::new(args.scene.build(matches)?);
    let camera = view.camera(&built);
    let rect = Rect {
        x0: args.rect[0],
        y0: args.rect[1],
        x1: args.rect[2],
        y1: args.rect[3],
    };
    let mut picker = make_picker(args.rays.backend, built.clone())?;
    let selected = marquee(
        picker.as_mut(),
        &camera,
        rect,
        args.step,
        args.rays.ray_mask,
    )?;
    // The marquee's lattice (checked by `marquee`: inside the view, step at least 1).
    let sides = |from: u32, to: u32| (to - from).div_ceil(args.step);
    let lattice = (
        (rect.x0, rect.y0),
        (sides(rect.x0, rect.x1), sides(rect.y0, rect.y1)),
        args.step,
    );
    warn_invalid_rays(&built, &camera, lattice, args.rays.ray_mask);
    write_output(args.out.as_deref(), |out| {
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
    let png = args
        .out
        .as_ref()
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")));
    if png.is_none() {
        super::no_json_out(
            "idbuffer",
            "CSV or PNG",
            ".csv or .png",
            args.out.as_deref(),
        )?;
        if args.raw_ids {
            return Err(Error::Invalid(
                "--raw-ids writes a PNG; give --out a file name ending in .png".into(),
            ));
        }
    }
    let view = args.view.view()?;
    check_id_buffer_size(view.width, view.height)?;
    let built = Arc::new(args.scene.build_checked(matches, |scene| {
        // Ids 0 ..= 65,534 are written as id + 1; 0 is nothing.
        if args.raw_ids && scene.objects().len() > usize::from(u16::MAX) {
            return Err(Error::Invalid(format!(
                "the scene has {} objects, too many for a 16-bit id image; leave out --raw-ids \
                 or write CSV",
                scene.objects().len()
            )));
        }
        Ok(())
    })?);
    let camera = view.camera(&built);
    let mut picker = make_picker(args.rays.backend, built.clone())?;
    let ids = object_id_buffer(picker.as_mut(), &camera, args.rays.ray_mask)?;
    let (w, h) = (camera.width(), camera.height());
    warn_invalid_rays(&built, &camera, ((0, 0), (w, h), 1), args.rays.ray_mask);
    match png {
        Some(path) if args.raw_ids => write_id_png(path, w, h, &ids)?,
        Some(path) => {
            let rgba = ids
                .iter()
                .flat_map(|&id| {
                    if id == NO_OBJECT {
                        SKY
                    } else {
                        object_color(id)
                    }
                })
                .collect();
            let png = Image {
                width: w,
                height: h,
                rgba,
            }
            .to_png()?;
            write_output(Some(path), |out| out.write_all(&png))?;
        }
        None => write_output(args.out.as_deref(), |out| {
            for row in ids.chunks(w as usize) {
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
        })?,
    }
    Ok(ExitCode::SUCCESS)
}

/// Writes `ids` as a 16-bit grayscale PNG of id + 1 (0 where nothing is hit).
fn write_id_png(path: &Path, width: u32, height: u32, ids: &[u32]) -> Result<(), Error> {
    let pixels: Vec<u8> = ids
        .iter()
        .flat_map(|&id| (if id == NO_OBJECT { 0u16 } else { id as u16 + 1 }).to_be_bytes())
        .collect();
    // Encoded in memory, then written with its errors seen: a writer dropped unfinished
    // ignored them (a full disk or `ulimit -f` left a cut file and exit 0).
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    let png_error = |e: png::EncodingError| Error::Invalid(format!("{}: {e}", path.display()));
    let mut writer = encoder.write_header().map_err(png_error)?;
    writer.write_image_data(&pixels).map_err(png_error)?;
    writer.finish().map_err(png_error)?;
    write_output(Some(path), |out| out.write_all(&bytes))
}

fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}
