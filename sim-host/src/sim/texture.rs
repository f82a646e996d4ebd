//! Surface textures: grey-level albedo maps on a regular grid, generated from a seed for each
//! [`TextureKind`] (or read from a picture), at a given mean albedo and contrast.
//!
//! Every generator produces a pattern around its kind's default albedo; the surface's albedo
//! shifts it and its contrast scales the deviations: `albedo + contrast * (p - default)`,
//! clamped to 0.01..=1.

use super::picture::GreyImage;
use super::scene_spec::{default_albedo, Surface, TextureKind};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// A grey-level texture on a regular grid (nearest-neighbour lookup, clamped).
#[derive(Debug, Clone)]
pub struct Texture {
    nx: usize,
    ny: usize,
    /// Cells per metre along s and h.
    res: [f32; 2],
    data: Vec<f32>,
}

/// Height of the skirting board and the ceiling trim, m.
const TRIM_M: f32 = 0.1;
/// Albedo of the trims.
const TRIM_ALBEDO: f32 = 0.35;

impl Texture {
    /// Mean albedo 0..1 over the surface (what a viewer paints it with).
    pub fn mean_albedo(&self) -> f32 {
        if self.data.is_empty() {
            return 0.0;
        }
        self.data.iter().sum::<f32>() / self.data.len() as f32
    }

    /// Albedo 0..1 at surface coordinates `s` (along) and `h` (up, or the second floor axis), m.
    #[inline]
    pub fn sample(&self, s: f32, h: f32) -> f32 {
        // Clamped to the grid as a float (NaN and below 0 to the first cell, past the end to
        // the last), then truncated: the same cell as truncating first and clamping the
        // integer, without the saturating 64-bit conversions (the renderer's inner loop).
        let i = (s * self.res[0]).max(0.0).min((self.nx - 1) as f32) as u32 as usize;
        let j = (h * self.res[1]).max(0.0).min((self.ny - 1) as f32) as u32 as usize;
        self.data[j * self.nx + i]
    }

    fn grid(length: f32, height: f32, res: [f32; 2]) -> (usize, usize) {
        (
            (length * res[0]).ceil() as usize + 1,
            (height * res[1]).ceil() as usize + 1,
        )
    }

    /// A vertical surface `length` x `height` m (a wall or an obstacle's side).
    pub fn vertical(
        surface: &Surface,
        length: f32,
        height: f32,
        rng: &mut ChaCha8Rng,
    ) -> Result<Self, String> {
        let mut t = match surface.texture {
            TextureKind::Image => return Self::image(surface, length, height),
            TextureKind::Stripes => Self::stripes(length, height, rng, false),
            TextureKind::Posters => Self::stripes(length, height, rng, true),
            TextureKind::Bricks => Self::bricks(length, height, rng),
            TextureKind::Wood => Self::wood(length, height, rng),
            // Plain (and anything else the validation let through): one grey.
            _ => Self::flat(length, height, default_albedo(TextureKind::Plain)),
        };
        t.paint(surface);
        // The room's light falls off a little towards the floor: a mild vertical shading.
        for j in 0..t.ny {
            let h = j as f32 / t.res[1];
            let shade = 0.9 + 0.1 * (h / height.max(0.1));
            let trim = surface.trim && (h < TRIM_M || h > height - TRIM_M);
            for v in &mut t.data[j * t.nx..(j + 1) * t.nx] {
                *v = if trim { TRIM_ALBEDO } else { *v * shade };
            }
        }
        Ok(t)
    }

    /// The floor, `size_x` x `size_y` m (s along x, h along y).
    pub fn floor(
        surface: &Surface,
        size_x: f32,
        size_y: f32,
        rng: &mut ChaCha8Rng,
    ) -> Result<Self, String> {
        let mut t = match surface.texture {
            TextureKind::Image => return Self::image(surface, size_x, size_y),
            TextureKind::Tiles => Self::tiles(size_x, size_y, rng),
            TextureKind::Carpet => Self::carpet(size_x, size_y, rng),
            _ => Self::flat(size_x, size_y, default_albedo(TextureKind::Plain)),
        };
        t.paint(surface);
        Ok(t)
    }

