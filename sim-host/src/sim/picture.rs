//! Pictures read from files as grey levels (a scene's `image` textures).

use std::path::Path;

/// A grey picture, values 0..=1, row-major from the top row.
#[derive(Debug, Clone)]
pub struct GreyImage {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Grey levels, 0..=1.
    pub data: Vec<f32>,
}

impl GreyImage {
    /// Reads a picture (PNG or JPEG) and converts it to grey. The error names the file.
    pub fn load(path: &Path) -> Result<Self, String> {
        let img = image::open(path)
            .map_err(|e| format!("cannot read picture {}: {e}", path.display()))?
            .to_luma8();
        let (w, h) = (img.width() as usize, img.height() as usize);
        if w < 2 || h < 2 {
            return Err(format!(
                "picture {} is {w} x {h} px; it needs at least 2 x 2",
                path.display()
            ));
        }
        Ok(Self {
            width: w,
            height: h,
            data: img.into_raw().iter().map(|&v| v as f32 / 255.0).collect(),
        })
    }

    /// The mean grey level.
    pub fn mean(&self) -> f32 {
        self.data.iter().sum::<f32>() / self.data.len() as f32
    }
}
