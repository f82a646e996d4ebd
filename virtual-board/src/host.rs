//! Talking to a board as a host does: framed protocol messages in, decoded messages out.

use protocol::{BoardToHost, Decoder, HostToBoard, Message};

/// The wire bytes of one host message (COBS frame with its delimiter).
///
/// # Panics
/// If the message does not fit the protocol's largest frame (a bench bug).
#[must_use]
pub fn frame(message: &HostToBoard) -> Vec<u8> {
    let mut buffer = vec![0u8; 1024];
    let len = protocol::encode(message, &mut buffer).expect("a host message fits its frame");
    buffer.truncate(len);
    buffer
}

/// Every message in `bytes` (a board's output to its host), and the decoder's error count.
#[must_use]
pub fn decode_board_to_host(bytes: &[u8]) -> (Vec<BoardToHost>, u32) {
    let mut decoder = Decoder::<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>::new_mid_stream();
    let mut messages = Vec::new();
    for &byte in bytes {
        if let Some(message) = decoder.push(byte) {
            messages.push(message);
        }
    }
    let errors = decoder.errors().total();
    (messages, errors)
}
