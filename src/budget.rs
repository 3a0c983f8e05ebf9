//! The memory budget: one limit on every allocation whose size comes from user input (argument
//! values, sizes read from file headers, request bodies), checked before allocating.
//!
//! The default is half the machine's physical memory (or 4 GiB where it cannot be read);
//! `--max-memory` on the command line sets it for the process. A size over the budget is an
//! [`Error::OverBudget`] naming what needed the memory, the size and the limit.

use crate::error::{Error, Result};
use std::sync::atomic::{AtomicU64, Ordering};

/// 0: not set yet (the default applies).
static LIMIT: AtomicU64 = AtomicU64::new(0);

/// The default budget when the machine's memory cannot be read.
const FALLBACK: u64 = 4 << 30;

/// Sets the process's budget in bytes (at least 1 MiB).
pub fn set_limit(bytes: u64) {
    LIMIT.store(bytes.max(1 << 20), Ordering::Relaxed);
}

/// The budget in bytes.
pub fn limit() -> u64 {
    match LIMIT.load(Ordering::Relaxed) {
        0 => default_limit(),
        n => n,
    }
}

/// Half the machine's physical memory (Linux `/proc/meminfo`), or 4 GiB.
pub fn default_limit() -> u64 {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| {
            let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
            let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
            Some(kib.saturating_mul(1024))
        });
    total.map_or(FALLBACK, |t| t / 2)
}

/// Checks that `count` items of `item_bytes` each fit the budget; `what` names them in the
/// error, e.g. "the render's pixels".
pub fn check(what: &str, count: u64, item_bytes: u64) -> Result<()> {
    let limit = limit();
    match count.checked_mul(item_bytes) {
        Some(bytes) if bytes <= limit => Ok(()),
        bytes => Err(Error::OverBudget(format!(
            "{what} would need {} ({count} × {item_bytes} bytes), over the memory budget of {} \
             (set it with --max-memory)",
            bytes.map_or("more than 16 EiB".to_string(), human),
            human(limit)
        ))),
    }
}

/// Parses a `--max-memory` value: bytes, or a number with K, M, G or T (powers of 1024, an
/// optional trailing `B` or `iB`).
pub fn parse_size(text: &str) -> std::result::Result<u64, String> {
    let t = text.trim();
    let upper = t.to_ascii_uppercase();
    let stripped = upper
        .strip_suffix("IB")
        .or_else(|| upper.strip_suffix('B'))
        .unwrap_or(&upper);
    let (number, shift) = match stripped.chars().last() {
        Some('K') => (&stripped[..stripped.len() - 1], 10),
        Some('M') => (&stripped[..stripped.len() - 1], 20),
        Some('G') => (&stripped[..stripped.len() - 1], 30),
        Some('T') => (&stripped[..stripped.len() - 1], 40),
        _ => (stripped, 0),
    };
    let value: f64 = number.trim().parse().map_err(|_| {
        format!(
            "{:?} is not a size (e.g. 8G, 512M, 1000000)",
            crate::budget::quote(t)
        )
    })?;
    if !(value.is_finite() && value >= 1.0) {
        return Err(format!("{t:?} is not a positive size"));
    }
    let bytes = value * (1u64 << shift) as f64;
    if bytes >= u64::MAX as f64 {
        return Err(format!("{t:?} is too large"));
    }
    Ok(bytes as u64)
}

/// A user token for an error message: at most 60 characters, with "…" when cut, and its
/// control characters escaped ([`crate::error::escape_controls`]).
pub fn quote(token: &str) -> String {
    const MOST: usize = 60;
    let cut = match token.char_indices().nth(MOST) {
        None => token,
        Some((cut, _)) => &token[..cut],
    };
    let mut quoted = crate::error::escape_controls(cut, false).into_owned();
    if cut.len() < token.len() {
        quoted.push('…');
    }
    quoted
}

/// `bytes` for a message: in GiB from 1 GiB, else in MiB, one decimal.
pub fn human(bytes: u64) -> String {
    const GIB: f64 = (1u64 << 30) as f64;
    const MIB: f64 = (1u64 << 20) as f64;
    if bytes as f64 >= GIB {
        format!("{:.1} GiB", bytes as f64 / GIB)
    } else {
        format!("{:.1} MiB", bytes as f64 / MIB)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_over_budget_sizes_are_refused_by_name() {
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("8GiB"), Ok(8 << 30));
        assert_eq!(parse_size("1000"), Ok(1000));
        assert!(parse_size("lots").is_err());
        assert!(parse_size("0").is_err());
        let e = check("the test's items", u64::MAX, 2)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("the test's items") && e.contains("memory budget"),
            "{e}"
        );
        assert!(check("small", 10, 10).is_ok());
        assert_eq!(quote(&"x".repeat(1000)).chars().count(), 61);
    }
}
