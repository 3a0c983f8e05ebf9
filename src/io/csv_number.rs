//! CSV numbers: an f64 in its shortest round-trip digits, written out in full for
//! 1e-7 <= |x| < 1e21 (as Rust's `{}` and JavaScript write them) and with an exponent outside
//! that range (as Rust's `{:e}` writes it: `1e300`, `-2.5e-8`).
//!
//! The digits come from `ryu` and are laid out here as `{}` and `{:e}` lay out their own (the
//! same shortest, nearest digits; a test holds the bytes to `format!` over millions of values):
//! `format!`'s digit generation and formatting machinery took a fifth of a whole-process pick of
//! 1M rays to a CSV file, eleven numbers a hit (BENCHMARKS.md).

/// The longest text [`layout`] writes: a sign, 21 integer digits and 17 more significant
/// digits with a point, or an exponent form (at most 25 bytes).
const MOST: usize = 48;

/// Appends `x` to `out` in CSV form (see the module's documentation).
#[inline]
pub fn push_csv_number(out: &mut String, x: f64) {
    use std::fmt::Write;
    let mut buf = [0u8; MOST];
    match text(x, &mut buf) {
        Some(text) => out.push_str(text),
        None => {
            let _ = write!(out, "{x}");
        }
    }
}

/// A CSV number as text (see the module's documentation).
pub fn csv_number(x: f64) -> String {
    let mut out = String::new();
    push_csv_number(&mut out, x);
    out
}

/// [`csv_number`] without allocating, for `write!`.
#[derive(Clone, Copy, Debug)]
pub struct CsvNumber(pub f64);

impl std::fmt::Display for CsvNumber {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut buf = [0u8; MOST];
        match text(self.0, &mut buf) {
            Some(text) => f.write_str(text),
            None => write!(f, "{}", self.0),
        }
    }
}

/// `x`'s CSV text in `buf`; `None` where `{}` writes it as it is (zero, not finite).
#[inline]
fn text(x: f64, buf: &mut [u8; MOST]) -> Option<&str> {
    let n = layout(x, buf)?;
    // SAFETY: `layout` writes ASCII bytes only (digits, '-', '.', 'e').
    Some(unsafe { std::str::from_utf8_unchecked(&buf[..n]) })
}

/// Whether `x` is written out in full rather than with an exponent.
#[inline]
fn in_full(x: f64) -> bool {
    (1e-7..1e21).contains(&x.abs())
}

/// Writes finite, non-zero `x` into `buf` and returns its length; `None` for zero (`0` or `-0`)
/// and values that are not finite, which `{}` writes as they are.
#[inline]
fn layout(x: f64, buf: &mut [u8; MOST]) -> Option<usize> {
    if x == 0.0 || !x.is_finite() {
        return None;
    }
    let mut ryu = ryu::Buffer::new();
    let text = ryu.format_finite(x).as_bytes();
    // Most numbers: ryu writes 1e-5 <= |x| < 1e16 in full as `{}` does, but for the `.0` of a
    // whole number, unless it lies on a tie (below), which the general path sees to.
    if (1e-5..1e16).contains(&x.abs()) {
        let point = text.iter().position(|&b| b == b'.').unwrap_or(text.len());
        let fraction = &text[(point + 1).min(text.len())..];
        let whole = fraction == b"0";
        // The place just below the last significant digit ([`halfway_below`]'s `k`).
        let below = if whole {
            let integer = &text[usize::from(x < 0.0)..point];
            integer.iter().rev().take_while(|&&b| b == b'0').count() as i32 - 1
        } else {
            -(fraction.len() as i32) - 1
        };
        if odd_mantissa_exponent(x) != below {
            let n = if whole { point } else { text.len() };
            buf[..n].copy_from_slice(&text[..n]);
            return Some(n);
        }
    }
    layout_digits(x, text, buf)
}

