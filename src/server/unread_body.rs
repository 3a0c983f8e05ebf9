//! Owns one rule of every answer: a request whose body was not read to its end (refused for
//! its size, late or broken, a 403 from another site or through an unknown host name, a 404 or
//! 405, a 503 over the memory budget before the body was read, a `DELETE` with a body) has what
//! is left of it drained when that is small and already on its way, and otherwise gets
//! `connection: close`.
//!
//! hyper cannot take another request from a connection with a body still in it: it drains the
//! rest when that is already in its buffer and closes the connection otherwise, without a word
//! in the answer. Here a handler's unread body comes back to this middleware, which reads up to
//! [`DRAIN_BYTES`] more of it for at most [`DRAIN_WAIT`] (not a body declared larger, one that
//! failed to read, or one behind `Expect: 100-continue`, whose client sends it only when
//! asked): a small body the client sent whole leaves the connection open, as hyper would have;
//! a body that is large, late or broken ends it, and the answer says so, so a client does not
//! send its next request onto a connection that is about to end. An HTTP/1.0 request's closing
//! answer is sent as HTTP/1.0 (hyper would add `keep-alive` beside `close` to an HTTP/1.1
//! answer for a 1.0 client that asked for it).

use axum::body::{Body, Bytes};
use axum::extract::Request;
use axum::http::{HeaderValue, Version, header};
use axum::middleware::Next;
use axum::response::Response;
use http_body::{Body as HttpBody, Frame, SizeHint};
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

/// The most bytes of an unread body drained to keep its connection open.
const DRAIN_BYTES: usize = 64 * 1024;
/// The longest an unread body is waited on to keep its connection open.
const DRAIN_WAIT: Duration = Duration::from_millis(50);

/// The middleware: `request`'s body watched for its end; an unread rest drained if it is small
/// and at hand, else the answer marked `connection: close`.
pub(crate) async fn close_if_body_unread(request: Request, next: Next) -> Response {
    let (parts, body) = request.into_parts();
    let version = parts.version;
    // A rest worth draining: not one the client holds back until asked, nor one declared too
    // large to drain.
    let drainable = !parts.headers.contains_key(header::EXPECT)
        && body
            .size_hint()
            .upper()
            .is_none_or(|n| n <= DRAIN_BYTES as u64);
    let watch = Arc::new(Watch::default());
    let body = if body.is_end_stream() {
        watch.ended.store(true, Ordering::Release);
        body
    } else {
        Body::new(Watched {
            inner: Some(body),
            watch: watch.clone(),
            failed: false,
        })
    };
    let mut response = next.run(Request::from_parts(parts, body)).await;
    let left = watch.left.lock().map_or(None, |mut left| left.take());
    let ended = watch.ended.load(Ordering::Acquire)
        || match left {
            Some(body) if drainable => drained(body).await,
            _ => false,
        };
    if !ended {
        response
            .headers_mut()
            .insert(header::CONNECTION, HeaderValue::from_static("close"));
        if version == Version::HTTP_10 {
            *response.version_mut() = Version::HTTP_10;
        }
    }
    response
}

/// Whether the rest of `body` arrives whole, within [`DRAIN_BYTES`] and [`DRAIN_WAIT`].
async fn drained(mut body: Body) -> bool {
    let read = async {
        let mut bytes = 0;
        loop {
            match std::future::poll_fn(|cx| Pin::new(&mut body).poll_frame(cx)).await {
                None => return true,
                Some(Ok(frame)) => {
                    bytes += frame.data_ref().map_or(0, Bytes::len);
                    if bytes > DRAIN_BYTES {
                        return false;
                    }
                }
                Some(Err(_)) => return false,
            }
        }
    };
    tokio::time::timeout(DRAIN_WAIT, read)
        .await
        .unwrap_or(false)
}

/// What the middleware learns of a request body: whether it was read to its end, and the body
/// itself when a handler let it go unread.
#[derive(Default)]
struct Watch {
    ended: AtomicBool,
    left: Mutex<Option<Body>>,
}

/// A request body that notes when it has been read to its end, and hands itself back to the
/// middleware when dropped before that (unless it failed to read: a broken body is not
/// drained).
struct Watched {
    inner: Option<Body>,
    watch: Arc<Watch>,
    failed: bool,
}

impl HttpBody for Watched {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        let Some(inner) = self.inner.as_mut() else {
            return Poll::Ready(None);
        };
        let polled = Pin::new(&mut *inner).poll_frame(cx);
        let done = match &polled {
            Poll::Ready(None) => true,
            Poll::Ready(Some(Ok(_))) => inner.is_end_stream(),
            Poll::Ready(Some(Err(_))) => {
                self.failed = true;
                false
            }
            Poll::Pending => false,
        };
        if done {
            self.watch.ended.store(true, Ordering::Release);
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.as_ref().is_none_or(Body::is_end_stream)
    }

    fn size_hint(&self) -> SizeHint {
        self.inner
            .as_ref()
            .map_or_else(|| SizeHint::with_exact(0), Body::size_hint)
    }
}

impl Drop for Watched {
    fn drop(&mut self) {
        if self.failed || self.watch.ended.load(Ordering::Acquire) {
            return;
        }
        if let (Some(body), Ok(mut left)) = (self.inner.take(), self.watch.left.lock()) {
            *left = Some(body);
        }
    }
}
