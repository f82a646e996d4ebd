//! The stereoboard_testing data set: take discovery and the file formats (images, timing.dat,
//! position.dat, `%i.bmp.tme`, calibration_data.txt).
//!
//! Images are decoded by the `image` crate: the data set's 8-bit BMPs, and PNG for users' own
//! recordings (`1.png`, `2.png`, ... in the same layout).

use anyhow::{bail, ensure, Context, Result};
use protocol::STEREO_FRAME_BYTES;
use std::path::{Path, PathBuf};

/// One forward-camera take of the data set.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Take {
    /// Board number (1 or 2), from `database_stereoboard_N`.
    pub board: u32,
    /// Take number, from `takeK`.
    pub take: u32,
    /// The take's directory.
    pub dir: PathBuf,
}

impl Take {
    /// Directory of the board (`database_stereoboard_N`).
    pub fn board_dir(&self) -> PathBuf {
        self.dir
            .parent()
            .and_then(Path::parent)
            .map(Path::to_path_buf)
            .unwrap_or_default()
    }

    /// Number of images `1.bmp ..= N.bmp` (or `.png`), counted until the first gap.
    pub fn image_count(&self) -> usize {
        (1..).take_while(|i| self.image_path(*i).is_file()).count()
    }

    /// Path of image `i` (1-based): `i.bmp`, or `i.png` where there is no BMP of that number.
    pub fn image_path(&self, i: usize) -> PathBuf {
        let bmp = self.dir.join(format!("{i}.bmp"));
        let png = self.dir.join(format!("{i}.png"));
        if !bmp.is_file() && png.is_file() {
            png
        } else {
            bmp
        }
    }
}

fn number_after(name: &str, prefix: &str) -> Option<u32> {
    name.strip_prefix(prefix)?.parse().ok()
}

/// Finds every forward take under `dataset` (`database_stereoboard_N/forward_camera/takeK/`),
/// sorted by board and take.
pub fn discover_takes(dataset: &Path) -> Result<Vec<Take>> {
    let mut takes = Vec::new();
    let entries = std::fs::read_dir(dataset)
        .with_context(|| format!("cannot read data set directory {}", dataset.display()))?;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(board) = number_after(&name, "database_stereoboard_") else {
            continue;
        };
        let fwd = entry.path().join("forward_camera");
        let Ok(tdirs) = std::fs::read_dir(&fwd) else {
            continue;
        };
        for t in tdirs.flatten() {
            let tname = t.file_name().to_string_lossy().to_ascii_lowercase();
            if let Some(take) = number_after(&tname, "take") {
                if t.path().is_dir() {
                    takes.push(Take {
                        board,
                        take,
                        dir: t.path(),
                    });
                }
            }
        }
    }
    takes.sort_by_key(|t| (t.board, t.take));
    if takes.is_empty() {
        bail!(
            "no forward takes (database_stereoboard_N/forward_camera/takeK) in {}",
            dataset.display()
        );
    }
    Ok(takes)
}

/// Width of a data-set image, px: the two 128-px cameras side by side.
pub const IMAGE_WIDTH: u32 = 256;
/// Height of a data-set image, px.
pub const IMAGE_HEIGHT: u32 = 96;

/// A recorded (or rendered) stereo frame, interleaved as the camera board receives it.
pub type Frame = Box<[u8; STEREO_FRAME_BYTES]>;

/// Reads an image of the data set (BMP or PNG, 256x96, gray; left half = right camera) into an
/// interleaved stereo frame `[L0 R0 L1 R1 ...]`, top row first. Errors name the file and the
/// problem.
pub fn load_frame(path: &Path) -> Result<Frame> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    decode_frame(&bytes).with_context(|| format!("bad image {}", path.display()))
}

/// Decodes the bytes of a BMP or PNG file (see [`load_frame`]).
///
/// Gray images are taken as they are; colour images whose pixels are all gray (such as an
/// 8-bit BMP with a gray palette) by their value, other colour images by their luma, and
/// 16-bit images scaled to 8 bits.
pub fn decode_frame(b: &[u8]) -> Result<Box<[u8; STEREO_FRAME_BYTES]>> {
    use image::{codecs, DynamicImage, ImageDecoder, ImageFormat};
    let format = image::guess_format(b)
        .ok()
        .filter(|f| matches!(f, ImageFormat::Bmp | ImageFormat::Png))
        .context("neither a BMP nor a PNG file (unknown signature)")?;
    let cursor = std::io::Cursor::new(b);
    let image = match format {
        ImageFormat::Png => {
            let decoder = codecs::png::PngDecoder::new(cursor).context("bad PNG header")?;
            check_header(decoder.dimensions(), decoder.color_type(), "PNG")?;
            DynamicImage::from_decoder(decoder)
        }
        _ => {
            let decoder = codecs::bmp::BmpDecoder::new(cursor).context("bad BMP header")?;
            check_header(decoder.dimensions(), decoder.color_type(), "BMP")?;
            DynamicImage::from_decoder(decoder)
        }
    }
    .map_err(|e| match e {
        image::ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            anyhow::anyhow!("pixel data truncated (the file ends inside the image)")
        }
        other => anyhow::anyhow!("cannot decode the pixels: {other}"),
    })?;
    let gray = to_gray(image);
    let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
    let half = (IMAGE_WIDTH / 2) as usize;
    for (row, src) in gray.chunks_exact(IMAGE_WIDTH as usize).enumerate() {
        for c in 0..half {
            // Left camera = image right half; right camera = image left half.
            frame[2 * (row * half + c)] = src[half + c];
            frame[2 * (row * half + c) + 1] = src[c];
        }
    }
    Ok(frame)
}

