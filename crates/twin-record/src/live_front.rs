//! The live view's front door: the address the user asked for, in front of the `foxglove`
//! crate's server, so that clients offering the Foxglove WebSocket protocol under its older
//! name get in too.
//!
//! The protocol the `foxglove` crate serves as `foxglove.sdk.v1` is the one Foxglove Studio
//! 1.x, Lichtblick and `@foxglove/ws-protocol` offer as `foxglove.websocket.v1` (same JSON
//! and binary messages; the SDK renamed it). The crate accepts only the new names and answers
//! any other offer with HTTP 400, and it has no hook for the handshake. So each connection
//! is taken here first: the upgrade request's `Sec-WebSocket-Protocol` offer of
//! `foxglove.websocket.v1` (when the client offers no `foxglove.sdk.*` name) is handed on as
//! `foxglove.sdk.v1`, the answer's choice is handed back under the name the client offered,
//! and from then on the bytes pass through untouched. Clients that offer the new names see
//! exactly the crate's handshake.
//!
//! Bounded like every outside link: at most [`MAX_CLIENTS`] connections at once (one more is
//! closed, counted and logged), a request head of at most [`MAX_HEAD`] bytes that must arrive
//! within [`HEAD_TIMEOUT`].
//!
//! When its clients may publish control requests ([`Origins::Trusted`]), a browser page
//! of another site must not be one of them: any page may open a WebSocket to a loopback
//! port, and its browser says which page in `Origin`. Requests from pages other than
//! those on this machine (`http(s)://127.0.0.1`, `localhost`, `[::1]`, any port), the
//! Foxglove web app (`https://app.foxglove.dev`) or a desktop app's `file://` are answered
//! 403 and closed, counted and logged; programs that are no browser send no `Origin`.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;

/// The subprotocol names the `foxglove` crate negotiates.
const SDK_V1: &str = "foxglove.sdk.v1";
const SDK_PREFIX: &str = "foxglove.sdk.";
/// The same protocol under the name older clients offer.
const LEGACY_V1: &str = "foxglove.websocket.v1";

/// Connections served at once.
pub const MAX_CLIENTS: usize = 32;
/// The largest HTTP head (request or answer) taken, in bytes.
pub const MAX_HEAD: usize = 16 * 1024;
/// How long a client has to send its whole upgrade request.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(10);

/// Whose browser pages the front lets in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origins {
    /// Any (a view that only shows the run).
    Any,
    /// Pages of this machine, Foxglove's web app and desktop apps (a view whose clients
    /// publish control requests).
    Trusted,
}

/// The pages trusted besides those served from this machine.
const TRUSTED_ORIGINS: [&str; 2] = ["https://app.foxglove.dev", "file://"];

/// Whether an upgrade request `head` comes from a page `origins` lets in: `Err` with the
/// page's origin when not.
pub fn origin_allowed(head: &[u8], origins: Origins) -> Result<(), String> {
    if origins == Origins::Any {
        return Ok(());
    }
    let text = String::from_utf8_lossy(head);
    let Some(origin) = text.split("\r\n").find_map(|line| {
        let (name, value) = line.split_once(':')?;
        name.trim()
            .eq_ignore_ascii_case("origin")
            .then(|| value.trim().to_ascii_lowercase())
    }) else {
        return Ok(());
    };
    let local = origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
        .is_some_and(this_machine);
    if local || TRUSTED_ORIGINS.contains(&origin.as_str()) {
        Ok(())
    } else {
        Err(origin)
    }
}

/// Whether an origin's `host[:port]` is this machine's: a loopback host, then nothing or
/// a port's digits.
fn this_machine(host_port: &str) -> bool {
    ["127.0.0.1", "localhost", "[::1]"].iter().any(|host| {
        host_port.strip_prefix(host).is_some_and(|port| {
            port.is_empty()
                || port
                    .strip_prefix(':')
                    .is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
        })
    })
}

/// Which name the client offered the protocol under.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Offer {
    /// A name the `foxglove` crate knows (or none it knows at all): passed on unchanged.
    AsIs,
    /// Only `foxglove.websocket.v1`: renamed on the way in and back on the way out.
    Legacy,
}

