//! Reading scenes and rays from files, and writing hits out.

pub mod gltf;
pub mod obj;
pub mod output;
pub mod ray_file;
pub mod scene_files;
