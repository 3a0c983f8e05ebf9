//! Writing hits as CSV (`ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz`) or JSON.
//!
//! Numbers are printed in Rust's shortest round-trip form, so an f64 world coordinate keeps every
//! digit it has (well below a millimetre at map coordinates). A miss keeps its row with `hit` 0
//! and the other fields empty.

use crate::ray::Hit;
use std::io::Write;

/// Output formats.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One row per ray with the header `ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz`.
    #[default]
    Csv,
    /// A JSON array with one object per ray.
    Json,
}

/// The CSV header line.
pub const CSV_HEADER: &str = "ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz";

/// Writes `hits` (answering rays `0..`) in `format`.
pub fn write_hits(out: &mut impl Write, hits: &[Hit], format: Format) -> std::io::Result<()> {
    match format {
        Format::Csv => {
            writeln!(out, "{CSV_HEADER}")?;
            for (i, h) in hits.iter().enumerate() {
                if h.hit {
                    let (p, n) = (h.position, h.normal);
                    writeln!(
                        out,
                        "{i},1,{},{},{},{},{},{},{},{},{},{},{}",
                        h.t, h.object, h.triangle, h.u, h.v, p.x, p.y, p.z, n.x, n.y, n.z
                    )?;
                } else {
                    writeln!(out, "{i},0,,,,,,,,,,,")?;
                }
            }
        }
        Format::Json => {
            writeln!(out, "[")?;
            for (i, h) in hits.iter().enumerate() {
                let sep = if i + 1 < hits.len() { "," } else { "" };
                let record = if h.hit {
                    let (p, n) = (h.position, h.normal);
                    format!(
                        "{{\"ray\":{i},\"hit\":true,\"t\":{},\"object\":{},\"triangle\":{},\"u\":{},\"v\":{},\"position\":[{},{},{}],\"normal\":[{},{},{}]}}",
                        json_number(h.t),
                        h.object,
                        h.triangle,
                        json_number(h.u),
                        json_number(h.v),
                        json_number(p.x),
                        json_number(p.y),
                        json_number(p.z),
                        json_number(n.x),
                        json_number(n.y),
                        json_number(n.z)
                    )
                } else {
                    format!("{{\"ray\":{i},\"hit\":false,\"invalid\":{}}}", h.invalid)
                };
                writeln!(out, "  {record}{sep}")?;
            }
            writeln!(out, "]")?;
        }
    }
    Ok(())
}

/// A JSON number in shortest round-trip form (`null` for non-finite values).
fn json_number(x: f64) -> String {
    if x.is_finite() {
        format!("{x:?}")
    } else {
        "null".into()
    }
}