    /// The ceiling, `size_x` x `size_y` m.
    pub fn ceiling(surface: &Surface, size_x: f32, size_y: f32) -> Result<Self, String> {
        let mut t = match surface.texture {
            TextureKind::Image => return Self::image(surface, size_x, size_y),
            TextureKind::Lamps => {
                let res = [10.0f32, 10.0];
                let (nx, ny) = Self::grid(size_x, size_y, res);
                let data = (0..nx * ny)
                    .map(|k| if (k % nx) % 10 < 2 { 0.55 } else { 0.8 })
                    .collect();
                Self { nx, ny, res, data }
            }
            _ => Self::flat(size_x, size_y, default_albedo(TextureKind::Plain)),
        };
        t.paint(surface);
        Ok(t)
    }

    /// Moves the pattern's mean from its kind's default to the surface's albedo and scales
    /// its deviations by the contrast.
    fn paint(&mut self, surface: &Surface) {
        let base = default_albedo(surface.texture);
        for v in &mut self.data {
            *v = (surface.albedo + surface.contrast * (*v - base)).clamp(0.01, 1.0);
        }
    }

    fn flat(length: f32, height: f32, v: f32) -> Self {
        let res = [10.0f32, 10.0];
        let (nx, ny) = Self::grid(length, height, res);
        Self {
            nx,
            ny,
            res,
            data: vec![v; nx * ny],
        }
    }

    /// A picture stretched over the surface: its albedo and contrast act around the
    /// picture's own mean (absent albedo: the picture's mean).
    fn image(surface: &Surface, length: f32, height: f32) -> Result<Self, String> {
        let path = surface
            .image
            .as_ref()
            .ok_or_else(|| "texture = \"image\" needs a picture".to_string())?;
        let img = GreyImage::load(path)?;
        let mean = img.mean();
        let albedo = if surface.albedo.is_finite() {
            surface.albedo
        } else {
            mean
        };
        // Image rows run downwards; `h` runs upwards from the floor (or along y).
        let mut data = vec![0.0; img.width * img.height];
        for j in 0..img.height {
            let src = &img.data[(img.height - 1 - j) * img.width..][..img.width];
            for (d, s) in data[j * img.width..][..img.width].iter_mut().zip(src) {
                *d = (albedo + surface.contrast * (s - mean)).clamp(0.01, 1.0);
            }
        }
        Ok(Self {
            nx: img.width,
            ny: img.height,
            res: [
                img.width as f32 / length.max(1e-3),
                img.height as f32 / height.max(1e-3),
            ],
            data,
        })
    }

    /// Vertical stripes of random width (2-27 cm) and grey; with `posters`, rectangles with
    /// their own finer stripes.
    fn stripes(length: f32, height: f32, rng: &mut ChaCha8Rng, posters: bool) -> Self {
        let res = [100.0f32, 25.0];
        let (nx, ny) = Self::grid(length, height, res);
        let mut col = vec![0.0f32; nx];
        let mut i = 0;
        while i < nx {
            let w = 2 + (rng.random::<f32>().powi(2) * 25.0) as usize;
            let v = 0.15 + 0.75 * rng.random::<f32>();
            for c in col.iter_mut().skip(i).take(w) {
                *c = v;
            }
            i += w;
        }
        let mut data = Vec::with_capacity(nx * ny);
        for _ in 0..ny {
            data.extend_from_slice(&col);
        }
        if posters {
            let n_posters = (length / 1.2) as usize + 1;
            for _ in 0..n_posters {
                let w = 0.3 + 0.6 * rng.random::<f32>();
                let hgt = 0.4 + 0.6 * rng.random::<f32>();
                let s0 = rng.random::<f32>() * (length - w).max(0.0);
                let h0 = 0.3 + rng.random::<f32>() * (height - hgt - 0.6).max(0.0);
                let period = 3 + rng.random_range(0..8usize);
                let (lo, hi) = (
                    0.1 + 0.2 * rng.random::<f32>(),
                    0.7 + 0.25 * rng.random::<f32>(),
                );
                let i0 = (s0 * res[0]) as usize;
                let i1 = (((s0 + w) * res[0]) as usize).min(nx);
                let j0 = (h0 * res[1]) as usize;
                let j1 = (((h0 + hgt) * res[1]) as usize).min(ny);
                for j in j0..j1 {
                    for i in i0..i1 {
                        data[j * nx + i] = if ((i - i0) / period).is_multiple_of(2) {
                            lo
                        } else {
                            hi
                        };
                    }
                }
            }
        }
        Self { nx, ny, res, data }
    }