/// [`layout`] from ryu's `text` of `x`, digit by digit: any magnitude, ties included.
fn layout_digits(x: f64, text: &[u8], buf: &mut [u8; MOST]) -> Option<usize> {
    // `text` is `-`?, digits with at most one '.', then `e` and a signed exponent or nothing.
    let (negative, text) = match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        _ => (false, text),
    };
    let (mantissa, exponent) = match text.iter().position(|&b| b == b'e') {
        Some(e) => (&text[..e], parse_exponent(&text[e + 1..])),
        None => (text, 0),
    };
    // The significant digits and the power of ten of the first one.
    let mut digits = [0u8; 24];
    let (mut count, mut before_point, mut leading, mut point) = (0usize, 0i32, 0i32, false);
    for &b in mantissa {
        if b == b'.' {
            point = true;
            continue;
        }
        if !point {
            before_point += 1;
        }
        if count == 0 && b == b'0' {
            leading += 1;
            continue;
        }
        digits[count] = b;
        count += 1;
    }
    while count > 1 && digits[count - 1] == b'0' {
        count -= 1;
    }
    let mut power = before_point - 1 - leading + exponent;
    if halfway_below(x, &digits[..count], power) {
        // `format!` rounds a tie up where ryu rounds it to the even digits below.
        (count, power) = round_up(&mut digits, count, power);
    }
    let digits = &digits[..count];
    let mut n = 0;
    let mut put = |b: u8| {
        buf[n] = b;
        n += 1;
    };
    if negative {
        put(b'-');
    }
    if in_full(x) {
        if power >= 0 {
            // Integer digits (padded with zeros), then the rest after a point.
            let whole = power as usize + 1;
            for i in 0..whole {
                put(digits.get(i).copied().unwrap_or(b'0'));
            }
            if digits.len() > whole {
                put(b'.');
                for &d in &digits[whole..] {
                    put(d);
                }
            }
        } else {
            put(b'0');
            put(b'.');
            for _ in 0..(-power - 1) {
                put(b'0');
            }
            for &d in digits {
                put(d);
            }
        }
    } else {
        put(digits[0]);
        if digits.len() > 1 {
            put(b'.');
            for &d in &digits[1..] {
                put(d);
            }
        }
        put(b'e');
        if power < 0 {
            put(b'-');
        }
        let mut itoa = itoa::Buffer::new();
        for &d in itoa.format(power.unsigned_abs()).as_bytes() {
            put(d);
        }
    }
    Some(n)
}

/// Whether `|x|` lies exactly halfway between the decimal `digits` (the first one at
/// `10^power`) and the next number of as many digits up: `|x| = (10·D + 5)·10^k` for the
/// digits' integer `D` and `k` the place just below the last digit. With `|x| = m·2^e`, `m`
/// odd, and `10·D + 5` odd, that holds exactly when `e == k` and `m·5^(−k) == (10·D + 5)·5^k`.
fn halfway_below(x: f64, digits: &[u8], power: i32) -> bool {
    let k = power - digits.len() as i32;
    if odd_mantissa_exponent(x) != k {
        return false;
    }
    let m = odd_mantissa(x);
    let d = digits
        .iter()
        .fold(0u128, |v, &b| v * 10 + u128::from(b - b'0'));
    let times_five =
        |v: u128, n: i32| -> Option<u128> { (0..n.max(0)).try_fold(v, |v, _| v.checked_mul(5)) };
    matches!(
        (times_five(u128::from(m), -k), times_five(10 * d + 5, k)),
        (Some(a), Some(b)) if a == b
    )
}

/// `|x|`'s odd integer `m` of `|x| = m·2^e` (`x` finite, not zero).
fn odd_mantissa(x: f64) -> u64 {
    let (m, _) = mantissa_exponent(x);
    m >> m.trailing_zeros()
}

/// `|x|`'s `e` of `|x| = m·2^e` with `m` odd (`x` finite, not zero).
#[inline]
fn odd_mantissa_exponent(x: f64) -> i32 {
    let (m, e) = mantissa_exponent(x);
    e + m.trailing_zeros() as i32
}

/// `|x|` as `m·2^e` with `m` the 53-bit significand (fewer bits below the normal range).
#[inline]
fn mantissa_exponent(x: f64) -> (u64, i32) {
    let bits = x.to_bits();
    let (field, fraction) = ((bits >> 52) & 0x7ff, bits & ((1u64 << 52) - 1));
    if field == 0 {
        (fraction, -1074)
    } else {
        (fraction | 1 << 52, field as i32 - 1075)
    }
}