/// Why a connection was closed before it reached the server.
#[derive(Debug, thiserror::Error)]
pub enum FrontError {
    #[error("HTTP head longer than {MAX_HEAD} bytes")]
    HeadTooLong,
    #[error("connection closed before the end of the HTTP head")]
    Truncated,
    #[error("no complete upgrade request within {HEAD_TIMEOUT:?}")]
    Slow,
    #[error("a page of {0} may not publish control requests (403)")]
    Origin(String),
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// Counts kept by the front, for the run's log.
#[derive(Debug, Default)]
pub struct FrontCounts {
    /// Connections handed to the server under the legacy name.
    pub legacy: AtomicU64,
    /// Connections closed because [`MAX_CLIENTS`] were being served.
    pub refused_full: AtomicU64,
    /// Connections closed for a bad or slow request head.
    pub refused_head: AtomicU64,
}

/// Rewrite an upgrade request head (up to and including its blank line): an offer of only
/// `foxglove.websocket.v1` becomes an offer of `foxglove.sdk.v1`.
pub fn rewrite_request(head: &[u8]) -> (Vec<u8>, Offer) {
    let text = String::from_utf8_lossy(head);
    let offered: Vec<&str> = protocol_values(&text)
        .flat_map(|v| v.split(','))
        .map(str::trim)
        .collect();
    if offered.iter().any(|p| p.starts_with(SDK_PREFIX)) || !offered.contains(&LEGACY_V1) {
        return (head.to_vec(), Offer::AsIs);
    }
    (rename(&text, LEGACY_V1, SDK_V1).into_bytes(), Offer::Legacy)
}

/// Rewrite the server's answer head for a client that made `offer`.
pub fn rewrite_response(head: &[u8], offer: Offer) -> Vec<u8> {
    match offer {
        Offer::AsIs => head.to_vec(),
        Offer::Legacy => rename(&String::from_utf8_lossy(head), SDK_V1, LEGACY_V1).into_bytes(),
    }
}

/// The values of the `Sec-WebSocket-Protocol` header lines of an HTTP head.
fn protocol_values(head: &str) -> impl Iterator<Item = &str> {
    head.split("\r\n").filter_map(|line| {
        let (name, value) = line.split_once(':')?;
        name.trim()
            .eq_ignore_ascii_case("sec-websocket-protocol")
            .then_some(value)
    })
}

/// `head` with the token `from` of its `Sec-WebSocket-Protocol` lines replaced by `to`.
fn rename(head: &str, from: &str, to: &str) -> String {
    let lines = head.split("\r\n").map(|line| match line.split_once(':') {
        Some((name, value)) if name.trim().eq_ignore_ascii_case("sec-websocket-protocol") => {
            let tokens: Vec<&str> = value
                .split(',')
                .map(str::trim)
                .map(|t| if t == from { to } else { t })
                .collect();
            format!("{name}: {}", tokens.join(", "))
        }
        _ => line.to_owned(),
    });
    lines.collect::<Vec<_>>().join("\r\n")
}

/// Read an HTTP head: the bytes up to and including the first blank line, and whatever
/// came after it in the same reads.
async fn read_head<R: AsyncRead + Unpin>(r: &mut R) -> Result<(Vec<u8>, Vec<u8>), FrontError> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 2048];
    loop {
        let n = r.read(&mut chunk).await?;
        if n == 0 {
            return Err(FrontError::Truncated);
        }
        let from = buf.len().saturating_sub(3);
        buf.extend_from_slice(&chunk[..n]);
        if let Some(i) = buf[from..].windows(4).position(|w| w == b"\r\n\r\n") {
            let end = from + i + 4;
            let rest = buf.split_off(end);
            return Ok((buf, rest));
        }
        if buf.len() > MAX_HEAD {
            return Err(FrontError::HeadTooLong);
        }
    }
}

