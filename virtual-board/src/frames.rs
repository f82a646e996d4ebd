//! What the camera board's two sensors see: 128x96 luminance images, one per frame, from the
//! recorded data set or from anything that renders them ([`FrameSource`]).

use std::fmt::Debug;
use std::path::{Path, PathBuf};

/// Image width, pixels.
pub const WIDTH: usize = 128;
/// Image height, pixels.
pub const HEIGHT: usize = 96;
/// Pixels per image.
pub const PIXELS: usize = WIDTH * HEIGHT;
/// Bytes of an interleaved stereo frame `[L0 R0 L1 R1 ...]`, rows top first.
pub const STEREO_BYTES: usize = 2 * PIXELS;

/// The scene as the two sensors see it at one instant: luminance, rows top first.
#[derive(Clone, PartialEq, Eq)]
pub struct StereoImage {
    /// The left sensor's image.
    pub left: Box<[u8; PIXELS]>,
    /// The right sensor's image.
    pub right: Box<[u8; PIXELS]>,
}

impl Debug for StereoImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StereoImage").finish_non_exhaustive()
    }
}

impl StereoImage {
    /// Splits an interleaved frame `[L0 R0 L1 R1 ...]`.
    #[must_use]
    pub fn from_interleaved(frame: &[u8; STEREO_BYTES]) -> Self {
        let mut left = Box::new([0u8; PIXELS]);
        let mut right = Box::new([0u8; PIXELS]);
        for (i, pair) in frame.chunks_exact(2).enumerate() {
            left[i] = pair[0];
            right[i] = pair[1];
        }
        Self { left, right }
    }

    /// The interleaved frame `[L0 R0 L1 R1 ...]` a working camera board captures of this scene.
    #[must_use]
    pub fn interleaved(&self) -> Box<[u8; STEREO_BYTES]> {
        let mut frame = Box::new([0u8; STEREO_BYTES]);
        for i in 0..PIXELS {
            frame[2 * i] = self.left[i];
            frame[2 * i + 1] = self.right[i];
        }
        frame
    }

    /// Row `y` of the left and right images resampled (nearest pixel) to `width` x `height`, as
    /// a sensor set to another picture size sees the same scene.
    #[must_use]
    pub fn rows(&self, y: usize, width: usize, height: usize) -> (Vec<u8>, Vec<u8>) {
        let sy = (y * HEIGHT / height.max(1)).min(HEIGHT - 1);
        let pick = |img: &[u8; PIXELS]| {
            (0..width)
                .map(|x| img[sy * WIDTH + (x * WIDTH / width.max(1)).min(WIDTH - 1)])
                .collect()
        };
        (pick(&self.left), pick(&self.right))
    }

    /// Reads a BMP of the data set: 256x96, 8-bit grey (a palette), uncompressed; the BMP's left
    /// half is the right camera, its right half the left camera (the data set's layout).
    ///
    /// # Errors
    /// A file that cannot be read or is not such a BMP, with the reason.
    pub fn load_bmp(path: &Path) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::decode_bmp(&bytes).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Decodes the bytes of a data-set BMP (see [`StereoImage::load_bmp`]).
    ///
    /// # Errors
    /// Not a 256x96 8-bit uncompressed BMP, or truncated.
    pub fn decode_bmp(b: &[u8]) -> Result<Self, String> {
        let u32_at = |at: usize| -> Result<u32, String> {
            b.get(at..at + 4)
                .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
                .ok_or_else(|| "too short for a BMP header".to_string())
        };
        if !b.starts_with(b"BM") {
            return Err("not a BMP (no 'BM' signature)".into());
        }
        let offset = u32_at(10)? as usize;
        let header = u32_at(14)? as usize;
        let width = u32_at(18)? as i32;
        let height = u32_at(22)? as i32;
        let bpp = u32_at(28)? & 0xFFFF;
        let compression = u32_at(30)?;
        if width != 256 || height.unsigned_abs() != 96 || bpp != 8 || compression != 0 {
            return Err(format!(
                "{width}x{height}, {bpp} bits, compression {compression}: expected 256x96, 8 bits, none"
            ));
        }
        if b.len() < offset + 256 * 96 {
            return Err("pixel data truncated".into());
        }
        let palette = |index: u8| {
            b.get(14 + header + 4 * usize::from(index) + 1)
                .copied()
                .unwrap_or(index)
        };
        let mut left = Box::new([0u8; PIXELS]);
        let mut right = Box::new([0u8; PIXELS]);
        for row in 0..HEIGHT {
            let src_row = if height > 0 { HEIGHT - 1 - row } else { row };
            let src = &b[offset + src_row * 256..offset + (src_row + 1) * 256];
            for c in 0..WIDTH {
                left[row * WIDTH + c] = palette(src[WIDTH + c]);
                right[row * WIDTH + c] = palette(src[c]);
            }
        }
        Ok(Self { left, right })
    }
}