/// Rejects images of the wrong size before their pixels are decoded.
fn check_header((w, h): (u32, u32), color: image::ColorType, kind: &str) -> Result<()> {
    ensure!(
        (w, h) == (IMAGE_WIDTH, IMAGE_HEIGHT),
        "size {w}x{h} (expected {IMAGE_WIDTH}x{IMAGE_HEIGHT}: two 128x96 cameras side by side; \
         {kind}, {color:?})"
    );
    Ok(())
}

/// One 8-bit gray value per pixel, row-major, top row first.
fn to_gray(image: image::DynamicImage) -> Vec<u8> {
    use image::DynamicImage;
    match image {
        DynamicImage::ImageLuma8(g) => g.into_raw(),
        DynamicImage::ImageRgb8(rgb) if rgb.pixels().all(|p| p[0] == p[1] && p[1] == p[2]) => {
            rgb.pixels().map(|p| p[0]).collect()
        }
        DynamicImage::ImageRgba8(rgba) if rgba.pixels().all(|p| p[0] == p[1] && p[1] == p[2]) => {
            rgba.pixels().map(|p| p[0]).collect()
        }
        other => other.to_luma8().into_raw(),
    }
}

/// A numeric table file (whitespace separated). `header` tells whether the first line was a
/// `%`-header.
#[derive(Debug, Clone)]
pub struct Table {
    /// Data rows.
    pub rows: Vec<Vec<f64>>,
    /// The file started with a header line.
    pub header: bool,
}

/// Reads a whitespace-separated numeric file with at least `min_cols` columns per row. A first
/// line starting with `%` is a header; with `skip_first_line` the first line is dropped
/// whatever it holds (the paper-era MATLAB rule).
pub fn read_table(path: &Path, min_cols: usize, skip_first_line: bool) -> Result<Table> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut rows = Vec::new();
    let mut header = false;
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if k == 0 {
            header = line.starts_with('%');
            if skip_first_line || header {
                continue;
            }
        }
        if line.is_empty() {
            continue;
        }
        let vals: Result<Vec<f64>, _> = line.split_whitespace().map(str::parse).collect();
        let vals = vals.map_err(|e| {
            anyhow::anyhow!(
                "{}: line {}: not a number ({e}): {line:?}",
                path.display(),
                k + 1
            )
        })?;
        ensure!(
            vals.len() >= min_cols,
            "{}: line {}: {} columns, expected {min_cols}",
            path.display(),
            k + 1,
            vals.len()
        );
        rows.push(vals);
    }
    ensure!(!rows.is_empty(), "{}: no data rows", path.display());
    Ok(Table { rows, header })
}

/// The board's stereo shift in the MATLAB / protocol convention (the negated value of
/// `calibration_data.txt`).
pub fn stereo_shift(take: &Take) -> Result<i32> {
    let path = take.board_dir().join("calibration_data.txt");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let v: i32 = text
        .trim()
        .parse()
        .with_context(|| format!("{}: expected one integer", path.display()))?;
    ensure!(
        v.abs() <= 20,
        "{}: shift {v} px out of range",
        path.display()
    );
    Ok(-v)
}

