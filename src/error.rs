//! The crate's error type: every failure a caller can see, as a sentence.

/// Everything that can go wrong in raypick. Library code returns these; it does not panic on user
/// data.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// A file's content is malformed; `line` is 1-based when known.
    #[error("{path}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Parse {
        /// The file.
        path: String,
        /// The 1-based line, for text formats.
        line: Option<usize>,
        /// What is wrong, as a sentence.
        message: String,
    },
    /// A scene or argument is not usable as given.
    #[error("{0}")]
    Invalid(String),
    /// A size that comes from user input (an argument, a file's header, a request) would need
    /// more memory than the process's budget ([`crate::budget`]); the sentence names what
    /// needed it, the size and the limit.
    #[error("{0}")]
    OverBudget(String),
    /// No GPU adapter could be found (on machines without a GPU, install Mesa's lavapipe).
    #[error(
        "no GPU adapter found ({0}); install a Vulkan driver such as Mesa lavapipe (mesa-vulkan-drivers)"
    )]
    NoAdapter(String),
    /// The adapter refused to create a device.
    #[error("the GPU adapter refused to create a device: {0}")]
    RequestDevice(String),
    /// The scene needs more GPU memory in one binding than the adapter allows.
    #[error(
        "{what} needs {needed} bytes in one GPU binding, but this adapter allows at most {limit} (max_storage_buffer_binding_size); use the CPU backend or a smaller scene"
    )]
    TooLargeForGpu {
        /// Which buffer.
        what: &'static str,
        /// Bytes needed.
        needed: u64,
        /// The adapter's limit.
        limit: u64,
    },
    /// The requested kernel workgroup size is zero or beyond what the adapter allows.
    #[error(
        "a workgroup of {requested} invocations is not possible on this adapter: {limit_name} is {limit}"
    )]
    WorkgroupSize {
        /// The size asked for.
        requested: u32,
        /// The adapter limit it breaks (`max_compute_invocations_per_workgroup` or
        /// `max_compute_workgroup_size_x`), or "the smallest workgroup" for zero.
        limit_name: &'static str,
        /// That limit's value.
        limit: u32,
    },
    /// wgpu reported a validation, out-of-memory or internal error.
    #[error("GPU error: {0}")]
    Gpu(String),
    /// The GPU device was lost (driver reset, watchdog, or removal).
    #[error("the GPU device was lost: {0}")]
    DeviceLost(String),
}

