//! The live view: a [`FlightLog`](super::FlightLog)'s channels served as they are written, over
//! the Foxglove WebSocket protocol (the `foxglove` crate's server, on 127.0.0.1), so that
//! Foxglove or Lichtblick shows a running flight or a real board as it happens (Open
//! connection, Foxglove WebSocket, `ws://127.0.0.1:PORT`).
//!
//! Messages go out stamped with the wall clock as they are sent; the file keeps the flight's
//! own times.

use anyhow::anyhow;
use foxglove::{Context, RawChannel, Schema, WebSocketServer, WebSocketServerHandle};
use std::collections::HashMap;
use std::sync::Arc;

/// The port the live view listens on unless told otherwise (Foxglove's default).
pub const DEFAULT_PORT: u16 = 8765;

/// A running live-view server and the channels it serves.
pub struct LiveServer {
    context: Arc<Context>,
    server: Option<WebSocketServerHandle>,
    channels: HashMap<&'static str, Arc<RawChannel>>,
}

impl LiveServer {
    /// Starts serving on 127.0.0.1:`port` (0: a free port, see [`LiveServer::port`]).
    pub fn start(port: u16) -> anyhow::Result<Self> {
        let context = Context::new();
        let server = WebSocketServer::new()
            .name("pocket-drone")
            .context(&context)
            .bind("127.0.0.1", port)
            .start_blocking()
            .map_err(|e| anyhow!("starting the live view on 127.0.0.1:{port}: {e}"))?;
        Ok(Self {
            context,
            server: Some(server),
            channels: HashMap::new(),
        })
    }

    /// Starts serving (as [`LiveServer::start`]) and says where on standard error.
    pub fn start_announced(port: u16) -> anyhow::Result<Self> {
        let server = Self::start(port)?;
        eprintln!(
            "live view: ws://127.0.0.1:{} (Foxglove: Open connection, Foxglove WebSocket)",
            server.port()
        );
        Ok(server)
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        self.server.as_ref().map_or(0, WebSocketServerHandle::port)
    }

    /// Advertises `topic` with its schema (once; later calls are ignored).
    pub(super) fn add_channel(
        &mut self,
        topic: &'static str,
        schema: Schema,
        message_encoding: &str,
    ) -> anyhow::Result<()> {
        if self.channels.contains_key(topic) {
            return Ok(());
        }
        let channel = self
            .context
            .channel_builder(topic)
            .message_encoding(message_encoding)
            .schema(schema)
            .build_raw()
            .map_err(|e| anyhow!("live view: adding {topic}: {e}"))?;
        self.channels.insert(topic, channel);
        Ok(())
    }

    /// Sends a message on `topic` to the connected clients subscribed to it.
    pub(super) fn send(&self, topic: &str, data: &[u8]) {
        if let Some(channel) = self.channels.get(topic) {
            channel.log(data);
        }
    }

    /// Stops the server.
    pub fn stop(&mut self) {
        if let Some(server) = self.server.take() {
            server.stop().wait_blocking();
        }
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        self.stop();
    }
}
