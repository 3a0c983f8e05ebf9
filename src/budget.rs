//! The memory budget: one limit on every allocation whose size comes from user input (argument
//! values, sizes read from file headers, request bodies), checked before allocating.
//!
//! The default is half of what the process can have ([`ceiling`]: the machine's physical
//! memory, the process's address-space limit (`ulimit -v`) and its control group's memory limit,
//! the least of them; 4 GiB where none can be read); `--max-memory` on the command line sets it
//! for the process, up to the ceiling (with swap). Under an address-space limit the budget is
//! also at most half of what that limit leaves the process at the time of each check (its own
//! mappings, a GPU driver's included, count against the limit). A size over the budget is an
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

/// The budget in bytes: the one set, or the default, and under an address-space limit
/// (`ulimit -v`) no more than half of what that limit leaves the process now ([`Limit`]).
pub fn limit() -> u64 {
    current().bytes
}

/// The budget now, and what sets it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Limit {
    bytes: u64,
    /// Whether half of what the address-space limit leaves is below the budget set (or the
    /// default). The default is half of that limit, but the process's own mappings count
    /// against it too: a GPU driver maps hundreds of MiB when it opens (lavapipe: a render that
    /// fitted the budget then aborted the process, unable to allocate).
    by_address_space: bool,
}

/// The budget now ([`limit`]) and what sets it, for a message: "set it with --max-memory", or
/// the address-space limit where that is what sets it.
pub fn limit_and_why() -> (u64, &'static str) {
    let limit = current();
    (limit.bytes, why(limit))
}

fn why(limit: Limit) -> &'static str {
    if limit.by_address_space {
        "half of what this process's address-space limit, `ulimit -v`, leaves it"
    } else {
        "set it with --max-memory"
    }
}

/// The budget set (`--max-memory`, `set_max_memory`) or the default, before an address-space
/// limit lowers it to half of what it leaves ([`limit`]).
pub fn set_or_default() -> u64 {
    match LIMIT.load(Ordering::Relaxed) {
        0 => default_limit(),
        n => n,
    }
}

fn current() -> Limit {
    let set = set_or_default();
    match address_space_left() {
        Some(left) if left / 2 < set => Limit {
            bytes: left / 2,
            by_address_space: true,
        },
        _ => Limit {
            bytes: set,
            by_address_space: false,
        },
    }
}

/// What the address-space limit (`ulimit -v`) leaves this process now: the limit less the
/// address space it has mapped (`VmSize`, Linux `/proc/self/status`); `None` without a limit
/// or where the mapped size cannot be read.
pub fn address_space_left() -> Option<u64> {
    static LIMIT_AS: std::sync::OnceLock<Option<u64>> = std::sync::OnceLock::new();
    let limit = (*LIMIT_AS.get_or_init(address_space_limit))?;
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmSize:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(limit.saturating_sub(kib.saturating_mul(1024)))
}

/// Half of [`ceiling`] without swap, or 4 GiB where nothing can be read. A budget of the
/// machine's memory alone let an allocation within it fail under a smaller address-space limit
/// (`ulimit -v`): the process aborted instead of saying what was too large.
pub fn default_limit() -> u64 {
    // Read once: three files and a system call, and `limit` is asked often.
    static DEFAULT: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *DEFAULT.get_or_init(|| ceiling(false).map_or(FALLBACK, |t| t / 2))
}

/// The most memory this process can have, in bytes: the least of the machine's physical memory
/// (with its swap when `with_swap`; Linux `/proc/meminfo`), the process's address-space limit
/// (`RLIMIT_AS`) and its control group's memory limit; `None` where none of them can be read.
pub fn ceiling(with_swap: bool) -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let field = |name: &str| {
        let line = meminfo.as_deref()?.lines().find(|l| l.starts_with(name))?;
        let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kib.saturating_mul(1024))
    };
    let physical = field("MemTotal:").map(|total| {
        let swap = if with_swap { field("SwapTotal:") } else { None };
        total.saturating_add(swap.unwrap_or(0))
    });
    [physical, address_space_limit(), cgroup_limit()]
        .into_iter()
        .flatten()
        .min()
}

