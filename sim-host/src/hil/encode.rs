//! The host's messages to the boards as bytes: one message framed for the wire
//! ([`push_msg`]), a camera frame as its `FrameChunk`s ([`encode_frame`]), and the signer of
//! the messages to the autopilot ([`host_signer`]).

use super::HilConfig;
use anyhow::anyhow;
use protocol::{
    encode, FrameChunk, HostToBoard, Message, WireTime, FRAME_CHUNK_BYTES, STEREO_FRAME_BYTES,
};

/// The signer of the host's messages to the autopilot (none without a key).
pub(super) fn host_signer(cfg: &HilConfig) -> crate::key::HostSigner {
    cfg.key.map_or_else(crate::key::HostSigner::default, |k| {
        crate::key::HostSigner::with_key(k, crate::key::link_id::HIL)
    })
}

/// Encodes one host message into `out`.
pub(super) fn push_msg(msg: &HostToBoard, out: &mut Vec<u8>) -> anyhow::Result<()> {
    let mut buf = [0u8; HostToBoard::MAX_FRAME_BYTES];
    let n = encode(msg, &mut buf).map_err(|e| anyhow!("encoding a host message: {e:?}"))?;
    out.extend_from_slice(buf.get(..n).unwrap_or(&[]));
    Ok(())
}

/// The chunks of one interleaved frame, encoded.
pub fn encode_frame(
    frame: &[u8; STEREO_FRAME_BYTES],
    frame_id: u16,
    capture: WireTime,
) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::with_capacity(STEREO_FRAME_BYTES + STEREO_FRAME_BYTES / 16);
    for (i, data) in frame.chunks(FRAME_CHUNK_BYTES).enumerate() {
        let msg = HostToBoard::FrameChunk(FrameChunk {
            frame_id,
            capture_us: capture,
            offset: (i * FRAME_CHUNK_BYTES) as u16,
            data: data
                .try_into()
                .map_err(|_| anyhow!("frame chunk larger than {FRAME_CHUNK_BYTES} bytes"))?,
        });
        push_msg(&msg, &mut out)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereo_board::app::{FrameAssembler, StereoBoardApp};
    use stereo_board::edge_fs::EdgeFsParams;

    #[test]
    fn frame_chunks_reassemble_on_the_board() {
        let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
        for (i, b) in frame.iter_mut().enumerate() {
            *b = (i * 7 % 251) as u8;
        }
        let bytes = encode_frame(&frame, 3, WireTime(123_456)).unwrap();
        let mut cb = Box::new(StereoBoardApp::new(EdgeFsParams::default_config()));
        let mut asm = Box::new(FrameAssembler::new());
        let mut got = None;
        cb.on_host_bytes(&bytes, &mut asm, |f, t| {
            got = Some((f == &*frame, t.as_micros()));
            false
        });
        assert_eq!(got, Some((true, 123_456)));
    }
}