/// Accept connections on `listener` and pass each to the server at `inner`, until the
/// runtime stops.
pub async fn serve(
    listener: TcpListener,
    inner: SocketAddr,
    counts: Arc<FrontCounts>,
    origins: Origins,
) {
    let slots = Arc::new(Semaphore::new(MAX_CLIENTS));
    loop {
        let (client, peer) = match listener.accept().await {
            Ok(c) => c,
            Err(e) => {
                tracing::warn!("live view: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let Ok(slot) = slots.clone().try_acquire_owned() else {
            let n = counts.refused_full.fetch_add(1, Ordering::Relaxed) + 1;
            tracing::warn!(
                "live view: {peer} closed, {MAX_CLIENTS} clients already connected ({n} so far)"
            );
            continue;
        };
        let counts = counts.clone();
        tokio::spawn(async move {
            if let Err(e) = pass(client, inner, &counts, origins).await {
                let n = counts.refused_head.fetch_add(1, Ordering::Relaxed) + 1;
                tracing::warn!("live view: {peer} closed: {e} ({n} so far)");
            }
            drop(slot);
        });
    }
}

/// One connection: the handshake, renamed where the client needs it, then the bytes both
/// ways until either side closes.
async fn pass(
    mut client: TcpStream,
    inner: SocketAddr,
    counts: &FrontCounts,
    origins: Origins,
) -> Result<(), FrontError> {
    let (head, rest) = tokio::time::timeout(HEAD_TIMEOUT, read_head(&mut client))
        .await
        .map_err(|_| FrontError::Slow)??;
    if let Err(origin) = origin_allowed(&head, origins) {
        let _ = client
            .write_all(b"HTTP/1.1 403 Forbidden\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
            .await;
        return Err(FrontError::Origin(origin));
    }
    let (head, offer) = rewrite_request(&head);
    if offer == Offer::Legacy {
        counts.legacy.fetch_add(1, Ordering::Relaxed);
    }
    let mut server = TcpStream::connect(inner).await?;
    server.write_all(&head).await?;
    server.write_all(&rest).await?;
    let (answer, rest) = read_head(&mut server).await?;
    client.write_all(&rewrite_response(&answer, offer)).await?;
    client.write_all(&rest).await?;
    // A closed connection is how a WebSocket session ends; its error is not the front's.
    let _ = tokio::io::copy_bidirectional(&mut client, &mut server).await;
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    const REQ: &str = "GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n";

    #[test]
    fn a_view_taking_control_requests_lets_in_only_trusted_pages() {
        let with = |origin: &str| format!("{REQ}Origin: {origin}\r\n\r\n").into_bytes();
        let none = format!("{REQ}\r\n").into_bytes();
        for ok in [
            "http://127.0.0.1:8080",
            "http://localhost",
            "HTTPS://LOCALHOST:3000",
            "http://[::1]:9",
            "https://app.foxglove.dev",
            "file://",
        ] {
            assert_eq!(origin_allowed(&with(ok), Origins::Trusted), Ok(()), "{ok}");
        }
        assert_eq!(origin_allowed(&none, Origins::Trusted), Ok(()));
        for bad in [
            "https://evil.example",
            "null",
            "http://127.0.0.1.evil.example",
            "http://localhost.evil.example:80",
            "https://app.foxglove.dev.evil.example",
            "http://127.0.0.1:80.evil.example",
            "http://[::1]x.evil.example",
            "http://127.0.0.1@evil.example",
        ] {
            assert!(
                origin_allowed(&with(bad), Origins::Trusted).is_err(),
                "{bad}"
            );
            assert_eq!(origin_allowed(&with(bad), Origins::Any), Ok(()), "{bad}");
        }
    }

    fn req(protocols: &str) -> Vec<u8> {
        format!("{REQ}Sec-WebSocket-Protocol: {protocols}\r\n\r\n").into_bytes()
    }

    #[test]
    fn legacy_offer_is_renamed_both_ways() {
        let (out, offer) = rewrite_request(&req("foxglove.websocket.v1"));
        assert_eq!(offer, Offer::Legacy);
        assert_eq!(out, req("foxglove.sdk.v1"));
        let answer =
            b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n";
        assert_eq!(
            rewrite_response(answer, offer),
            b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.websocket.v1\r\n\r\n"
        );
    }

    #[test]
    fn sdk_offers_and_others_pass_unchanged() {
        for p in [
            "foxglove.sdk.v1",
            "foxglove.sdk.v1.1, foxglove.websocket.v1",
            "foxglove.websocket.v1, foxglove.sdk.v1",
            "something.else",
        ] {
            let (out, offer) = rewrite_request(&req(p));
            assert_eq!((out, offer), (req(p), Offer::AsIs), "{p}");
        }
        let no_header = format!("{REQ}\r\n").into_bytes();
        assert_eq!(rewrite_request(&no_header).1, Offer::AsIs);
        let answer = b"HTTP/1.1 101 x\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n";
        assert_eq!(rewrite_response(answer, Offer::AsIs), answer.to_vec());
    }

    #[test]
    fn header_name_is_case_insensitive_and_lists_are_kept() {
        let head = format!("{REQ}SEC-WEBSOCKET-PROTOCOL: a ,foxglove.websocket.v1\r\n\r\n");
        let (out, offer) = rewrite_request(head.as_bytes());
        assert_eq!(offer, Offer::Legacy);
        assert_eq!(
            String::from_utf8(out).unwrap(),
            format!("{REQ}SEC-WEBSOCKET-PROTOCOL: a, foxglove.sdk.v1\r\n\r\n")
        );
    }

    #[tokio::test]
    async fn head_reader_splits_and_bounds() {
        let mut r: &[u8] = b"GET / HTTP/1.1\r\nA: b\r\n\r\nFRAME";
        let (head, rest) = read_head(&mut r).await.unwrap();
        assert_eq!(head, b"GET / HTTP/1.1\r\nA: b\r\n\r\n");
        assert_eq!(rest, b"FRAME");
        let mut short: &[u8] = b"GET / HTTP/1.1\r\n";
        assert!(matches!(
            read_head(&mut short).await,
            Err(FrontError::Truncated)
        ));
        let long = vec![b'a'; MAX_HEAD + 10];
        let mut r: &[u8] = &long;
        assert!(matches!(
            read_head(&mut r).await,
            Err(FrontError::HeadTooLong)
        ));
    }
}