/// Adds one in the last place of the first `count` of `digits` (the first at `10^power`) and
/// trims trailing zeros: the new count and power.
fn round_up(digits: &mut [u8; 24], mut count: usize, mut power: i32) -> (usize, i32) {
    let mut i = count;
    loop {
        if i == 0 {
            // All nines: a one, a place up.
            digits[0] = b'1';
            count = 1;
            power += 1;
            break;
        }
        i -= 1;
        if digits[i] == b'9' {
            digits[i] = b'0';
        } else {
            digits[i] += 1;
            break;
        }
    }
    while count > 1 && digits[count - 1] == b'0' {
        count -= 1;
    }
    (count, power)
}

/// The exponent after ryu's `e`: an optional '-', then digits.
fn parse_exponent(text: &[u8]) -> i32 {
    let (negative, digits) = match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        _ => (false, text),
    };
    let magnitude = digits
        .iter()
        .fold(0i32, |v, &d| v * 10 + i32::from(d - b'0'));
    if negative { -magnitude } else { magnitude }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What `csv_number` wrote before: `format!`'s `{}` in the full range, `{:e}` outside it.
    fn by_format(x: f64) -> String {
        if x == 0.0 || !x.is_finite() || in_full(x) {
            format!("{x}")
        } else {
            format!("{x:e}")
        }
    }

    /// A fixed xorshift sequence from `seed` (not zero).
    fn xorshift(seed: u64) -> impl FnMut() -> u64 {
        let mut s = seed;
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        }
    }

    fn check(x: f64) {
        assert_eq!(csv_number(x), by_format(x), "bits {:#x}", x.to_bits());
        assert_eq!(
            CsvNumber(x).to_string(),
            by_format(x),
            "bits {:#x}",
            x.to_bits()
        );
    }

    #[test]
    fn the_edges_are_written_as_format_writes_them() {
        let mut values = vec![
            0.0,
            -0.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            f64::EPSILON,
            5e-324,
            1.0,
            0.1,
            0.3,
            2.0 / 3.0,
            123456789.0,
            9007199254740993.0,
            1.7976931348623157e308,
            0.5,
            100.0,
            1e-7,
            1e21,
            f64::from_bits(0x4317_9085_685d_83c9), // 1658206780088562.25, a tie
            0.5f64.powi(60) * 3.0,
        ];
        for e in -330..=310 {
            let p = format!("1e{e}").parse::<f64>().unwrap();
            values.extend([
                p,
                p.next_up(),
                p.next_down(),
                1.5 * p,
                9.999999999999999 * p,
            ]);
        }
        for v in values {
            check(v);
            check(-v);
        }
    }

    #[test]
    fn random_values_are_written_as_format_writes_them() {
        // A fixed xorshift: every bit pattern's kind (subnormal, every exponent) and values
        // at map and unit scales.
        let mut next = xorshift(0x9e37_79b9_7f4a_7c15);
        for _ in 0..1_000_000 {
            let bits = next();
            check(f64::from_bits(bits));
            let unit = (bits >> 11) as f64 / (1u64 << 53) as f64;
            check(unit);
            check(unit * 1e6 - 5e5);
            check((unit - 0.5) * 1e-6);
        }
    }

    #[test]
    fn values_with_short_exact_expansions_are_written_as_format_writes_them() {
        // m · 2^−j for odd m is (m · 5^j) · 10^−j exactly, its last digit a 5: where the
        // shortest digits are one shorter, it lies halfway between two of them (a tie, which
        // `format!` rounds up and ryu to even).
        let mut next = xorshift(0x2545_f491_4f6c_dd1d);
        let mut ties = 0;
        for _ in 0..200_000 {
            let m = (next() >> 11) | 1;
            for j in [1, 2, 3, 5, 8, 13, 21, 34] {
                let x = m as f64 * 0.5f64.powi(j);
                // A tie: the exact digits (m · 5^j) one longer than the shortest.
                let shortest = format!("{x:e}");
                let shortest = shortest.split('e').next().unwrap_or_default();
                let shortest = shortest.bytes().filter(u8::is_ascii_digit).count();
                let exact = (0..j).try_fold(u128::from(m), |v, _| v.checked_mul(5));
                if let Some(exact) = exact {
                    ties += usize::from(exact.to_string().len() == shortest + 1);
                }
                check(x);
                check(-x * 1e10);
            }
        }
        assert!(ties > 1000, "{ties} ties");
    }
}
