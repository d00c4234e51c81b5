//! What a host prints of Zenoh's own traces. The central host's word on a host it turned
//! away: Zenoh refuses a host with the wrong run id or secret inside its handshake and says so
//! only in a debug-level trace of its own; the central host listens for that trace alone and
//! prints it. And, on either side, the traces a user asks for with `RUST_LOG` (for instance
//! `RUST_LOG=zenoh=debug`: each connection attempt, lease and reconnection), on stderr.

use std::fmt::Debug;
use std::io::IsTerminal;
use std::str::FromStr;

use tracing::Level;
use tracing::field::{Field, Visit};
use tracing_subscriber::filter::Targets;
use tracing_subscriber::layer::{Context, SubscriberExt};
use tracing_subscriber::{Layer, Registry};

/// Where Zenoh traces a handshake it refused.
const HANDSHAKE: &str = "zenoh_transport::unicast::establishment";

/// The variable naming the traces a user wants printed (tracing's target=level syntax).
const LOG_VAR: &str = "RUST_LOG";

/// Installs this process's tracing subscriber: on the central host (`central`) a line for
/// every host Zenoh's authentication turns away, and on any host the traces `RUST_LOG` asks
/// for. Call it once, before the Zenoh session opens.
pub fn install(central: bool) {
    let refusals =
        central.then(|| Refusals.with_filter(Targets::new().with_target(HANDSHAKE, Level::DEBUG)));
    let asked = std::env::var(LOG_VAR).ok().and_then(|text| {
        Targets::from_str(&text)
            .inspect_err(|e| eprintln!("{LOG_VAR}={text:?} is not target=level,...: {e}"))
            .ok()
    });
    let printed = asked.map(|targets| {
        tracing_subscriber::fmt::layer()
            .with_writer(std::io::stderr)
            .with_ansi(std::io::stderr().is_terminal())
            .with_filter(targets)
    });
    // Another subscriber already installed keeps its place; these then go unprinted.
    let _ =
        tracing::subscriber::set_global_default(Registry::default().with(refusals).with(printed));
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
