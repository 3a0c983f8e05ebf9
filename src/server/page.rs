//! The viewer page served at `GET /`: one self-contained HTML file (no external resources, no
//! build step), compiled into the binary.

use axum::response::Html;

/// The viewer page's HTML.
pub const VIEWER_HTML: &str = include_str!("viewer.html");

/// `GET /`.
pub(crate) async fn viewer() -> Html<&'static str> {
    Html(VIEWER_HTML)
}
