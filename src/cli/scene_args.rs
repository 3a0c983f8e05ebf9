//! Scene options shared by every command: `--scene FILE [--mask M]` (repeatable; a `--mask`
//! applies to the `--scene` just before it), `--scenes DESCRIPTION.json`, and the builder settings.

use clap::{ArgMatches, Args};
use raypick::check::synthetic::example_scene;
use raypick::io::scene_files::{Loaded, SceneFile, load_description, load_instanced, load_scene};
use raypick::{BuildOptions, Builder, BuiltScene, Error, Scene, SplitAxis};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct SceneArgs {
    /// Scene file: a mesh (Wavefront .obj, PLY .ply or .ply.gz, STL .stl; one object each), glTF
    /// 2.0 .gltf/.glb (one object per mesh primitive, node transforms applied), or an elevation
    /// grid (.asc ESRI ASCII grid, .tif/.tiff GeoTIFF; one terrain object). Repeat for several.
    /// A built scene saved by `raypick build` (.rpk) is given alone: it loads with its trees,
    /// with no rebuild (its masks and builder are those it was built with).
    /// Object ids follow the order given. Default: the built-in example scene (a height-grid
    /// terrain with two buildings; `raypick example` writes it as files).
    #[arg(long, action = clap::ArgAction::Append)]
    pub scene: Vec<PathBuf>,
    /// Layer mask (decimal, 0x.. or 0b..) for the objects of the `--scene` just before it.
    #[arg(long, value_parser = parse_mask, action = clap::ArgAction::Append)]
    pub mask: Vec<u32>,
    /// A scene description file (JSON): `{"objects": [{"file": "dem.asc", "mask": 1}, ...]}`.
    #[arg(long, conflicts_with = "scene")]
    pub scenes: Option<PathBuf>,
    /// Tree builder: `grid` cuts a height grid into blocks and builds over them (the default for
    /// a scene that is one grid); `median-cut` splits triangles (the default otherwise).
    #[arg(long, value_parser = crate::cli::choice::choice::<Builder>(), default_value_t = BuildOptions::default().builder)]
    pub builder: Builder,
    /// Split-axis policy of the median-cut builder.
    #[arg(long, value_parser = crate::cli::choice::choice::<SplitAxis>(), default_value_t = BuildOptions::default().split_axis)]
    pub split: SplitAxis,
    /// Most triangles per leaf (1 ..= 15).
    #[arg(long, default_value_t = BuildOptions::default().leaf_size)]
    pub leaf_size: u32,
}

/// "instances of N mesh(es)" for an instanced scene, as the commands' summary lines say it.
pub fn instances_of(built: &BuiltScene) -> Option<String> {
    built.instances().map(|i| {
        let meshes = i.meshes().len();
        format!(
            "instances of {meshes} mesh{}",
            if meshes == 1 { "" } else { "es" }
        )
    })
}

/// Parses a mask in decimal, hexadecimal (`0x`) or binary (`0b`).
pub fn parse_mask(text: &str) -> Result<u32, String> {
    let t = text.trim();
    let parsed = if let Some(hex) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        u32::from_str_radix(hex, 16)
    } else if let Some(bin) = t.strip_prefix("0b").or_else(|| t.strip_prefix("0B")) {
        u32::from_str_radix(bin, 2)
    } else {
        t.parse::<u32>()
    };
    parsed.map_err(|_| {
        format!(
            "'{}' is not a 32-bit mask (decimal, 0x.. or 0b..)",
            raypick::budget::quote(text)
        )
    })
}

impl SceneArgs {
    /// The files with their masks; `matches` are the subcommand's, used to pair each `--mask`
    /// with the `--scene` before it. An `--out` that names a buffer one of them reads is refused
    /// here, where the files are known.
    pub fn files(&self, matches: &ArgMatches) -> Result<Vec<SceneFile>, Error> {
        let files = self.listed(matches)?;
        super::out_guard::refuse_gltf_buffers(matches, files.iter().map(|f| f.file.as_path()))?;
        Ok(files)
    }

