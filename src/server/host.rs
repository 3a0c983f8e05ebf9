//! Which `Host` names the server answers to. A page on another web site can make the user's
//! browser reach a server on their machine through a name of its own (DNS rebinding: the
//! site's name first resolves to the site, then to 127.0.0.1); the browser then treats the
//! server as the site's own origin, so the `Origin` check ([`super::origin`]) passes and the
//! page can read the scene and its picks and edit it. A name that resolves to this machine
//! only by such a trick is never one the user typed, so a request is served only when its
//! `Host` is an IP address (the site cannot own one of this machine's), `localhost` or a name
//! under `.localhost` (browsers resolve those to the loopback themselves), or a name given with
//! `--allow-host` (a real name of the machine, a reverse proxy's public name; `*` allows any).
//! Others get 403 with a sentence. A request without a `Host` (HTTP/1.0 clients, some tools)
//! is not a browser's and is served.

use super::api::{ApiError, AppState};
use axum::extract::{Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::net::IpAddr;
use std::sync::Arc;

/// The `--allow-host` value that allows every name.
pub const ANY_HOST: &str = "*";

/// Refuses a request whose `Host` the server does not answer to (see the module docs).
pub(crate) async fn known_hosts_only(
    State(state): State<Arc<AppState>>,
    request: Request,
    next: Next,
) -> Response {
    if let Some(host) = request.headers().get(header::HOST) {
        let host = String::from_utf8_lossy(host.as_bytes());
        if !allowed(&host, &state.config.allowed_hosts) {
            return ApiError::new(
                StatusCode::FORBIDDEN,
                format!(
                    "this server does not answer to the name {:?} (only to IP addresses, \
                     localhost and names given with --allow-host, against pages of other web \
                     sites that point their own names at it); start it with --allow-host {} if \
                     that is one of its names",
                    crate::budget::quote(&host),
                    crate::budget::quote(name_of(&host))
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
    let bare = name.trim_start_matches('[').trim_end_matches(']');
    bare.parse::<IpAddr>().is_ok()
        || name == "localhost"
        || name.ends_with(".localhost")
        || allowed_hosts
            .iter()
            .any(|a| a == ANY_HOST || a.trim_end_matches('.').eq_ignore_ascii_case(&name))
}

/// The name of a `Host` header without its port: `example.com` of `example.com:8080`,
/// `[::1]` of `[::1]:8080`.
fn name_of(host: &str) -> &str {
    let host = host.trim();
    if host.starts_with('[') {
        return host.find(']').map_or(host, |end| &host[..=end]);
    }
    match host.rsplit_once(':') {
        Some((name, port)) if port.bytes().all(|b| b.is_ascii_digit()) => name,
        _ => host,
    }
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
