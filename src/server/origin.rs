//! Which requests may change the server's state: those that do not come from another web
//! site. A browser sends a page's cross-site `POST` with a `text/plain` body without asking the
//! server first (no preflight), so without this check any page a user visits could add, move or
//! remove objects of a server on their machine, or keep its worker busy. A request whose
//! method is not `GET`, `HEAD` or `OPTIONS` and whose `Origin` header names another site than
//! its `Host` (or is `null`: a sandboxed frame, a local file) gets 403 with a sentence.
//! Clients that are not browsers (curl, scripts, the Python package) send no `Origin` and are
//! not affected; the viewer page, served by this server, is of the same origin.

use super::api::ApiError;
use axum::extract::Request;
use axum::http::{Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

/// Refuses a state-changing request from another origin (see the module docs).
pub(crate) async fn same_origin_only(request: Request, next: Next) -> Response {
    if matches!(
        *request.method(),
        Method::GET | Method::HEAD | Method::OPTIONS
    ) {
        return next.run(request).await;
    }
    let headers = request.headers();
    let text = |name| {
        headers
            .get(name)
            .map(|v| String::from_utf8_lossy(v.as_bytes()))
    };
    if let Some(origin) = text(header::ORIGIN) {
        let host = text(header::HOST).unwrap_or_default();
        if !same_site(&origin, &host) {
            return ApiError::new(
                StatusCode::FORBIDDEN,
                format!(
                    "a {} from another web site is refused: its Origin {:?} is not this \
                     server ({:?}); send it from the server's own page, or without an Origin \
                     header",
                    request.method(),
                    crate::budget::quote(&origin),
                    crate::budget::quote(&host)
                ),
            )
            .into_response();
        }
    }
    next.run(request).await
}

/// Whether `origin` (`scheme://host[:port]`) names the server reached as `host` (`host[:port]`),
/// the scheme's default port written or not, letters in either case.
fn same_site(origin: &str, host: &str) -> bool {
    let Some((scheme, authority)) = origin.trim().split_once("://") else {
        return false;
    };
    let default = match scheme.to_ascii_lowercase().as_str() {
        "http" => ":80",
        "https" => ":443",
        _ => return false,
    };
    let plain = |a: &str| {
        let a = a.trim().to_ascii_lowercase();
        match a.strip_suffix(default) {
            Some(bare) => bare.to_owned(),
            None => a,
        }
    };
    !host.trim().is_empty() && plain(authority) == plain(host)
}

#[cfg(test)]
mod tests {
    use super::same_site;

    #[test]
    fn the_same_site_is_its_host_with_or_without_the_default_port() {
        assert!(same_site("http://127.0.0.1:8080", "127.0.0.1:8080"));
        assert!(same_site("http://Example.com", "example.com:80"));
        assert!(same_site("https://example.com:443", "example.com"));
        assert!(same_site("http://[::1]:8080", "[::1]:8080"));
        assert!(!same_site("http://evil.example", "127.0.0.1:8080"));
        assert!(!same_site("http://127.0.0.1:8081", "127.0.0.1:8080"));
        assert!(!same_site("https://example.com", "example.com:80"));
        assert!(!same_site("null", "127.0.0.1:8080"));
        assert!(!same_site("file://", ""));
        assert!(!same_site("http://127.0.0.1:8080", ""));
    }
}