    /// The files a description lists, or the `--scene` files with their `--mask`s.
    fn listed(&self, matches: &ArgMatches) -> Result<Vec<SceneFile>, Error> {
        if let Some(path) = &self.scenes {
            if !self.mask.is_empty() {
                // clap keeps --mask from coming before any --scene, not from coming with
                // --scenes: it was ignored there.
                return Err(Error::Invalid(format!(
                    "--mask does not apply to --scenes {}: a scene description gives each file's \
                     mask itself (\"mask\")",
                    path.display()
                )));
            }
            let files = load_description(path)?;
            super::out_guard::refuse_listed(matches, path, files.iter().map(|f| f.file.as_path()))?;
            return Ok(files);
        }
        let scene_at: Vec<usize> = matches
            .indices_of("scene")
            .map(|i| i.collect())
            .unwrap_or_default();
        let mask_at: Vec<usize> = matches
            .indices_of("mask")
            .map(|i| i.collect())
            .unwrap_or_default();
        let mut files: Vec<SceneFile> = self
            .scene
            .iter()
            .map(|file| SceneFile {
                file: file.clone(),
                mask: None,
                transform: None,
            })
            .collect();
        for (mask, at) in self.mask.iter().zip(mask_at) {
            let Some(k) = scene_at.iter().rposition(|&s| s < at) else {
                return Err(Error::Invalid(format!(
                    "--mask {mask} comes before any --scene"
                )));
            };
            if files[k].mask.replace(*mask).is_some() {
                return Err(Error::Invalid(format!(
                    "{} has two --mask values",
                    files[k].file.display()
                )));
            }
        }
        Ok(files)
    }

    /// The builder settings these arguments name.
    pub fn build_options(&self) -> BuildOptions {
        BuildOptions {
            builder: self.builder,
            split_axis: self.split,
            leaf_size: self.leaf_size,
        }
    }

    /// The built scene of a `.rpk` file given as the only `--scene` (`None` when no `.rpk` is
    /// given); an error when a `.rpk` comes with other scene files, masks or builder options.
    fn saved(
        &self,
        matches: &ArgMatches,
        placement: Placement,
    ) -> Result<Option<BuiltScene>, Error> {
        let Some(rpk) = self
            .scene
            .iter()
            .find(|p| raypick::rpk::has_rpk_extension(p) || raypick::rpk::is_rpk(p))
        else {
            return Ok(None);
        };
        let explicit =
            |id: &str| matches.value_source(id) == Some(clap::parser::ValueSource::CommandLine);
        if self.scene.len() > 1 || !self.mask.is_empty() {
            return Err(Error::Invalid(format!(
                "{} is a built scene (.rpk): give it as the only --scene, without --mask",
                rpk.display()
            )));
        }
        if ["builder", "split", "leaf_size"].into_iter().any(explicit) {
            return Err(Error::Invalid(format!(
                "{} is a built scene (.rpk) with its trees: --builder, --split and --leaf-size \
                 apply when building (`raypick build`)",
                rpk.display()
            )));
        }
        super::progress::phase("loading the built scene", || match placement {
            // SAFETY: a one-shot command picks and exits; raypick itself never writes into a
            // saved scene in place (`build --out` renames a new file over it), and a file
            // shortened by another program meanwhile stops the process with exit 2
            // (`crate::cli::mapped_file_guard`).
            Placement::InPlace => unsafe { raypick::rpk::load_in_place(rpk) },
            Placement::Owned => raypick::rpk::load(rpk),
        })
        .map(Some)
    }

    /// Loads the scene (or the example) and builds the tree, for a command that picks and
    /// exits: a saved scene is used in place ([`raypick::rpk::load_in_place`]).
    pub fn build(&self, matches: &ArgMatches) -> Result<BuiltScene, Error> {
        self.build_timed(matches).map(|(built, _, _)| built)
    }

    /// [`SceneArgs::build`] with `check` run on the loaded scene before its tree is built: a
    /// command's refusal of a scene (too many objects for its output, say) costs no build.
    pub fn build_checked(
        &self,
        matches: &ArgMatches,
        check: impl Fn(&Scene) -> Result<(), Error>,
    ) -> Result<BuiltScene, Error> {
        self.build_placed(matches, Placement::InPlace, &check)
            .map(|(built, _, _)| built)
    }

