//! The data set's BMPs as the camera board sees them, shared by the benchmark's build script and
//! `cargo xtask insns` (which streams every frame of every take to the benchmark).

/// Frame width, pixels per camera.
pub const W: usize = 128;
/// Frame height, rows.
pub const H: usize = 96;

/// Converts one data-set BMP into an interleaved 128x96 stereo frame.
pub fn interleave(bmp: &[u8]) -> Result<Vec<u8>, String> {
    let u32_at = |at: usize| -> Result<u32, String> {
        bmp.get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| "truncated header".to_string())
    };
    let offset = u32_at(10)? as usize;
    let (width, height) = (u32_at(18)? as i32, u32_at(22)? as i32);
    let bpp = bmp.get(28).copied().unwrap_or(0);
    if width != 2 * W as i32 || height.unsigned_abs() as usize != H || bpp != 8 {
        return Err(format!(
            "expected 256x96 8-bit, got {width}x{height} {bpp}-bit"
        ));
    }
    let pixels = bmp
        .get(offset..offset + 2 * W * H)
        .ok_or("truncated pixel data")?;
    let mut frame = vec![0u8; 2 * W * H];
    for row in 0..H {
        let src_row = if height > 0 { H - 1 - row } else { row };
        let src = &pixels[src_row * 2 * W..(src_row + 1) * 2 * W];
        for c in 0..W {
            frame[2 * (row * W + c)] = src[W + c]; // left camera: right half of the BMP
            frame[2 * (row * W + c) + 1] = src[c]; // right camera: left half
        }
    }
    Ok(frame)
}
