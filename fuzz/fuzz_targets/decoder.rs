//! Fuzz the streaming decoders of every direction with arbitrary byte streams.
//!
//! Invariants checked: no panic; every delimiter ends exactly one frame, which is either
//! delivered or counted as an error; every delivered message re-encodes to a frame that decodes
//! to the same message.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::*;

fn check<M: Message + Clone + PartialEq + core::fmt::Debug, const N: usize>(data: &[u8]) {
    let mut decoder = Decoder::<M, N>::new();
    let mut delivered = 0u32;
    let mut wire = [0u8; 2048];
    for &byte in data {
        if let Some(msg) = decoder.push(byte) {
            delivered += 1;
            let n = encode(&msg, &mut wire).expect("a decoded message re-encodes");
            let mut again = Decoder::<M, N>::new();
            let mut out = None;
            again.feed(&wire[..n], |m| out = Some(m));
            let out = out.expect("the re-encoded frame decodes");
            // Compare encodings, not values: NaN payloads are not equal to themselves.
            let mut wire2 = [0u8; 2048];
            let n2 = encode(&out, &mut wire2).expect("encode");
            assert_eq!(&wire[..n], &wire2[..n2]);
        }
    }
    let delimiters = data.iter().filter(|&&b| b == DELIMITER).count() as u32;
    assert_eq!(delivered + decoder.errors().total(), delimiters);
}

fuzz_target!(|data: &[u8]| {
    check::<StereoToAutopilot, { StereoToAutopilot::MAX_FRAME_BYTES }>(data);
    check::<AutopilotToStereo, { AutopilotToStereo::MAX_FRAME_BYTES }>(data);
    check::<HostToBoard, { HostToBoard::MAX_FRAME_BYTES }>(data);
    check::<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>(data);
});