/// Per-image times from `%i.bmp.tme` (line k = image k), if the file exists.
pub fn read_tme(take: &Take) -> Result<Option<Vec<f64>>> {
    let path = take.dir.join("%i.bmp.tme");
    if !path.is_file() {
        return Ok(None);
    }
    let t = read_table(&path, 1, false)?;
    Ok(Some(t.rows.iter().map(|r| r[0]).collect()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{GrayImage, ImageFormat, RgbImage};

    /// A data-set-like BMP as the recorder wrote it: 8 bit, gray palette, bottom-up rows.
    fn bmp(width: i32, height: i32, bpp: u16) -> Vec<u8> {
        let mut b = vec![0u8; 1078 + 256 * 96];
        b[0..2].copy_from_slice(b"BM");
        let len = b.len() as u32;
        b[2..6].copy_from_slice(&len.to_le_bytes());
        b[10..14].copy_from_slice(&1078u32.to_le_bytes());
        b[14..18].copy_from_slice(&40u32.to_le_bytes());
        b[18..22].copy_from_slice(&width.to_le_bytes());
        b[22..26].copy_from_slice(&height.to_le_bytes());
        b[26..28].copy_from_slice(&1u16.to_le_bytes());
        b[28..30].copy_from_slice(&bpp.to_le_bytes());
        b[46..50].copy_from_slice(&256u32.to_le_bytes());
        for i in 0..256 {
            b[54 + 4 * i..54 + 4 * i + 3].fill(i as u8);
        }
        // Bottom-up: the first stored row is the bottom row (95); mark it.
        for c in 0..256 {
            b[1078 + c] = if c < 128 { 10 } else { 20 };
        }
        b
    }

    fn encode(image: image::DynamicImage, format: ImageFormat) -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        image.write_to(&mut out, format).unwrap();
        out.into_inner()
    }

    /// A test pattern with every pixel distinct enough to catch a swap or a flip.
    fn pattern(x: u32, y: u32) -> u8 {
        (x * 3 + y * 7) as u8
    }

    fn check_pattern(f: &[u8; STEREO_FRAME_BYTES]) {
        for row in 0..96u32 {
            for c in 0..128u32 {
                let i = 2 * (row * 128 + c) as usize;
                assert_eq!(f[i], pattern(128 + c, row), "left camera at ({c}, {row})");
                assert_eq!(f[i + 1], pattern(c, row), "right camera at ({c}, {row})");
            }
        }
    }

    #[test]
    fn bmp_is_flipped_and_halves_swapped() {
        let f = decode_frame(&bmp(256, 96, 8)).unwrap();
        let bottom = 95 * 128 * 2;
        assert_eq!((f[bottom], f[bottom + 1]), (20, 10));
        assert_eq!((f[0], f[1]), (0, 0));
    }

    #[test]
    fn gray_png_and_bmp_give_the_same_frame() {
        let gray = GrayImage::from_fn(256, 96, |x, y| image::Luma([pattern(x, y)]));
        for format in [ImageFormat::Png, ImageFormat::Bmp] {
            let bytes = encode(gray.clone().into(), format);
            check_pattern(&decode_frame(&bytes).unwrap());
        }
    }

    #[test]
    fn colour_png_reads_as_luma_and_gray_rgb_as_its_value() {
        let gray_rgb = RgbImage::from_fn(256, 96, |x, y| image::Rgb([pattern(x, y); 3]));
        check_pattern(&decode_frame(&encode(gray_rgb.into(), ImageFormat::Png)).unwrap());
        let red = RgbImage::from_pixel(256, 96, image::Rgb([255, 0, 0]));
        let f = decode_frame(&encode(red.into(), ImageFormat::Png)).unwrap();
        // Rec. 709 luma of pure red: 0.2126 * 255.
        assert!(f.iter().all(|&v| (53..=55).contains(&v)), "{}", f[0]);
    }

    #[test]
    fn png_takes_are_found_and_loaded() {
        let dir = std::env::temp_dir().join(format!("edgefs-png-take-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let gray = GrayImage::from_fn(256, 96, |x, y| image::Luma([pattern(x, y)]));
        for i in 1..=3 {
            gray.save(dir.join(format!("{i}.png"))).unwrap();
        }
        let take = Take {
            board: 1,
            take: 1,
            dir: dir.clone(),
        };
        assert_eq!(take.image_count(), 3);
        check_pattern(&load_frame(&take.image_path(2)).unwrap());
        let e = format!("{:#}", load_frame(&dir.join("4.png")).unwrap_err());
        assert!(e.contains("4.png") && e.contains("cannot read"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn bad_images_are_rejected_with_the_reason() {
        let e = format!("{:#}", decode_frame(&bmp(128, 96, 8)).unwrap_err());
        assert!(e.contains("128x96"), "{e}");
        let e = format!("{:#}", decode_frame(&bmp(256, 96, 24)).unwrap_err());
        assert!(e.contains("truncated"), "24-bit header on 8-bit data: {e}");
        let e = format!("{:#}", decode_frame(b"GIF89a......").unwrap_err());
        assert!(e.contains("neither a BMP nor a PNG"), "{e}");
        let mut short = bmp(256, 96, 8);
        short.truncate(3000);
        let e = format!("{:#}", decode_frame(&short).unwrap_err());
        assert!(e.contains("truncated"), "{e}");
        let small = GrayImage::new(128, 96);
        let e = format!(
            "{:#}",
            decode_frame(&encode(small.into(), ImageFormat::Png)).unwrap_err()
        );
        assert!(e.contains("128x96") && e.contains("PNG"), "{e}");
        let mut png = encode(GrayImage::new(256, 96).into(), ImageFormat::Png);
        png.truncate(png.len() / 2);
        assert!(decode_frame(&png).is_err());
    }
}
