//! Fuzz the encoder: any message body and any output buffer size either encodes into the
//! buffer (and decodes back) or is refused; it never panics or writes out of bounds.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::*;

fuzz_target!(|data: &[u8]| {
    let (size, body) = match data.split_first() {
        Some((&s, rest)) => (usize::from(s) * 3, rest),
        None => return,
    };
    let mut chunk = heapless::Vec::<u8, FRAME_CHUNK_BYTES>::new();
    for &b in body.iter().take(FRAME_CHUNK_BYTES) {
        let _ = chunk.push(b);
    }
    let msg = HostToBoard::FrameChunk(FrameChunk {
        frame_id: 1,
        capture_us: WireTime(2),
        offset: 3,
        data: chunk,
    });
    let mut out = vec![0u8; size];
    if let Ok(n) = encode(&msg, &mut out) {
        assert!(n <= size);
        let mut decoder = HostToBoardDecoder::new();
        let mut got = None;
        decoder.feed(&out[..n], |m| got = Some(m));
        assert_eq!(got, Some(msg));
    }
});