/// Limits at or above this are no limit (cgroup v1 writes "unlimited" as a huge number).
const UNLIMITED: u64 = 1 << 60;

/// The process's address-space limit (`RLIMIT_AS`, `ulimit -v`), when it has one.
fn address_space_limit() -> Option<u64> {
    #[cfg(unix)]
    {
        let mut limit = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: getrlimit writes the one struct it is given.
        let read = unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut limit) } == 0;
        // `rlim_t` is u64 here, narrower on some targets.
        #[allow(clippy::useless_conversion)]
        let bytes = u64::try_from(limit.rlim_cur).ok()?;
        (read && limit.rlim_cur != libc::RLIM_INFINITY && bytes < UNLIMITED).then_some(bytes)
    }
    #[cfg(not(unix))]
    None
}

/// The memory limit of the control groups this process runs in, the least of them: cgroup v2's
/// `memory.max` of its own group (from `/proc/self/cgroup`) and of each group above it, or v1's
/// `memory.limit_in_bytes` of its memory group; and the mount's root files (a container's
/// namespace shows its own group as the root).
fn cgroup_limit() -> Option<u64> {
    use std::path::{Path, PathBuf};
    let read = |path: &Path| -> Option<u64> {
        let bytes = std::fs::read_to_string(path)
            .ok()?
            .trim()
            .parse::<u64>()
            .ok()?;
        (bytes < UNLIMITED).then_some(bytes)
    };
    let mut files: Vec<PathBuf> = vec![
        "/sys/fs/cgroup/memory.max".into(),
        "/sys/fs/cgroup/memory/memory.limit_in_bytes".into(),
    ];
    let groups = std::fs::read_to_string("/proc/self/cgroup").unwrap_or_default();
    for line in groups.lines().take(64) {
        let mut parts = line.splitn(3, ':');
        let (Some(_), Some(controllers), Some(group)) = (parts.next(), parts.next(), parts.next())
        else {
            continue;
        };
        let group = group.trim_start_matches('/');
        if controllers.is_empty() {
            // v2: the group and every group above it (at most 64 levels).
            let mut dir = Path::new("/sys/fs/cgroup").join(group);
            for _ in 0..64 {
                files.push(dir.join("memory.max"));
                if !dir.pop() || dir == Path::new("/sys/fs/cgroup") {
                    break;
                }
            }
        } else if controllers.split(',').any(|c| c == "memory") {
            files.push(
                Path::new("/sys/fs/cgroup/memory")
                    .join(group)
                    .join("memory.limit_in_bytes"),
            );
        }
    }
    files.iter().filter_map(|f| read(f)).min()
}

/// The threads rayon's global pool starts, read as rayon reads it: `RAYON_NUM_THREADS` when it
/// is a positive count, else the deprecated `RAYON_RS_NUM_CPUS`, else one per core; at most
/// [`rayon::max_num_threads`]. Starting the pool with this count makes the count checked
/// ([`prepare_threads`]) the count started.
pub fn global_thread_count() -> usize {
    let cores = || std::thread::available_parallelism().map_or(1, |n| n.get());
    let read = |name: &str| {
        std::env::var(name)
            .ok()
            .and_then(|s| s.parse::<usize>().ok())
    };
    let n = match read("RAYON_NUM_THREADS") {
        Some(0) => cores(),
        Some(n) => n,
        None => read("RAYON_RS_NUM_CPUS")
            .filter(|&n| n > 0)
            .unwrap_or_else(cores),
    };
    n.min(rayon::max_num_threads())
}