/// Where the sensors' images come from: asked once per frame the sensors start.
pub trait FrameSource: Debug + Send {
    /// The scene for frame `index` (0 for the first frame the sensors stream), which starts at
    /// `start_ns` of the board's virtual time, or `None` once the source has no more: the
    /// sensors then keep seeing the last one.
    fn frame(&mut self, index: u64, start_ns: u64) -> Option<StereoImage>;
}

/// Recorded images played in order, one per frame.
#[derive(Debug, Clone)]
pub struct Recorded {
    images: Vec<StereoImage>,
}

impl Recorded {
    /// Plays `images` in order.
    #[must_use]
    pub fn new(images: Vec<StereoImage>) -> Self {
        Self { images }
    }

    /// The first `count` images `1.bmp ..= count.bmp` of a data-set take directory.
    ///
    /// # Errors
    /// An image that is missing or not a data-set BMP.
    pub fn from_take(take: &Path, count: usize) -> Result<Self, String> {
        (1..=count)
            .map(|i| StereoImage::load_bmp(&take.join(format!("{i}.bmp"))))
            .collect::<Result<Vec<_>, _>>()
            .map(Self::new)
    }

    /// The images, in play order.
    #[must_use]
    pub fn images(&self) -> &[StereoImage] {
        &self.images
    }
}

impl FrameSource for Recorded {
    fn frame(&mut self, index: u64, _start_ns: u64) -> Option<StereoImage> {
        usize::try_from(index)
            .ok()
            .and_then(|i| self.images.get(i))
            .cloned()
    }
}

/// Take 1 of the recorded data set (board 1, forward camera), which the bench tests play:
/// under `VBOARD_DATASET` if set, else `../shared/data/stereoboard_testing` beside the checkout.
pub fn data_set_take_1() -> PathBuf {
    std::env::var_os("VBOARD_DATASET")
        .map_or_else(
            || {
                PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                    .join("../../shared/data/stereoboard_testing")
            },
            PathBuf::from,
        )
        .join("database_stereoboard_1/forward_camera/take1")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bmp(pixel: impl Fn(usize, usize) -> u8) -> Vec<u8> {
        let mut b = vec![0u8; 1078 + 256 * 96];
        b[..2].copy_from_slice(b"BM");
        b[10..14].copy_from_slice(&1078u32.to_le_bytes());
        b[14..18].copy_from_slice(&40u32.to_le_bytes());
        b[18..22].copy_from_slice(&256i32.to_le_bytes());
        b[22..26].copy_from_slice(&96i32.to_le_bytes());
        b[28..30].copy_from_slice(&8u16.to_le_bytes());
        for i in 0..256 {
            b[54 + 4 * i..58 + 4 * i].copy_from_slice(&[i as u8, i as u8, i as u8, 0]);
        }
        for row in 0..96 {
            for col in 0..256 {
                b[1078 + row * 256 + col] = pixel(row, col);
            }
        }
        b
    }

    #[test]
    fn a_bmp_is_flipped_and_its_halves_swapped() {
        // Bottom-up rows; the BMP's left half is the right camera.
        let img = StereoImage::decode_bmp(&bmp(|row, col| {
            if col < 128 {
                row as u8
            } else {
                200 + (row % 50) as u8
            }
        }))
        .unwrap();
        assert_eq!(img.right[0], 95, "top row is the BMP's last");
        assert_eq!(img.left[0], 200 + (95 % 50) as u8);
        let frame = img.interleaved();
        assert_eq!(StereoImage::from_interleaved(&frame), img);
        assert_eq!(frame[1], 95);
    }

    #[test]
    fn a_bmp_of_another_shape_is_refused_with_the_reason() {
        let mut b = bmp(|_, _| 0);
        b[18..22].copy_from_slice(&128i32.to_le_bytes());
        assert!(StereoImage::decode_bmp(&b).unwrap_err().contains("128x96"));
        assert!(StereoImage::decode_bmp(b"GIF89a").is_err());
        assert!(StereoImage::decode_bmp(&bmp(|_, _| 0)[..2000]).is_err());
    }

    #[test]
    fn a_smaller_picture_size_samples_the_same_scene() {
        let img = StereoImage::decode_bmp(&bmp(|_, col| (col % 128) as u8)).unwrap();
        let (l, r) = img.rows(0, 64, 48);
        assert_eq!(l.len(), 64);
        assert_eq!(r[1], 2);
        let (l, _) = img.rows(0, 640, 480);
        assert_eq!(l[5], 1);
    }
}
