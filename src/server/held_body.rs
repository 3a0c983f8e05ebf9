//! Owns one rule of the memory budget: an answer's memory stays reserved until hyper has sent
//! it, not only until its handler returns. A pick's JSON answer (up to hundreds of MB) lives in
//! the response while a client reads it; released when the handler returned, the budget let
//! new picks in while six slow readers held twice the budget, and clients that never read held
//! theirs until the idle timeout, uncounted. The reservation is owned by the answer's bytes
//! themselves (hyper may end the body while it still holds them in its write queue), so it is
//! given back when the last of them has been written or dropped.

use super::api::Reservation;
use axum::body::{Body, Bytes};

/// An answer's bytes and the reservation that counts them.
struct Owned {
    data: Vec<u8>,
    _memory: Reservation,
}

impl AsRef<[u8]> for Owned {
    fn as_ref(&self) -> &[u8] {
        &self.data
    }
}

/// `data` as a response body that keeps `memory` reserved as long as any of it is held.
pub(crate) fn holding(data: Vec<u8>, memory: Reservation) -> Body {
    Body::from(Bytes::from_owner(Owned {
        data,
        _memory: memory,
    }))
}