/// Readies the process for `threads` threads, before any is started, under an address-space
/// limit (`ulimit -v`): checks that they fit what it leaves (the words why not). Their stacks (`RUST_MIN_STACK`, else the standard
/// library's 2 MiB, and a guard page each) must fit half of it, and the allocator's arenas
/// (glibc reserves 64 MiB for each new one) are capped to the other half ([`cap_arenas`]), so
/// that arenas made by the first threads cannot take the address space the later ones' stacks
/// need. Threads started against a limit too tight for them failed to start with an error, but
/// those that had started ran on, and one of them (or the starting thread) could fail a small
/// allocation and abort the process before the error was said (seen with 5,000 threads under a
/// 1 GB limit; 40–100 threads under 1 GB failed part-way on the arenas).
pub fn prepare_threads(threads: usize) -> std::result::Result<(), String> {
    let Some(left) = address_space_left() else {
        return Ok(());
    };
    cap_arenas(left / 2);
    let stack = std::env::var("RUST_MIN_STACK")
        .ok()
        .and_then(|s| s.parse::<u64>().ok())
        .unwrap_or(2 << 20);
    let needed = (threads as u64).saturating_mul(stack.saturating_add(4096));
    if needed > left / 2 {
        return Err(format!(
            "{threads} threads need {} of address space for their stacks, more than half of \
             the {} the address-space limit leaves",
            human(needed),
            human(left)
        ));
    }
    Ok(())
}

/// Caps the allocator's arenas (glibc's `M_ARENA_MAX`, lowered only) to as many 64 MiB
/// reservations beside the main one as `bytes` holds, so threads' arenas stay within it.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn cap_arenas(bytes: u64) {
    const ARENA: u64 = 64 << 20;
    let cores = {
        // SAFETY: `sysconf` reads a system value.
        let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
        n.max(1) as u64
    };
    let current = std::env::var("MALLOC_ARENA_MAX")
        .ok()
        .and_then(|s| s.parse::<u64>().ok())
        .filter(|&n| n > 0)
        .unwrap_or(8 * cores);
    let most = (1 + bytes / ARENA).min(current).min(i32::MAX as u64);
    // SAFETY: `mallopt` sets one of the allocator's parameters; any positive value is valid.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, most as i32);
    }
}

/// Other allocators reserve nothing per thread up front.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn cap_arenas(_: u64) {}

/// Checks that `count` items of `item_bytes` each fit the budget; `what` names them in the
/// error, e.g. "the render's pixels".
pub fn check(what: &str, count: u64, item_bytes: u64) -> Result<()> {
    let (limit, why) = limit_and_why();
    check_against(what, count, item_bytes, limit, why)
}

