//! The central host's word on a host it turned away. Zenoh refuses a host with the wrong run
//! id or secret inside its handshake and says so only in a debug-level trace of its own; the
//! central host listens for that trace alone and prints it.

use std::fmt::Debug;

use tracing::Level;
use tracing::field::{Field, Visit};
use tracing_subscriber::filter::Targets;
use tracing_subscriber::layer::{Context, SubscriberExt};
use tracing_subscriber::{Layer, Registry};

/// Where Zenoh traces a handshake it refused.
const HANDSHAKE: &str = "zenoh_transport::unicast::establishment";

/// Prints a line for every host Zenoh's authentication turns away. Installs this process's
/// tracing subscriber: call it once, in the central host, before it listens.
pub fn report() {
    let layer = Refusals.with_filter(Targets::new().with_target(HANDSHAKE, Level::DEBUG));
    // Another subscriber already installed keeps its place; refusals then go unprinted.
    let _ = tracing::subscriber::set_global_default(Registry::default().with(layer));
}

struct Refusals;

impl<S: tracing::Subscriber> Layer<S> for Refusals {
    fn on_event(&self, event: &tracing::Event<'_>, _: Context<'_, S>) {
        let mut message = MessageText(String::new());
        event.record(&mut message);
        if let Some(why) = refusal(&message.0) {
            eprintln!("refused a host that presented {why} (Zenoh's authentication)");
        }
    }
}

/// What a handshake's trace says was wrong, if it refused a host's credentials.
fn refusal(message: &str) -> Option<&'static str> {
    if message.contains("Invalid user") {
        Some("another run id")
    } else if message.contains("Invalid password") {
        Some("a wrong secret")
    } else {
        None
    }
}

struct MessageText(String);

impl Visit for MessageText {
    fn record_debug(&mut self, field: &Field, value: &dyn Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zenohs_refusals_are_told_apart() {
        let trace = |why| format!("UsrPwd extension - Recv OpenSyn. {why}");
        assert_eq!(refusal(&trace("Invalid user.")), Some("another run id"));
        assert_eq!(refusal(&trace("Invalid password.")), Some("a wrong secret"));
        assert_eq!(refusal("Failed to accept link before deadline"), None);
    }
}