    /// Brickwork: 24 x 7 cm bricks (grey 0.40-0.60) in courses offset by half a brick, 1 cm
    /// mortar (0.62).
    fn bricks(length: f32, height: f32, rng: &mut ChaCha8Rng) -> Self {
        let res = [100.0f32, 100.0];
        let (nx, ny) = Self::grid(length, height, res);
        let (bw, bh) = (25usize, 8usize); // brick + joint, cm
        let cols = nx / bw + 2;
        let rows = ny / bh + 1;
        let greys: Vec<f32> = (0..cols * rows)
            .map(|_| 0.40 + 0.20 * rng.random::<f32>())
            .collect();
        let mut data = vec![0.0; nx * ny];
        for j in 0..ny {
            let course = j / bh;
            let shift = if course % 2 == 1 { bw / 2 } else { 0 };
            for i in 0..nx {
                let u = i + shift;
                let joint = j % bh == 0 || u % bw == 0;
                data[j * nx + i] = if joint {
                    0.62
                } else {
                    greys[course * cols + u / bw]
                };
            }
        }
        Self { nx, ny, res, data }
    }

    /// Vertical planks 9-20 cm wide (grey 0.35-0.55), 5 mm dark seams, a faint grain along
    /// the planks.
    fn wood(length: f32, height: f32, rng: &mut ChaCha8Rng) -> Self {
        let res = [200.0f32, 20.0];
        let (nx, ny) = Self::grid(length, height, res);
        let mut col = vec![0.0f32; nx];
        let mut i = 0;
        while i < nx {
            let w = 18 + rng.random_range(0..23usize);
            let v = 0.35 + 0.20 * rng.random::<f32>();
            let mut grain = 0.0f32;
            for (k, c) in col.iter_mut().skip(i).take(w).enumerate() {
                grain = 0.8 * grain + 0.2 * (rng.random::<f32>() - 0.5) * 0.15;
                *c = if k == 0 { 0.2 } else { v + grain };
            }
            i += w;
        }
        let mut data = Vec::with_capacity(nx * ny);
        for _ in 0..ny {
            data.extend_from_slice(&col);
        }
        Self { nx, ny, res, data }
    }