/// [`check`] against a budget of `limit` bytes, set as `why` says.
fn check_against(what: &str, count: u64, item_bytes: u64, limit: u64, why: &str) -> Result<()> {
    match count.checked_mul(item_bytes) {
        Some(bytes) if bytes <= limit => Ok(()),
        bytes => Err(Error::OverBudget(format!(
            "{what} would need {} ({count} × {item_bytes} bytes), over the memory budget of {} \
             ({why})",
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
            "\"{}\" is not a size (e.g. 8G, 512M, 1000000)",
            crate::budget::quote(t)
        )
    })?;
    // A number past f64's range ("9" × 500) reads as infinite: too large, not "not positive".
    if value == f64::INFINITY {
        return Err(format!("\"{}\" is too large", quote(t)));
    }
    // A fraction of a unit is a size ("0.5G" is 512M); less than one byte is not.
    let bytes = value * (1u64 << shift) as f64;
    if !(value.is_finite() && bytes >= 1.0) {
        return Err(format!("\"{}\" is not a positive size", quote(t)));
    }
    if bytes >= u64::MAX as f64 {
        return Err(format!("\"{}\" is too large", quote(t)));
    }
    Ok(bytes as u64)
}

/// The least budget a user may set: 1 MiB.
pub const LEAST: u64 = 1 << 20;

/// A budget a user asked for (`--max-memory`, Python's `raypick.set_max_memory`): `bytes`, as
/// the user wrote it (`written`, for the message), when it is at least [`LEAST`] and no more
/// than the process can have ([`ceiling`] with swap: more would let an allocation within the
/// budget abort the process).
pub fn check_limit(bytes: u64, written: &str) -> std::result::Result<u64, String> {
    let written = quote(written.trim());
    if bytes < LEAST {
        return Err(format!(
            "\"{written}\" is below the least memory budget, 1M"
        ));
    }
    if let Some(most) = ceiling(true)
        && bytes > most
    {
        return Err(format!(
            "\"{written}\" is more memory than this process can have ({}: the machine's memory \
             and swap, `ulimit -v` and the control group's limit, the least of them)",
            human(most)
        ));
    }
    Ok(bytes)
}

/// [`parse_size`], then [`check_limit`]: a budget as the command line's `--max-memory` takes it.
pub fn parse_limit(text: &str) -> std::result::Result<u64, String> {
    check_limit(parse_size(text)?, text)
}

/// A user token for an error message: at most 60 characters as shown, with "…" when cut, and
/// its control characters escaped ([`crate::error::escape_controls`]) before it is measured
/// (a token of NULs, each shown as `\u{0}`, stays as short).
pub fn quote(token: &str) -> String {
    const MOST: usize = 60;
    let mut quoted = String::new();
    let mut shown = 0;
    let mut buf = [0u8; 4];
    for c in token.chars() {
        let piece = crate::error::escape_controls(c.encode_utf8(&mut buf), false);
        let n = piece.chars().count();
        if shown + n > MOST {
            quoted.push('…');
            break;
        }
        quoted.push_str(&piece);
        shown += n;
    }
    quoted
}

/// A number for a message: as Rust writes it where that is short, else in scientific notation
/// (`-1e300`, not three hundred digits).
pub fn number(x: f64) -> String {
    let plain = x.to_string();
    if plain.len() <= 24 {
        plain
    } else {
        format!("{x:e}")
    }
}

/// A point for a message, `[x, y, z]`, each coordinate by [`number`].
pub fn point(p: glam::DVec3) -> String {
    format!("[{}, {}, {}]", number(p.x), number(p.y), number(p.z))
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
    fn quoted_tokens_and_numbers_stay_short() {
        assert_eq!(quote("abc"), "abc");
        let long = "x".repeat(100);
        assert_eq!(quote(&long), format!("{}…", "x".repeat(60)));
        // Escaped before measured: 60 NULs would show as 300 characters.
        let nuls = quote(&"\0".repeat(60));
        assert!(nuls.chars().count() <= 61, "{nuls}");
        assert!(nuls.starts_with("\\u{0}") && nuls.ends_with('…'), "{nuls}");
        assert_eq!(number(2.5), "2.5");
        assert_eq!(number(-1e300), "-1e300");
        assert_eq!(number(1e-300), "1e-300");
        assert_eq!(
            point(glam::DVec3::new(1.0, 1e-300, f64::INFINITY)),
            "[1, 1e-300, inf]"
        );
    }

    #[test]
    fn sizes_parse_and_over_budget_sizes_are_refused_by_name() {
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("8GiB"), Ok(8 << 30));
        assert_eq!(parse_size("1000"), Ok(1000));
        assert!(parse_size("lots").is_err());
        assert!(parse_size("0").is_err());
        // A fraction of a unit is a size ("0.5G" was "not a positive size"); below a byte not.
        assert_eq!(parse_size("0.5G"), Ok(512 << 20));
        assert_eq!(parse_size("1.5k"), Ok(1536));
        assert!(parse_size("0.5").is_err());
        assert!(parse_size("-1G").is_err());
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

    /// A size of exactly the budget fits it, as the error's "over the memory budget" says; one
    /// byte more does not, nor a product past u64.
    #[test]
    fn a_size_of_exactly_the_budget_fits_it() {
        let budget = 3 << 30;
        let fits = |count, item| check_against("items", count, item, budget, "a test").is_ok();
        assert!(fits(budget, 1) && fits(1, budget) && fits(3, 1 << 30));
        assert!(!fits(budget + 1, 1) && !fits(1, budget + 1));
        assert!(!fits(u64::MAX, 2));
        let e = check_against("items", 2, budget, budget, "a test").unwrap_err();
        assert!(e.to_string().contains("over the memory budget of"), "{e}");
    }
}
