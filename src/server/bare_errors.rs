//! The sentence for the requests hyper refuses before any route sees them. hyper answers a
//! request it cannot parse itself, with an empty body: 400 (a malformed method, URI, version
//! or header), 414 (a URI over 65,534 bytes) or 431 (over 100 header fields, or a head of
//! several hundred KiB), and closes the connection; it offers no hook for the body. The connection's
//! writer ([`super::LimitedIo`]) hands each write to [`with_sentence`], which gives those three
//! answers the body every other error answer has, `{"error": "sentence"}`. No answer of the
//! routes is touched: each of their errors has a body.

/// hyper's automatic answers (its own words, as it writes them after the version) and the
/// sentence for each.
const ANSWERS: [(&[u8], &str); 3] = [
    (
        b" 400 Bad Request\r\n",
        "the request could not be read as HTTP: its method, URI, version or a header is \
         malformed",
    ),
    (
        b" 414 URI Too Long\r\n",
        "the request's URI is too long (at most 65,534 bytes): send the data in a POST body",
    ),
    (
        b" 431 Request Header Fields Too Large\r\n",
        "the request's head is too large: at most 100 header fields, and a few hundred KiB \
         before the body",
    ),
];

/// The most bytes an automatic error answer of hyper's takes (a status line, a few headers
/// and no body); longer writes are never one.
const BARE_HEAD_BYTES: usize = 4096;

/// The empty body's length as hyper writes it, and what takes its place.
const EMPTY: &[u8] = b"\r\ncontent-length: 0\r\n";

/// `written` with a JSON body saying what was wrong, when it is one whole automatic answer of
/// hyper's (the status line of [`ANSWERS`], an empty body, and `connection: close`; in an
/// HTTP/1.0 answer, which hyper writes on a connection whose last request was HTTP/1.0, the
/// close goes without saying); else `None`.
pub(super) fn with_sentence(written: &[u8]) -> Option<Vec<u8>> {
    // Every write of every answer comes here, a large answer's body in many writes of what is
    // left of it: what is not an automatic error's head is let go at its first bytes (the
    // head was searched whole on each write, hundreds of MB, and two large answers held the
    // runtime's threads for seconds).
    if !(written.starts_with(b"HTTP/1.1 ") || written.starts_with(b"HTTP/1.0 "))
        || written.len() > BARE_HEAD_BYTES
    {
        return None;
    }
    let says_close = find(written, b"\r\nconnection: close\r\n").is_some();
    let (closes, line) = if let Some(line) = written.strip_prefix(b"HTTP/1.1") {
        (says_close, line)
    } else {
        let line = written.strip_prefix(b"HTTP/1.0")?;
        (
            find(written, b"\r\nconnection: keep-alive\r\n").is_none(),
            line,
        )
    };
    let (_, sentence) = ANSWERS
        .iter()
        .find(|(status, _)| line.starts_with(status))?;
    if !closes || !written.ends_with(b"\r\n\r\n") {
        return None;
    }
    let at = find(written, EMPTY)?;
    let body = serde_json::json!({ "error": sentence }).to_string();
    let mut answer = Vec::with_capacity(written.len() + body.len() + 64);
    answer.extend_from_slice(&written[..at]);
    // An HTTP/1.0 answer ends its connection without saying so: this one says it.
    answer.extend_from_slice(
        format!(
            "\r\ncontent-type: application/json\r\ncontent-length: {}\r\n{}",
            body.len(),
            if says_close {
                ""
            } else {
                "connection: close\r\n"
            }
        )
        .as_bytes(),
    );
    answer.extend_from_slice(&written[at + EMPTY.len()..]);
    answer.extend_from_slice(body.as_bytes());
    Some(answer)
}

/// Where `needle` first occurs in `haystack`.
fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &[u8] = b"HTTP/1.1 414 URI Too Long\r\nconnection: close\r\ncontent-length: 0\r\n\
        date: Mon, 30 Nov 2026 08:36:20 GMT\r\n\r\n";

    /// Every write comes here, a large answer's body in many writes of what is left of it:
    /// what is no automatic answer is let go without reading it through. 2,000 writes of a
    /// 64 MB rest searched 128 GB (two 229 MB answers held the runtime's threads for 2–6 s).
    #[test]
    fn large_writes_are_let_go_at_once() {
        let mut body = vec![b' '; 64 << 20];
        let started = std::time::Instant::now();
        for k in 0..2000 {
            body[k] = b'{';
            assert!(with_sentence(&body[k..]).is_none());
        }
        // An automatic answer's head followed by anything is no whole answer either.
        let mut head = HEAD.to_vec();
        head.extend_from_slice(&body[..8192]);
        assert!(with_sentence(&head).is_none());
        assert!(
            started.elapsed() < std::time::Duration::from_secs(2),
            "{:?}",
            started.elapsed()
        );
    }

    #[test]
    fn an_automatic_answer_gets_its_sentence_and_keeps_its_head() {
        let answer = String::from_utf8(with_sentence(HEAD).expect("rewritten")).unwrap();
        let (head, body) = answer.split_once("\r\n\r\n").expect("a head and a body");
        let value: serde_json::Value = serde_json::from_str(body).expect("JSON");
        assert!(value["error"].as_str().unwrap().contains("URI is too long"));
        assert!(head.starts_with("HTTP/1.1 414 URI Too Long\r\n"));
        assert!(head.contains(&format!("\r\ncontent-length: {}\r\n", body.len())));
        assert!(head.contains("\r\ncontent-type: application/json\r\n"));
        assert!(head.contains("\r\ndate: "));
        assert_eq!(
            head.matches("\r\nconnection: close\r\n").count(),
            1,
            "{head}"
        );
        assert!(!head.contains("content-length: 0\r\n"));
    }

    #[test]
    fn an_http_1_0_automatic_answer_gets_its_sentence_too() {
        let head = b"HTTP/1.0 400 Bad Request\r\ncontent-length: 0\r\ndate: Mon, 30 Nov 2026 \
            08:36:20 GMT\r\n\r\n";
        let answer = String::from_utf8(with_sentence(head).expect("rewritten")).unwrap();
        assert!(
            answer.starts_with("HTTP/1.0 400 Bad Request\r\n"),
            "{answer}"
        );
        assert!(
            answer.ends_with("\"}") && answer.contains("could not be read"),
            "{answer}"
        );
        assert_eq!(
            answer.matches("\r\nconnection: close\r\n").count(),
            1,
            "{answer}"
        );
        let kept =
            b"HTTP/1.0 400 Bad Request\r\nconnection: keep-alive\r\ncontent-length: 0\r\n\r\n";
        assert_eq!(with_sentence(kept), None);
    }

    #[test]
    fn other_writes_are_left_alone() {
        // A route's answer, a part of one, another status, a kept-alive connection.
        let route = b"HTTP/1.1 400 Bad Request\r\ncontent-type: application/json\r\n\
            content-length: 20\r\nconnection: close\r\n\r\n{\"error\":\"bad pick\"}";
        let kept = b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n";
        let other =
            b"HTTP/1.1 405 Method Not Allowed\r\nconnection: close\r\ncontent-length: 0\r\n\r\n";
        for written in [
            &route[..],
            &HEAD[..40],
            &kept[..],
            &other[..],
            b"{\"t\": 1}",
        ] {
            assert_eq!(
                with_sentence(written),
                None,
                "{}",
                String::from_utf8_lossy(written)
            );
        }
    }
}
