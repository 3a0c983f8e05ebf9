//! # raypick
//!
//! Exact, fast answers to "what is under this pixel?" for 3D scenes: a median-cut bounding
//! volume hierarchy, a stackless WGSL compute kernel for batches of pick rays, and a CPU path
//! that runs the same traversal over the same buffers.
//!
//! ```
//! use std::sync::Arc;
//! use raypick::{BuildOptions, BuiltScene, CpuPicker, DVec3, Picker, Ray, check::synthetic};
//!
//! let scene = synthetic::example_scene();
//! let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
//! let mut picker = CpuPicker::new(built);
//! let hits = picker.pick(&[Ray::new(DVec3::new(34.0, 44.0, 100.0), DVec3::NEG_Z)]).unwrap();
//! assert!(hits[0].hit);
//! assert_eq!(hits[0].object, 1); // the tower
//! ```
//!
//! Data flow: [`Scene`] -> [`bvh::median_cut`] -> [`Bvh`] (flat buffers, [`layout`]) ->
//! [`gpu::GpuPicker`] (`wgsl/pick.wgsl`), [`CpuPicker`] (the wide SIMD [`engine`]) or
//! [`picker::ReferencePicker`] (the kernel's twin, [`cpu::traverse`]) -> [`frame::resolve`]
//! (f64 refinement) -> [`Hit`].
//!
//! Vectors are [`glam`]'s (`DVec3` for world positions and directions), re-exported as
//! [`raypick::glam`](glam) and [`DVec3`], so callers need no `glam` dependency of their own.

#![warn(missing_docs)]

pub mod apps;
pub mod auto;
pub mod budget;
pub mod bvh;
pub mod check;
pub mod cpu;
pub mod dem;
pub mod engine;
pub mod error;
pub mod exact;
pub mod frame;
pub mod gpu;
pub mod huge_pages;
pub mod instance;
pub mod io;
pub mod layout;
pub mod names;
pub mod picker;
pub mod prefetch;
pub mod query;
pub mod ray;
pub mod ray_order;
pub mod rpk;
pub mod scene;
#[cfg(feature = "server")]
pub mod server;
pub mod steps;
pub mod store;

/// The vector library of the API (rays, hits, cameras, scenes), re-exported so that callers use
/// the very version raypick is built with.
pub use glam;
/// glam's f64 3-vector: world positions, directions and normals.
pub use glam::DVec3;

/// The README's Rust example, compiled and run as a doctest (`cargo test --doc`).
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

pub use bvh::{BuildOptions, Builder, Bvh, SplitAxis};
pub use error::{Error, Result};
pub use gpu::{GpuContext, GpuPicker};
pub use picker::{Backend, BuiltScene, CpuPicker, Picker, ReferencePicker, Refit, make_picker};
pub use query::{Answers, Cull, Intersector, Mode, Query};
pub use ray::{Hit, Ray};
pub use scene::{GridShape, Mesh, Scene};