    /// [`SceneArgs::build_timed`] for a command that picks instanced scenes (pick, verify,
    /// serve): when a file is listed several times, or glTF nodes share a mesh, each mesh is
    /// built once and placed by its transforms ([`BuiltScene::instanced`]), with the same objects
    /// in the same order as the copies [`SceneArgs::build`] makes. `owned`: a saved scene is
    /// copied into memory of its own (see [`SceneArgs::build_owned`]).
    pub fn build_instanced(
        &self,
        matches: &ArgMatches,
        owned: bool,
    ) -> Result<(BuiltScene, f64, f64), Error> {
        let start = std::time::Instant::now();
        let placement = if owned {
            Placement::Owned
        } else {
            Placement::InPlace
        };
        if let Some(built) = self.saved(matches, placement)? {
            // The warnings `build` gave when it saved the scene, given again to whoever picks
            // from it (worked out from the loaded trees: about 2 ms for the dragon's 202k
            // triangles).
            warn_lost(&built);
            return Ok((built, start.elapsed().as_secs_f64(), 0.0));
        }
        let files = self.files(matches)?;
        if files.is_empty() {
            return self.build_loaded(example_scene(), start, &|_| Ok(()));
        }
        let loaded = super::progress::phase("loading the scene", || load_instanced(&files))?;
        let scene = match loaded {
            Loaded::Copies(scene) => scene,
            Loaded::Instanced(meshes, instances) => {
                let loaded = start.elapsed().as_secs_f64();
                let options = self.build_options();
                let built = super::progress::phase("building the trees", || {
                    BuiltScene::instanced(meshes, instances, &options)
                })?;
                warn_lost(&built);
                return Ok((built, loaded, start.elapsed().as_secs_f64() - loaded));
            }
        };
        self.build_loaded(scene, start, &|_| Ok(()))
    }

    /// [`SceneArgs::build`] for a process that lives on (the server, a soak): a saved scene is
    /// copied into memory of its own ([`raypick::rpk::load`]), so a file replaced or rewritten
    /// meanwhile changes nothing.
    pub fn build_owned(&self, matches: &ArgMatches) -> Result<BuiltScene, Error> {
        self.build_placed(matches, Placement::Owned, &|_| Ok(()))
            .map(|(built, _, _)| built)
    }

    /// Like [`SceneArgs::build`], also returning the seconds spent loading and building.
    pub fn build_timed(&self, matches: &ArgMatches) -> Result<(BuiltScene, f64, f64), Error> {
        self.build_placed(matches, Placement::InPlace, &|_| Ok(()))
    }

    /// Loads and builds; `check` sees the scene before any tree is built (a saved scene's once
    /// it is read).
    fn build_placed(
        &self,
        matches: &ArgMatches,
        placement: Placement,
        check: &dyn Fn(&Scene) -> Result<(), Error>,
    ) -> Result<(BuiltScene, f64, f64), Error> {
        let start = std::time::Instant::now();
        if let Some(built) = self.saved(matches, placement)? {
            let Some(instances) = built.instances() else {
                check(&built.scene)?;
                warn_lost(&built);
                return Ok((built, start.elapsed().as_secs_f64(), 0.0));
            };
            // A saved instanced scene, for a command that picks copies: its instances baked
            // into objects (the same ids and names) and built again; their triangles checked
            // against the budget before they are made.
            instances.check_bake("baking the saved instances into copies")?;
            let scene = instances.baked()?;
            check(&scene)?;
            let loaded = start.elapsed().as_secs_f64();
            let options = self.build_options();
            let built =
                super::progress::phase("building the tree", || BuiltScene::new(scene, &options))?;
            warn_lost(&built);
            return Ok((built, loaded, start.elapsed().as_secs_f64() - loaded));
        }
        let files = self.files(matches)?;
        let scene = if files.is_empty() {
            example_scene()
        } else {
            super::progress::phase("loading the scene", || load_scene(&files))?
        };
        self.build_loaded(scene, start, check)
    }

    /// Builds a loaded scene, once `check` has seen it; the seconds from `start` to the build's
    /// start, and the build's.
    fn build_loaded(
        &self,
        scene: Scene,
        start: std::time::Instant,
        check: &dyn Fn(&Scene) -> Result<(), Error>,
    ) -> Result<(BuiltScene, f64, f64), Error> {
        check(&scene)?;
        let loaded = start.elapsed().as_secs_f64();
        let options = self.build_options();
        let built =
            super::progress::phase("building the tree", || BuiltScene::new(scene, &options))?;
        warn_lost(&built);
        Ok((built, loaded, start.elapsed().as_secs_f64() - loaded))
    }
}

/// Warns about what the scene's single-precision frames cannot hold
/// ([`raypick::frame::faults`]): picks on those parts would be missed or off without a word.
fn warn_lost(built: &BuiltScene) {
    for warning in raypick::frame::faults::frame_warnings(built) {
        eprintln!("warning: {warning}");
    }
}

/// How a saved scene's arrays are held: in the file's mapped pages, or copied.
#[derive(Clone, Copy)]
enum Placement {
    InPlace,
    Owned,
}
