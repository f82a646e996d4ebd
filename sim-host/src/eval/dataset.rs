//! The stereoboard_testing data set: take discovery and the file formats (BMP, timing.dat,
//! position.dat, `%i.bmp.tme`, calibration_data.txt).

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

    /// Number of images `1.bmp ..= N.bmp` (counted until the first gap).
    pub fn image_count(&self) -> usize {
        (1..).take_while(|i| self.image_path(*i).is_file()).count()
    }

    /// Path of image `i` (1-based).
    pub fn image_path(&self, i: usize) -> PathBuf {
        self.dir.join(format!("{i}.bmp"))
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

/// Reads a BMP of the data set (256x96, 8 bit, uncompressed, gray palette; left half = right
/// camera) into an interleaved stereo frame `[L0 R0 L1 R1 ...]`, top row first.
pub fn load_bmp(path: &Path) -> Result<Box<[u8; STEREO_FRAME_BYTES]>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    decode_bmp(&bytes).with_context(|| format!("bad image {}", path.display()))
}

fn u32_at(b: &[u8], at: usize) -> Result<u32> {
    let s = b
        .get(at..at + 4)
        .context("file too short for a BMP header")?;
    Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

fn u16_at(b: &[u8], at: usize) -> Result<u16> {
    let s = b
        .get(at..at + 2)
        .context("file too short for a BMP header")?;
    Ok(u16::from_le_bytes([s[0], s[1]]))
}

/// Decodes the BMP bytes (see [`load_bmp`]).
pub fn decode_bmp(b: &[u8]) -> Result<Box<[u8; STEREO_FRAME_BYTES]>> {
    ensure!(b.starts_with(b"BM"), "not a BMP file (no 'BM' signature)");
    let offset = u32_at(b, 10)? as usize;
    let header = u32_at(b, 14)? as usize;
    let width = u32_at(b, 18)? as i32;
    let height = u32_at(b, 22)? as i32;
    let bpp = u16_at(b, 28)?;
    let compression = u32_at(b, 30)?;
    ensure!(
        width == 256 && height.abs() == 96,
        "size {width}x{} (expected 256x96: two 128x96 cameras side by side)",
        height.abs()
    );
    ensure!(bpp == 8, "{bpp} bits per pixel (expected 8-bit gray)");
    ensure!(compression == 0, "compressed BMP (type {compression})");
    // Palette (B, G, R, 0) entries follow the header; map indices through it (identity in the
    // data set).
    let mut palette = [0u8; 256];
    for (i, p) in palette.iter_mut().enumerate() {
        *p = b.get(14 + header + 4 * i + 1).copied().unwrap_or(i as u8);
    }
    let stride = 256usize;
    ensure!(
        b.len() >= offset + stride * 96,
        "pixel data truncated ({} bytes, expected {})",
        b.len(),
        offset + stride * 96
    );
    let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
    for row in 0..96 {
        let src_row = if height > 0 { 95 - row } else { row };
        let src = &b[offset + src_row * stride..offset + (src_row + 1) * stride];
        for c in 0..128 {
            // Left camera = BMP right half; right camera = BMP left half.
            frame[2 * (row * 128 + c)] = palette[src[128 + c] as usize];
            frame[2 * (row * 128 + c) + 1] = palette[src[c] as usize];
        }
    }
    Ok(frame)
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

    fn bmp(width: i32, height: i32, bpp: u16) -> Vec<u8> {
        let mut b = vec![0u8; 1078 + 256 * 96];
        b[0..2].copy_from_slice(b"BM");
        b[10..14].copy_from_slice(&1078u32.to_le_bytes());
        b[14..18].copy_from_slice(&40u32.to_le_bytes());
        b[18..22].copy_from_slice(&width.to_le_bytes());
        b[22..26].copy_from_slice(&height.to_le_bytes());
        b[28..30].copy_from_slice(&bpp.to_le_bytes());
        for i in 0..256 {
            b[54 + 4 * i..54 + 4 * i + 3].fill(i as u8);
        }
        // Bottom-up: the first stored row is the bottom row (95); mark it.
        for c in 0..256 {
            b[1078 + c] = if c < 128 { 10 } else { 20 };
        }
        b
    }

    #[test]
    fn bmp_is_flipped_and_halves_swapped() {
        let f = decode_bmp(&bmp(256, 96, 8)).unwrap();
        let bottom = 95 * 128 * 2;
        assert_eq!((f[bottom], f[bottom + 1]), (20, 10));
        assert_eq!((f[0], f[1]), (0, 0));
    }

    #[test]
    fn bad_bmps_are_rejected_with_the_reason() {
        let e = decode_bmp(&bmp(128, 96, 8)).unwrap_err().to_string();
        assert!(e.contains("128x96"), "{e}");
        let e = decode_bmp(&bmp(256, 96, 24)).unwrap_err().to_string();
        assert!(e.contains("24 bits"), "{e}");
        assert!(decode_bmp(b"GIF89a").is_err());
        let mut short = bmp(256, 96, 8);
        short.truncate(3000);
        assert!(decode_bmp(&short)
            .unwrap_err()
            .to_string()
            .contains("truncated"));
    }
}