/// Shorthand for results in this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// `text` with its control characters (a NUL, an escape sequence's ESC, a line break) written
/// as escapes (`\u{0}`, `\u{1b}`, `\n`), so a file name or token in a message cannot break the
/// line it is on or drive the terminal; with `keep_lines`, line breaks and tabs stay (a whole
/// message, whose GPU validation text may run over lines).
pub fn escape_controls(text: &str, keep_lines: bool) -> std::borrow::Cow<'_, str> {
    // Bidirectional formatting characters too: printed raw, a file name holding U+202E shows
    // its text reversed on a terminal.
    let bidi = |c: char| matches!(c, '\u{061C}' | '\u{200E}' | '\u{200F}' | '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}');
    let escaped =
        |c: char| (c.is_control() && !(keep_lines && matches!(c, '\n' | '\t'))) || bidi(c);
    if !text.chars().any(escaped) {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 16);
    for c in text.chars() {
        if escaped(c) {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    std::borrow::Cow::Owned(out)
}

/// `text` with every long token cut short by [`crate::budget::quote`] (at most 60 characters
/// and "…"): each run of non-blank characters longer than that, keeping a quote mark ('', "" or
/// ``) around it; then the whole cut at `most` characters. For messages that repeat user input
/// (a JSON reader's, the argument parser's), so a 10 MB token never reaches standard error.
pub fn shorten_tokens(text: &str, most: usize) -> String {
    const QUOTES: [char; 3] = ['\'', '"', '`'];
    let mut out = String::with_capacity(text.len().min(most + 8));
    let mut rest = text;
    while !rest.is_empty() {
        let blank_end = rest
            .find(|c: char| !c.is_whitespace())
            .unwrap_or(rest.len());
        out.push_str(&rest[..blank_end]);
        rest = &rest[blank_end..];
        let token_end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        let token = &rest[..token_end];
        rest = &rest[token_end..];
        if token.chars().nth(60).is_none() {
            out.push_str(token);
            continue;
        }
        let first = token.chars().next().unwrap_or_default();
        if QUOTES.contains(&first) {
            // `"body"tail`, e.g. `"zzz…",`: the body cut short, the closing mark and what
            // follows it kept.
            let inner = &token[first.len_utf8()..];
            out.push(first);
            match inner.rfind(first) {
                Some(close) => {
                    out.push_str(&crate::budget::quote(&inner[..close]));
                    out.push(first);
                    out.push_str(&crate::budget::quote(&inner[close + first.len_utf8()..]));
                }
                None => out.push_str(&crate::budget::quote(inner)),
            }
        } else {
            out.push_str(&crate::budget::quote(token));
        }
        if out.len() > most.saturating_mul(4) {
            break;
        }
    }
    match out.char_indices().nth(most) {
        None => out,
        Some((cut, _)) => format!("{}…", &out[..cut]),
    }
}

/// `text` with every quoted span ('…', "…" or `…`) of more than 60 characters cut short by
/// [`crate::budget::quote`], its quote marks kept. A span opens at a mark that starts the text
/// or follows a blank or an opening bracket, and closes at the next same mark that ends the text
/// or comes before a blank or punctuation, so a quoted token with blanks in it (serde's
/// ``unknown field `…` ``, whatever the field's name) is cut as one. Linear in `text`'s length.
pub fn shorten_quoted(text: &str) -> String {
    const QUOTES: [char; 3] = ['\'', '"', '`'];
    let mut out = String::new();
    let mut copied = 0;
    // Per quote mark: no closing mark after some place, so none after any later one either.
    let mut unclosed = [false; 3];
    let mut prev: Option<char> = None;
    let mut chars = text.char_indices();
    while let Some((at, c)) = chars.next() {
        let opens = prev.is_none_or(|p| p.is_whitespace() || "([{:=".contains(p));
        prev = Some(c);
        let Some(kind) = QUOTES.iter().position(|&q| q == c).filter(|_| opens) else {
            continue;
        };
        if unclosed[kind] {
            continue;
        }
        let body = at + c.len_utf8();
        let close = text[body..]
            .match_indices(c)
            .map(|(j, _)| body + j)
            .find(|&j| {
                text[j + c.len_utf8()..]
                    .chars()
                    .next()
                    .is_none_or(|n| n.is_whitespace() || ",.;:)]}".contains(n))
            });
        let Some(close) = close else {
            unclosed[kind] = true;
            continue;
        };
        let inner = &text[body..close];
        if inner.chars().nth(60).is_some() {
            out.push_str(&text[copied..body]);
            out.push_str(&crate::budget::quote(inner));
            copied = close;
        }
        // On after the closing mark.
        for (k, _) in chars.by_ref() {
            if k >= close {
                break;
            }
        }
    }
    out.push_str(&text[copied..]);
    out
}

#[cfg(test)]
mod tests {
    use super::{escape_controls, shorten_quoted, shorten_tokens};

    #[test]
    fn long_tokens_are_cut_and_short_ones_kept() {
        assert_eq!(shorten_tokens("a 'b' `c`", 100), "a 'b' `c`");
        let long = "x".repeat(10_000);
        let cut = shorten_tokens(&format!("field `{long}`, expected one of `a`"), 1000);
        assert!(cut.starts_with("field `xxx") && cut.ends_with("…`, expected one of `a`"));
        let cut = shorten_tokens(&format!("string \"{long}\", expected"), 1000);
        assert!(cut.ends_with("…\", expected"), "{cut}");
        assert!(cut.chars().count() < 120, "{cut}");
        let many = "ab ".repeat(10_000);
        assert!(shorten_tokens(&many, 300).chars().count() <= 301);
    }

    /// Control characters and bidirectional formatting ones are escaped; other text, line
    /// breaks with `keep_lines` included, stays.
    #[test]
    fn controls_and_bidi_characters_are_escaped() {
        assert_eq!(
            escape_controls("t\u{f3}w\u{202e}er\0.obj", false),
            "t\u{f3}w\\u{202e}er\\u{0}.obj"
        );
        assert_eq!(escape_controls("a\nb", true), "a\nb");
        assert_eq!(escape_controls("a\nb", false), "a\\nb");
        assert!(matches!(
            escape_controls("plain", false),
            std::borrow::Cow::Borrowed(_)
        ));
    }

    #[test]
    fn long_quoted_spans_are_cut_blanks_and_all() {
        let kept = "unknown field `rayz`, expected one of `rays`, `camera`";
        assert_eq!(shorten_quoted(kept), kept);
        let long = "x y ".repeat(10_000);
        let cut = shorten_quoted(&format!("unknown variant `{long}`, expected `all`"));
        assert!(cut.starts_with("unknown variant `x y x"), "{cut}");
        assert!(cut.ends_with("…`, expected `all`"), "{cut}");
        assert!(cut.chars().count() < 120, "{cut}");
        let cut = shorten_quoted(&format!("bad '{}' here", "z".repeat(100)));
        assert_eq!(cut, format!("bad '{}…' here", "z".repeat(60)));
        // Unclosed marks are left alone, in linear time.
        let open = "'a ".repeat(200_000);
        assert_eq!(shorten_quoted(&open), open);
    }
}
