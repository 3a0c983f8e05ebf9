//! What a batch of rays asks for: the query mode (closest, any, all), face culling, the
//! all-hits limit and the ray/triangle test; and the answers that come back.

use crate::layout::{
    CULL_BACK, CULL_FRONT, CULL_NONE, CULL_SHIFT, GpuHit, GpuHitEntry, GpuRay, MODE_ALL, MODE_ANY,
    MODE_CLOSEST,
};
use crate::ray::{Hit, Ray};

/// Which hits a ray asks for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// The nearest hit.
    #[default]
    Closest,
    /// Any hit: traversal stops at the first one found (line of sight, shadows).
    Any,
    /// Every hit along the ray, sorted by t, up to `max_hits` (the nearest are kept).
    All,
}

/// Face culling. A triangle is front-facing when its vertices run counter-clockwise as seen from
/// the ray's origin, i.e. when the ray runs against the normal `(v1 − v0) × (v2 − v0)`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Cull {
    /// Both faces are hit.
    #[default]
    None,
    /// Back faces are skipped.
    Back,
    /// Front faces are skipped.
    Front,
}

/// The ray/triangle test.
///
/// The default is the watertight test: on 1M probes aimed exactly at shared edges and vertices
/// it let none through where Möller–Trumbore let 8–11% through, at no measured cost in speed
/// (BENCHMARKS.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Intersector {
    /// Möller–Trumbore, as in the paper.
    MollerTrumbore,
    /// Woop, Benthin and Wald's watertight test: rays never slip between triangles sharing an edge.
    #[default]
    Watertight,
}

/// The settings of one batch of rays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Query {
    /// Which hits each ray asks for.
    pub mode: Mode,
    /// Face culling.
    pub cull: Cull,
    /// The most hits kept per ray in [`Mode::All`] (1 ..= [`MAX_HITS_LIMIT`]).
    pub max_hits: u32,
    /// The ray/triangle test.
    pub intersector: Intersector,
}

/// The largest `max_hits` accepted.
pub const MAX_HITS_LIMIT: u32 = 1024;

impl Default for Query {
    fn default() -> Self {
        Self {
            mode: Mode::Closest,
            cull: Cull::None,
            max_hits: 16,
            intersector: Intersector::Watertight,
        }
    }
}

impl Query {
    /// The kernel's per-ray flag word for this query.
    pub fn flags(&self) -> u32 {
        let mode = match self.mode {
            Mode::Closest => MODE_CLOSEST,
            Mode::Any => MODE_ANY,
            Mode::All => MODE_ALL,
        };
        let cull = match self.cull {
            Cull::None => CULL_NONE,
            Cull::Back => CULL_BACK,
            Cull::Front => CULL_FRONT,
        };
        mode | cull << CULL_SHIFT
    }

    /// The all-hits list length the kernel needs (0 outside [`Mode::All`]).
    pub fn list_length(&self) -> u32 {
        if self.mode == Mode::All {
            self.max_hits
        } else {
            0
        }
    }

    /// An estimate of the bytes a picker holds per ray of a batch for this query: the world
    /// ray, the kernel ray (twice where the batch is reordered), the raw result and the answer,
    /// and in [`Mode::All`] `max_hits` list slots (raw and resolved). Callers size their
    /// batches by it against the memory budget ([`crate::budget`]).
    pub fn bytes_per_ray(&self) -> u64 {
        use std::mem::size_of;
        let base = size_of::<Ray>()
            + 2 * size_of::<GpuRay>()
            + 2 * size_of::<f64>()
            + 2 * size_of::<GpuHit>()
            + size_of::<Hit>()
            + size_of::<usize>()
            + 1;
        let slot = 2 * size_of::<GpuHitEntry>() + size_of::<Hit>();
        base as u64 + u64::from(self.list_length()) * slot as u64
    }

    /// Checks the settings.
    pub fn validate(&self) -> crate::Result<()> {
        if self.mode == Mode::All && !(1..=MAX_HITS_LIMIT).contains(&self.max_hits) {
            return Err(crate::Error::Invalid(format!(
                "max hits {} is out of range; it must be 1 ..= {MAX_HITS_LIMIT}",
                self.max_hits
            )));
        }
        Ok(())
    }
}

/// The answers for a batch.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Answers {
    /// One record per ray: the closest hit, the hit found (any), or the nearest of the list
    /// (all); a miss otherwise. Carries the ray's box and triangle test counts and invalid flag.
    pub nearest: Vec<Hit>,
    /// [`Mode::All`]: every kept hit, ray after ray, each ray's sorted by t.
    pub lists: Vec<Hit>,
    /// [`Mode::All`]: ray `i`'s hits are `lists[list_start[i]..list_start[i + 1]]`.
    pub list_start: Vec<usize>,
    /// [`Mode::All`]: whether ray `i` had more hits than `max_hits`.
    pub overflow: Vec<bool>,
}

impl Answers {
    /// The hits of ray `i`: its list in [`Mode::All`], else its one hit (or none).
    pub fn hits_of(&self, i: usize) -> &[Hit] {
        if self.list_start.is_empty() {
            let h = &self.nearest[i..i + 1];
            if h[0].hit { h } else { &[] }
        } else {
            &self.lists[self.list_start[i]..self.list_start[i + 1]]
        }
    }

    /// The answers of the rays at `idx`, in that order.
    pub fn subset(&self, idx: &[usize]) -> Answers {
        let mut out = Answers {
            nearest: idx.iter().map(|&i| self.nearest[i]).collect(),
            ..Answers::default()
        };
        if !self.list_start.is_empty() {
            out.list_start.push(0);
            for &i in idx {
                out.lists.extend_from_slice(self.hits_of(i));
                out.list_start.push(out.lists.len());
                out.overflow.push(self.overflow[i]);
            }
        }
        out
    }
}

crate::names::named!(Mode {
    Closest => ("closest", "The nearest hit."),
    Any => ("any", "Any hit: traversal stops at the first one found (line of sight, shadows)."),
    All => ("all", "Every hit along the ray, sorted by t, up to --max-hits (the nearest are kept)."),
});

crate::names::named!(Cull {
    None => ("none", "Both faces are hit."),
    Back => ("back", "Back faces are skipped."),
    Front => ("front", "Front faces are skipped."),
});

crate::names::named!(Intersector {
    MollerTrumbore => ("moller-trumbore", "Möller–Trumbore, as in the paper."),
    Watertight => ("watertight", "Woop, Benthin and Wald's watertight test: rays never slip between triangles sharing an edge."),
});
