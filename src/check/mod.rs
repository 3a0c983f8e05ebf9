//! Checking tools: everything that judges answers rather than producing them. The brute-force
//! f64 [`oracle`] and its [`sweep`], the [`compare`] rules (mismatch, shared-edge tie, boundary
//! tie), the watertightness [`probe`]s and the seeded [`synthetic`] scenes and ray kinds.
//! Nothing in the pick pipeline depends on this folder; it depends on the pipeline.

pub mod compare;
pub mod oracle;
pub mod probe;
pub mod sweep;
pub mod synthetic;