    /// 30 cm tiles of random grey (0.3-0.7) with fine grain.
    fn tiles(size_x: f32, size_y: f32, rng: &mut ChaCha8Rng) -> Self {
        let res = [50.0f32, 50.0];
        let (nx, ny) = Self::grid(size_x, size_y, res);
        let tiles_x = nx / 15 + 1;
        let tiles: Vec<f32> = (0..tiles_x * (ny / 15 + 1))
            .map(|_| 0.3 + 0.4 * rng.random::<f32>())
            .collect();
        let mut data = vec![0.0; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                data[j * nx + i] =
                    tiles[(j / 15) * tiles_x + i / 15] + 0.08 * (rng.random::<f32>() - 0.5);
            }
        }
        Self { nx, ny, res, data }
    }

    /// Carpet: 1 cm grain (+-0.05) over a faint mottling at 20 cm (+-0.04), no edges.
    fn carpet(size_x: f32, size_y: f32, rng: &mut ChaCha8Rng) -> Self {
        let res = [100.0f32, 100.0];
        let (nx, ny) = Self::grid(size_x, size_y, res);
        let mx = nx / 20 + 2;
        let mottle: Vec<f32> = (0..mx * (ny / 20 + 2))
            .map(|_| 0.08 * (rng.random::<f32>() - 0.5))
            .collect();
        let mut data = vec![0.0; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                // Bilinear mottling between 20 cm nodes.
                let (fi, fj) = (i as f32 / 20.0, j as f32 / 20.0);
                let (i0, j0) = (fi as usize, fj as usize);
                let (a, b) = (fi - i0 as f32, fj - j0 as f32);
                let m = |ii: usize, jj: usize| mottle[jj * mx + ii];
                let mot = (1.0 - a) * (1.0 - b) * m(i0, j0)
                    + a * (1.0 - b) * m(i0 + 1, j0)
                    + (1.0 - a) * b * m(i0, j0 + 1)
                    + a * b * m(i0 + 1, j0 + 1);
                data[j * nx + i] = 0.4 + mot + 0.1 * (rng.random::<f32>() - 0.5);
            }
        }
        Self { nx, ny, res, data }
    }

    /// Mean absolute difference between neighbouring cells along `s` at height `h` over
    /// `length` m, sampled every `step` m (a measure of vertical-edge contrast).
    pub fn edge_energy(&self, length: f32, h: f32, step: f32) -> f32 {
        let n = (length / step) as usize;
        let mut sum = 0.0;
        let mut prev = self.sample(0.0, h);
        for k in 1..n {
            let v = self.sample(k as f32 * step, h);
            sum += (v - prev).abs();
            prev = v;
        }
        sum / n.max(1) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn make(kind: TextureKind, contrast: f32) -> Texture {
        let s = Surface {
            contrast,
            ..Surface::of(kind)
        };
        Texture::vertical(&s, 4.0, 2.5, &mut ChaCha8Rng::seed_from_u64(3)).unwrap()
    }

    #[test]
    fn sample_picks_the_cell_of_truncating_then_clamping() {
        let t = make(TextureKind::Bricks, 1.0);
        let reference = |s: f32, h: f32| {
            let i = ((s * t.res[0]).max(0.0) as usize).min(t.nx - 1);
            let j = ((h * t.res[1]).max(0.0) as usize).min(t.ny - 1);
            t.data[j * t.nx + i]
        };
        let (len, height) = (t.nx as f32 / t.res[0], t.ny as f32 / t.res[1]);
        let specials = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -1e30,
            1e30,
            -0.0,
            0.0,
            f32::MIN_POSITIVE,
            len,
            height,
            (t.nx - 1) as f32 / t.res[0],
            (t.ny - 1) as f32 / t.res[1],
        ];
        let mut coords: Vec<f32> = specials.to_vec();
        // Every cell boundary and around it, beyond both ends.
        for k in -20..(t.nx.max(t.ny) as i32 + 20) {
            for off in [-1e-4f32, 0.0, 0.37, 0.999] {
                coords.push((k as f32 + off) / t.res[0]);
                coords.push((k as f32 + off) / t.res[1]);
            }
        }
        for &s in &coords {
            for &h in coords.iter().step_by(7).chain(&specials) {
                assert_eq!(
                    t.sample(s, h).to_bits(),
                    reference(s, h).to_bits(),
                    "({s}, {h})"
                );
            }
        }
    }

    #[test]
    fn textures_have_the_edges_their_kind_promises() {
        // 1.23 m: inside a course of bricks, not on a joint.
        let plain = make(TextureKind::Plain, 1.0).edge_energy(4.0, 1.23, 0.01);
        assert!(plain < 1e-6, "plain {plain}");
        for kind in [
            TextureKind::Stripes,
            TextureKind::Posters,
            TextureKind::Bricks,
            TextureKind::Wood,
        ] {
            let full = make(kind, 1.0).edge_energy(4.0, 1.23, 0.01);
            let low = make(kind, 0.2).edge_energy(4.0, 1.23, 0.01);
            assert!(full > 0.005, "{kind:?} {full}");
            assert!(
                (low / full - 0.2).abs() < 0.05,
                "{kind:?}: contrast 0.2 gives {low} vs {full}"
            );
        }
    }

    #[test]
    fn albedo_sets_the_mean() {
        // Stripes are few and wide, so their mean wanders more from seed to seed.
        for (kind, tol) in [
            (TextureKind::Plain, 0.01),
            (TextureKind::Bricks, 0.03),
            (TextureKind::Stripes, 0.12),
        ] {
            let s = Surface {
                albedo: 0.3,
                trim: false,
                ..Surface::of(kind)
            };
            let t = Texture::vertical(&s, 4.0, 2.5, &mut ChaCha8Rng::seed_from_u64(1)).unwrap();
            let mean = t.data.iter().sum::<f32>() / t.data.len() as f32;
            // The vertical shading takes 5 % off on average.
            assert!((mean - 0.3 * 0.95).abs() < tol, "{kind:?} mean {mean}");
        }
    }

    #[test]
    fn picture_textures_are_read_and_stretched() {
        let dir = std::env::temp_dir().join(format!("scene-img-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("half.png");
        // Left half black, right half white, 8 x 4 px.
        let img =
            image::GrayImage::from_fn(8, 4, |x, _| image::Luma([if x < 4 { 0 } else { 255 }]));
        img.save(&path).unwrap();
        let s = Surface {
            image: Some(path.clone()),
            albedo: f32::NAN,
            ..Surface::of(TextureKind::Image)
        };
        let t = Texture::vertical(&s, 2.0, 1.0, &mut ChaCha8Rng::seed_from_u64(0)).unwrap();
        assert!(t.sample(0.5, 0.5) < 0.05);
        assert!(t.sample(1.5, 0.5) > 0.95);
        std::fs::write(dir.join("bad.png"), b"not a picture").unwrap();
        let e = GreyImage::load(&dir.join("bad.png")).unwrap_err();
        assert!(e.contains("bad.png"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
