//! The live view's clients asking the run's control channel: a client publishes on
//! [`CONTROL_TOPIC`] in JSON, one request of the control protocol (docs/control.md) per
//! message, and the live view hands it to the run through its
//! [`twin_runtime::control::Inlet`], as a connection of the channel would. The reply comes
//! back on the `/control` channel the client sees (the run records each request with its
//! reply there). Offered only when the run has `--control` and the live view listens on a
//! loopback address: the channel can power any node off, and the WebSocket has no
//! authentication.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use foxglove::websocket::{Client, ClientChannel, ServerListener};
use twin_runtime::control::{Inlet, InletRefusal, MAX_LINE};

pub use twin_record::live::PUBLISH_ENCODING as CONTROL_ENCODING;

/// The topic a client publishes control requests on.
pub const CONTROL_TOPIC: &str = "/control";

/// What the live view did with its clients' control requests.
#[derive(Debug, Default)]
pub struct ControlCounts {
    /// Handed to the run.
    pub taken: AtomicU64,
    /// Refused (each kind logged the first time): on another topic or encoding, not a JSON
    /// object, too long, or the run's inlet full or closed.
    pub refused: AtomicU64,
}

/// Why a published message was not handed to the run.
#[derive(Debug, thiserror::Error)]
enum Refused {
    #[error("published on `{0}` in `{1}`: control requests are taken on `/control` in `json`")]
    Topic(String, String),
    #[error("not a JSON object: {0}")]
    NotAnObject(String),
    #[error(transparent)]
    Inlet(#[from] InletRefusal),
}

impl Refused {
    /// Its kind, for logging the first of each.
    fn kind(&self) -> usize {
        match self {
            Refused::Topic(..) => 0,
            Refused::NotAnObject(_) => 1,
            Refused::Inlet(_) => 2,
        }
    }
}

/// The live view's listener ([`twin_record::live::LiveServer::start`]): each message on
/// [`CONTROL_TOPIC`] to the run.
#[derive(Debug)]
pub struct ControlListener {
    inlet: Inlet,
    counts: Arc<ControlCounts>,
    /// Whether each kind of refusal has been logged.
    logged: [std::sync::atomic::AtomicBool; 3],
}

impl ControlCounts {
    /// Taken and refused so far.
    pub fn read(&self) -> (u64, u64) {
        (
            self.taken.load(Ordering::Relaxed),
            self.refused.load(Ordering::Relaxed),
        )
    }
}

impl ControlListener {
    /// Hand requests to `inlet`, counted in `counts`.
    pub fn new(inlet: Inlet, counts: Arc<ControlCounts>) -> Self {
        ControlListener {
            inlet,
            counts,
            logged: Default::default(),
        }
    }
}

/// The request line of a message published on `channel`: the JSON object re-written on
/// one line, or why not.
fn request_line(channel: &ClientChannel, payload: &[u8]) -> Result<String, Refused> {
    if channel.topic != CONTROL_TOPIC || channel.encoding != CONTROL_ENCODING {
        return Err(Refused::Topic(
            channel.topic.clone(),
            channel.encoding.clone(),
        ));
    }
    if payload.len() > MAX_LINE {
        return Err(InletRefusal::TooLong.into());
    }
    let value: serde_json::Value =
        serde_json::from_slice(payload).map_err(|e| Refused::NotAnObject(e.to_string()))?;
    if !value.is_object() {
        return Err(Refused::NotAnObject(format!("a JSON {}", kind_of(&value))));
    }
    Ok(value.to_string())
}

fn kind_of(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "boolean",
        serde_json::Value::Number(_) => "number",
        serde_json::Value::String(_) => "string",
        serde_json::Value::Array(_) => "array",
        serde_json::Value::Object(_) => "object",
    }
}

impl ServerListener for ControlListener {
    fn on_client_advertise(&self, client: Client, channel: &ClientChannel) {
        // Debug only: a client may advertise channels without end.
        tracing::debug!(
            "live view: client {} publishes on {} ({})",
            client.id(),
            channel.topic,
            channel.encoding
        );
    }

    fn on_message_data(&self, client: Client, channel: &ClientChannel, payload: &[u8]) {
        match request_line(channel, payload).and_then(|l| Ok(self.inlet.offer(l)?)) {
            Ok(()) => {
                self.counts.taken.fetch_add(1, Ordering::Relaxed);
            }
            Err(why) => {
                self.counts.refused.fetch_add(1, Ordering::Relaxed);
                if !self.logged[why.kind()].swap(true, Ordering::Relaxed) {
                    tracing::warn!(
                        "live view: client {}'s control request refused: {why} (further \
                         refusals of this kind are counted, not logged)",
                        client.id()
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn chan(topic: &str, encoding: &str) -> ClientChannel {
        ClientChannel {
            id: foxglove::websocket::ClientChannelId::new(1),
            topic: topic.into(),
            encoding: encoding.into(),
            schema_name: String::new(),
            schema_encoding: None,
            schema: None,
        }
    }

    #[test]
    fn a_published_request_is_one_line_of_the_control_protocol() {
        let c = chan("/control", "json");
        let pretty =
            b"{\n  \"op\": \"fault\",\n  \"kind\": \"power-off\",\n  \"target\": \"PL12\"\n}";
        assert_eq!(
            request_line(&c, pretty).unwrap(),
            r#"{"kind":"power-off","op":"fault","target":"PL12"}"#
        );
        assert!(matches!(
            request_line(&chan("/other", "json"), b"{}"),
            Err(Refused::Topic(..))
        ));
        assert!(matches!(
            request_line(&chan("/control", "protobuf"), b"{}"),
            Err(Refused::Topic(..))
        ));
        assert!(matches!(
            request_line(&c, b"[1]"),
            Err(Refused::NotAnObject(_))
        ));
        assert!(matches!(
            request_line(&c, b"{"),
            Err(Refused::NotAnObject(_))
        ));
        let long = format!("{{\"op\":\"{}\"}}", "x".repeat(MAX_LINE));
        assert!(matches!(
            request_line(&c, long.as_bytes()),
            Err(Refused::Inlet(InletRefusal::TooLong))
        ));
    }
}
