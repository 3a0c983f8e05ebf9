//! Applications built on the pick pipeline: [`camera`]s that turn pixels into world rays,
//! ray-cast [`render`]ing, screen-space [`select`]ion (marquee and object-id buffer), and what
//! a line-of-[`sight`] query is warned about. Each only sees the [`crate::Hit`]s a [`crate::Picker`] returns.

pub mod camera;
pub mod render;
pub mod select;
pub mod sight;
