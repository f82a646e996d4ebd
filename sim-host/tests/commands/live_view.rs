//! `sim-host fly --live` serves the flight as it happens over the Foxglove WebSocket protocol:
//! a WebSocket client connects as Foxglove does, sees the log's channels advertised with
//! their schemas, subscribes and receives messages that decode.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tungstenite::client::IntoClientRequest;
use tungstenite::Message;

/// Kills the flight when the test ends, however it ends.
struct Flight(Child);

impl Drop for Flight {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn a_live_flight_is_served_to_a_foxglove_client() {
    let dir = std::env::temp_dir().join(format!("fly-live-{}", std::process::id()));
    let mut flight = Flight(
        Command::new(env!("CARGO_BIN_EXE_sim-host"))
            .args([
                "fly",
                "--duration",
                "120",
                "--quiet",
                "--live",
                "--live-port",
                "0",
            ])
            .arg("--out")
            .arg(&dir)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    // The address comes first on standard error.
    let stderr = flight.0.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let url = loop {
        let line = lines
            .next()
            .expect("fly says where the live view is")
            .unwrap();
        if let Some(rest) = line.strip_prefix("live view: ") {
            break rest.split_whitespace().next().unwrap().to_string();
        }
    };
    assert!(url.starts_with("ws://127.0.0.1:"), "{url}");

    let mut request = url.as_str().into_client_request().unwrap();
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut ws, response) = tungstenite::connect(request).expect("the live view accepts");
    assert_eq!(
        response.headers()["Sec-WebSocket-Protocol"],
        "foxglove.sdk.v1"
    );

    // Channels are advertised as the flight writes them; subscribe to /tf (3D, protobuf) and
    // /state (a JSON record) once both are.
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut channels: Vec<(u64, String, String)> = Vec::new();
    let mut subscribed = false;
    let mut received: Vec<(u32, Vec<u8>)> = Vec::new();
    // Reads until five transforms and a state arrived: the two channels' messages interleave
    // as the flight writes them, so a fixed message count can hold only one channel's.
    let enough = |received: &[(u32, Vec<u8>)]| {
        let count = |sub: u32| received.iter().filter(|(s, _)| *s == sub).count();
        count(1) >= 5 && count(2) >= 1
    };
    while Instant::now() < deadline && !enough(&received) {
        match ws.read().expect("the live view stays up") {
            Message::Text(text) => {
                let v: serde_json::Value = serde_json::from_str(&text).unwrap();
                if v["op"] == "advertise" {
                    for c in v["channels"].as_array().unwrap() {
                        channels.push((
                            c["id"].as_u64().unwrap(),
                            c["topic"].as_str().unwrap().to_string(),
                            c["schemaName"].as_str().unwrap_or("").to_string(),
                        ));
                    }
                } else if v["op"] == "status"
                    && v["message"]
                        .as_str()
                        .is_some_and(|m| m.starts_with("Unknown channel ID"))
                {
                    // The foxglove server sends a channel's advertisement before it records the
                    // channel as advertised to this client, so a subscription that follows the
                    // advertisement closely can be refused; a client subscribes again.
                    subscribed = false;
                }
            }
            Message::Binary(data) => {
                // Message data: opcode 1, subscription id, timestamp, payload.
                assert_eq!(data[0], 1, "a message");
                let sub = u32::from_le_bytes(data[1..5].try_into().unwrap());
                received.push((sub, data[13..].to_vec()));
            }
            _ => {}
        }
        let id = |topic: &str| channels.iter().find(|c| c.1 == topic).map(|c| c.0);
        if !subscribed {
            if let (Some(tf), Some(state)) = (id("/tf"), id("/state")) {
                let subscribe = serde_json::json!({
                    "op": "subscribe",
                    "subscriptions": [{"id": 1, "channelId": tf}, {"id": 2, "channelId": state}],
                });
                ws.send(Message::text(subscribe.to_string())).unwrap();
                subscribed = true;
            }
        }
    }
    let schema = |topic: &str| {
        channels
            .iter()
            .find(|c| c.1 == topic)
            .map(|c| c.2.clone())
            .unwrap_or_default()
    };
    assert_eq!(schema("/tf"), "foxglove.FrameTransforms", "{channels:?}");
    assert_eq!(schema("/scene"), "foxglove.SceneUpdate", "{channels:?}");
    assert_eq!(schema("/state"), "pocket_drone.State", "{channels:?}");
    let tf: Vec<&Vec<u8>> = received
        .iter()
        .filter(|(s, _)| *s == 1)
        .map(|(_, d)| d)
        .collect();
    let states: Vec<&Vec<u8>> = received
        .iter()
        .filter(|(s, _)| *s == 2)
        .map(|(_, d)| d)
        .collect();
    assert!(
        tf.len() >= 5 && !states.is_empty(),
        "{} transforms, {} states",
        tf.len(),
        states.len()
    );
    let transforms =
        <foxglove::schemas::FrameTransforms as foxglove::Decode>::decode(&tf[0][..]).unwrap();
    assert!(transforms
        .transforms
        .iter()
        .any(|t| t.child_frame_id == "drone"));
    let state: serde_json::Value = serde_json::from_slice(states[0]).unwrap();
    assert!(state["mode"].is_string(), "{state}");
    drop(flight);
    let _ = std::fs::remove_dir_all(&dir);
}
