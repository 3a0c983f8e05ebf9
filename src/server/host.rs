//! Which `Host` names the server answers to. A page on another web site can make the user's
//! browser reach a server on their machine through a name of its own (DNS rebinding: the
//! site's name first resolves to the site, then to 127.0.0.1); the browser then treats the
//! server as the site's own origin, so the `Origin` check ([`super::origin`]) passes and the
//! page can read the scene and its picks and edit it. A name that resolves to this machine
//! only by such a trick is never one the user typed, so a request is served only when its
//! `Host` is an IP address (the site cannot own one of this machine's), `localhost` or a name
//! under `.localhost` (browsers resolve those to the loopback themselves), or a name given with
//! `--allow-host` (a real name of the machine, a reverse proxy's public name; `*` allows any).
//! Others get 403 with a sentence. An HTTP/1.0 request without a `Host` (old clients, some
//! tools) is not a browser's and is served; an HTTP/1.1 one gets 400, as RFC 9112 (3.2) asks
//! (HTTP/2 names its host in the target, which is checked instead).

use super::api::{ApiError, AppState};
use axum::extract::{Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::net::{IpAddr, Ipv6Addr};
use std::sync::Arc;

/// The `--allow-host` value that allows every name.
pub const ANY_HOST: &str = "*";

/// Refuses a request whose `Host` the server does not answer to (see the module docs).
pub(crate) async fn known_hosts_only(
    State(state): State<Arc<AppState>>,
    request: Request,
    next: Next,
) -> Response {
    // The `Host` header, and the target's own authority where the request names one
    // (`GET http://name/path`, which a server must take over the header).
    let mut hosts = request.headers().get_all(header::HOST).iter();
    let header = hosts
        .next()
        .map(|h| String::from_utf8_lossy(h.as_bytes()).into_owned());
    if hosts.next().is_some() {
        // Which one a proxy in front read is anyone's guess (RFC 9112, 3.2: a 400).
        return ApiError::new(
            StatusCode::BAD_REQUEST,
            "the request has more than one Host header; send one",
        )
        .into_response();
    }
    let target = request.uri().authority().map(|a| a.as_str().to_owned());
    if header.is_none() && target.is_none() && request.version() == axum::http::Version::HTTP_11 {
        return ApiError::new(
            StatusCode::BAD_REQUEST,
            "an HTTP/1.1 request must name the server in a Host header; send one",
        )
        .into_response();
    }
    for host in header.iter().chain(&target) {
        if !allowed(host, &state.config.allowed_hosts) {
            let name = name_of(host);
            // Advice only where the flag would take the name as quoted (whole).
            let advice = match check_allowed_host(name) {
                Ok(_) if name.chars().count() <= 60 => format!(
                    "; start it with --allow-host {} if that is one of its names",
                    crate::budget::quote(name)
                ),
                _ => String::new(),
            };
            return ApiError::new(
                StatusCode::FORBIDDEN,
                format!(
                    "this server does not answer to the name {:?} (only to IP addresses, \
                     localhost and names given with --allow-host, against pages of other web \
                     sites that point their own names at it){advice}",
                    crate::budget::quote(host),
                ),
            )
            .into_response();
        }
    }
    next.run(request).await
}

/// Whether the server answers to `host` (a `Host` header: `name[:port]` or `[v6][:port]`).
pub(crate) fn allowed(host: &str, allowed_hosts: &[String]) -> bool {
    let name = name_of(host).trim_end_matches('.').to_ascii_lowercase();
    if name.is_empty() {
        return false;
    }
    let address = match name.strip_prefix('[') {
        Some(inner) => inner
            .strip_suffix(']')
            .is_some_and(|v6| v6.parse::<Ipv6Addr>().is_ok()),
        None => name.parse::<IpAddr>().is_ok(),
    };
    address
        || name == "localhost"
        || name.ends_with(".localhost")
        || allowed_hosts
            .iter()
            .any(|a| a == ANY_HOST || a.trim_end_matches('.').eq_ignore_ascii_case(&name))
}

/// The name of a `Host` header without its port: `example.com` of `example.com:8080`,
/// `[::1]` of `[::1]:8080`.
/// A bracketed IPv6 address followed by anything but a port is returned whole (and is then no
/// address).
fn name_of(host: &str) -> &str {
    let host = host.trim();
    if host.starts_with('[') {
        return match host.find(']') {
            Some(end) if port(&host[end + 1..]) => &host[..=end],
            _ => host,
        };
    }
    match host.rfind(':') {
        Some(colon) if port(&host[colon..]) => &host[..colon],
        _ => host,
    }
}

/// Whether `rest` (what follows a host's name) is nothing or `:` and a port number's digits.
fn port(rest: &str) -> bool {
    rest.is_empty()
        || rest
            .strip_prefix(':')
            .is_some_and(|digits| !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit()))
}

/// Checks a `--allow-host` value: a host name (letters, digits, `-`, `.`, `_`) or `*`, without
/// a port or a scheme.
pub fn check_allowed_host(name: &str) -> Result<String, String> {
    let valid = name == ANY_HOST
        || (!name.is_empty()
            && name.len() <= 253
            && name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'.' | b'_')));
    if valid {
        Ok(name.to_ascii_lowercase())
    } else {
        Err(format!(
            "{:?} is not a host name; give a name such as picks.example.com (no scheme, no \
             port), or * for any",
            crate::budget::quote(name)
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ip_addresses_and_localhost_are_answered_other_names_only_when_allowed() {
        let none: Vec<String> = Vec::new();
        for host in [
            "127.0.0.1:8080",
            "127.0.0.1",
            "[::1]:8080",
            "[::1]",
            "192.168.1.20:80",
            "localhost:8080",
            "LOCALHOST",
            "app.localhost:3000",
            "localhost.:8080",
        ] {
            assert!(allowed(host, &none), "{host}");
        }
        for host in [
            "evil.example:8080",
            "evil.example",
            "localhost.evil.example",
            "127.0.0.1.evil.example",
            "",
            ":8080",
            "[::1]evil.example",
            "[::1",
            "[::1]:80x",
        ] {
            assert!(!allowed(host, &none), "{host}");
        }
        let named = vec!["picks.example.com".to_owned()];
        assert!(allowed("Picks.Example.com:443", &named));
        assert!(allowed("picks.example.com.", &named));
        assert!(!allowed("example.com", &named));
        assert!(allowed("anything.example", &[ANY_HOST.to_owned()]));
    }

    #[test]
    fn allowed_host_values_are_bare_names() {
        assert_eq!(
            check_allowed_host("Picks.Example.com").unwrap(),
            "picks.example.com"
        );
        assert_eq!(check_allowed_host("*").unwrap(), "*");
        for bad in ["", "http://a.example", "a.example:8080", "a b", "*.example"] {
            assert!(check_allowed_host(bad).is_err(), "{bad}");
        }
    }
}
