//! Query options shared by `pick` and `verify`: mode, culling, list length, intersector, ray
//! mask and range defaults.

use super::scene_args::parse_mask;
use clap::Args;
use raypick::{Cull, Error, Intersector, Mode, Query};

#[derive(Args, Debug)]
pub struct QueryArgs {
    /// closest: the nearest hit; any: stop at the first hit found; all: every hit, sorted by t.
    #[arg(long, value_parser = crate::cli::choice::choice::<Mode>(), default_value_t = Mode::Closest)]
    pub mode: Mode,
    /// In `--mode all`, the most hits kept per ray (the nearest), 1 ..= 1024; a ray that had
    /// more is flagged (`overflow`). Only with `--mode all` [default: 16].
    #[arg(long, value_name = "MAX_HITS")]
    pub max_hits: Option<u32>,
    /// Skip back faces or front faces (front = counter-clockwise as seen from the ray).
    #[arg(long, value_parser = crate::cli::choice::choice::<Cull>(), default_value_t = Cull::None)]
    pub cull: Cull,
    /// The ray/triangle test (watertight: rays never slip between triangles; moller-trumbore: the
    /// paper's test).
    #[arg(long, value_parser = crate::cli::choice::choice::<Intersector>(), default_value_t = Intersector::Watertight)]
    pub intersector: Intersector,
    /// Layer mask of every ray (decimal, 0x.. or 0b..): only objects sharing a bit with it are
    /// hit (objects have mask 0xffffffff unless --mask says otherwise; ray mask 0 hits nothing).
    #[arg(long, value_parser = parse_mask, default_value = "0xffffffff")]
    pub ray_mask: u32,
    /// Default tmin of every ray (hits need t > tmin).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = parse_ray_parameter)]
    pub tmin: f64,
    /// Default tmax of every ray (hits need t <= tmax); a ray line's 7th number overrides it.
    #[arg(long, default_value_t = f64::INFINITY, allow_hyphen_values = true, value_parser = parse_ray_parameter)]
    pub tmax: f64,
}

/// `--max-hits` without it.
pub const DEFAULT_MAX_HITS: u32 = 16;

impl QueryArgs {
    /// The query these options describe.
    pub fn query(&self) -> Query {
        Query {
            mode: self.mode,
            cull: self.cull,
            max_hits: self.max_hits.unwrap_or(DEFAULT_MAX_HITS),
            intersector: self.intersector,
        }
    }

    /// [`QueryArgs::query`], checked ([`Query::validate`]); `--max-hits` outside `--mode all`
    /// is refused (it would be ignored).
    pub fn checked(&self) -> Result<Query, Error> {
        if let (Some(k), false) = (self.max_hits, self.mode == Mode::All) {
            return Err(Error::Invalid(format!(
                "--max-hits {k} applies to --mode all only (this is --mode {})",
                self.mode
            )));
        }
        let query = self.query();
        query.validate()?;
        Ok(query)
    }
}

/// A `--tmin` or `--tmax` value: a number, or `inf` (not NaN, which no `t` compares with).
pub fn parse_ray_parameter(text: &str) -> Result<f64, String> {
    parse_number_where(text, |t| !t.is_nan(), "a ray parameter (a number, or inf)")
}

/// A number argument for which `ok` holds; else a sentence quoting it as not `what`.
pub fn parse_number_where(text: &str, ok: fn(f64) -> bool, what: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(x) if ok(x) => Ok(x),
        _ => Err(format!("'{}' is not {what}", raypick::budget::quote(text))),
    }
}
