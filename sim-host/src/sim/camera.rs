//! Stereo camera: two pinholes 6 cm apart, 128 x 96, with the camera board's calibrated focal
//! length (the one Edge-FS converts with), rendered by per-pixel ray casting from the drone's
//! true pose (exact under roll and pitch), supersampled, integrated over the exposure time
//! (motion blur), blurred (optics), lit by the scene's `light` through an auto-exposure
//! (exposure time, then gain), with shot and read noise, gain mismatch and 8-bit quantisation,
//! delivered interleaved exactly as the real camera does: `[L0 R0 L1 R1 ...]`, row-major, top
//! row first.
//!
//! Camera axes follow the body: the optical axis is body x, image u (columns) grows to body y
//! (right), image v (rows) grows to body z (down).

use super::imu::gauss;
use super::math::{Quat, V3};
use super::scene::Scene;
use protocol::STEREO_FRAME_BYTES;
use rand_chacha::ChaCha8Rng;

/// Image width, px.
pub const WIDTH: usize = 128;
/// Image height, px.
pub const HEIGHT: usize = 96;

// The calibrated camera's effects, measured by `sim-host camera-calib` on board 1's eleven
// forward takes (docs/replay.md, "Camera effects").

/// Column fixed-pattern offset of the calibrated camera (left, right), DN: the part of the
/// high-passed mean column profile common to different takes (left 1.70 DN, correlation 0.35
/// between takes; right 0.30 DN).
pub const CALIBRATED_COLUMN_FPN_DN: [f32; 2] = [1.70, 0.30];
/// Row fixed-pattern offset of the calibrated camera, DN (common part of the row profiles:
/// 0.53 left, 0.49 right).
pub const CALIBRATED_ROW_FPN_DN: f32 = 0.5;
/// Pixel fixed-pattern offset of the calibrated camera, DN (common part of the per-pixel
/// means' 3x3 high-pass: 0.74).
pub const CALIBRATED_PIXEL_FPN_DN: f32 = 0.74;
/// Vignetting of the calibrated camera, per px²: the mean column level over all takes falls
/// as `1 + k x²` from the centre (left -5.9e-5, right -6.0e-5; board 2 -7.3e-5 to -8.0e-5):
/// 0.76 at the side edges.
pub const CALIBRATED_VIGNETTING_K: f32 = -6.0e-5;
/// Rolling-shutter readout of the calibrated camera, s: the bottom half's column edges shift
/// against the top half's by 2.97 +- 1.19 px per rad/s of yaw (46 +- 19 ms top to bottom).
pub const CALIBRATED_ROLLING_SHUTTER_S: f32 = 0.046;
/// The right camera's roll against the left of the calibrated camera, rad (0.5 degrees): the
/// angle at which the renderings of board 1's takes show the recorded frames' left-right
/// shear (`replay`'s bottom-minus-top-half left-right shift; recorded minus rendered, median
/// over the 11 takes: -0.22 px without the roll, -0.02 to +0.08 px with it over seeds 1-4).
pub const CALIBRATED_STEREO_ROLL_RAD: f32 = -0.009;

/// Camera parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraParams {
    /// Focal length, px (default: the camera board's calibrated
    /// [`stereo_board::edge_fs::CAMERA_FOCAL_PX`], so renderer and Edge-FS agree).
    pub focal_length_px: f32,
    /// Stereo baseline, m (left camera at -b/2, right at +b/2 along body y).
    pub baseline_m: f32,
    /// Camera position ahead of the centre of mass along body x, m.
    pub forward_offset_m: f32,
    /// Frame rate, Hz.
    pub fps: f64,
    /// Supersampling per pixel along each axis (1: one ray per pixel).
    pub supersample: usize,
    /// Apply the 3x3 binomial optical blur.
    pub blur: bool,
    /// Sensor response: digital numbers per unit albedo per second of exposure at the
    /// default lighting (`light = 1`) and unity gain.
    pub dn_per_albedo_s: f32,
    /// Auto-exposure target: mean image level, DN.
    pub target_dn: f32,
    /// Longest exposure, s (auto-exposure raises the gain beyond it).
    pub max_exposure_s: f32,
    /// Highest analogue gain.
    pub max_gain: f32,
    /// Largest change of exposure x gain from one frame to the next (the auto-exposure's
    /// step), factor.
    pub ae_step: f32,
    /// Electrons per DN at unity gain (full well / 255); shot noise follows from it.
    pub electrons_per_dn: f32,
    /// Read noise, electrons RMS (amplified by the gain).
    pub read_noise_e: f32,
    /// Add shot and read noise (off: noiseless images, for geometry tests).
    pub noise: bool,
    /// Integrate the image over the exposure time (motion blur) from the body's velocity and
    /// rates.
    pub motion_blur: bool,
    /// Right camera gain relative to the left.
    pub gain_right: f32,
    /// Right camera offset, DN.
    pub offset_right_dn: f32,
    /// Horizontal stereo misalignment, px: at infinity a feature sits this much further left
    /// in the left image than in the right one (the `stereo_shift` of `protocol::EdgeFsConfig`).
    pub misalign_px: f32,
    /// Vertical misalignment of the right image, px (rows, positive: feature lower in right).
    pub misalign_v_px: f32,
    /// The right camera's roll about its optical axis relative to the left camera, rad:
    /// positive puts a feature further right in the right image's bottom rows than in its top
    /// rows (by the angle times the rows between them, px), so a column's disparity differs
    /// from the top of the image to the bottom.
    pub stereo_roll_rad: f32,
    /// Column fixed-pattern offset of the left and the right camera: standard deviation of a
    /// per-column offset that does not move with the scene, DN (each camera its own pattern,
    /// drawn from [`pattern_seed`](Self::pattern_seed)).
    pub column_fpn_dn: [f32; 2],
    /// Row fixed-pattern offset: standard deviation of a per-row offset, DN.
    pub row_fpn_dn: f32,
    /// Pixel fixed-pattern offset (dark-signal non-uniformity, dust): standard deviation of a
    /// per-pixel offset, DN.
    pub pixel_fpn_dn: f32,
    /// Vignetting: the response falls as `1 + k r²` with `r` the distance from the image
    /// centre, px (`k` per px², negative: darker towards the edges).
    pub vignetting_k: f32,
    /// Rolling shutter: time from the exposure of the top row to that of the bottom row, s
    /// (0: global shutter). Rows below the middle are exposed later.
    pub rolling_shutter_s: f32,
    /// Seed of the sensor's fixed patterns (a given camera pair: fixed, not the flight's seed).
    pub pattern_seed: u64,
}

impl Default for CameraParams {
    /// The calibrated camera: [`CameraParams::ideal`] with the effects measured on the
    /// recorded stereo-board frames (`sim-host camera-calib`, docs/replay.md).
    fn default() -> Self {
        Self {
            column_fpn_dn: CALIBRATED_COLUMN_FPN_DN,
            row_fpn_dn: CALIBRATED_ROW_FPN_DN,
            pixel_fpn_dn: CALIBRATED_PIXEL_FPN_DN,
            vignetting_k: CALIBRATED_VIGNETTING_K,
            rolling_shutter_s: CALIBRATED_ROLLING_SHUTTER_S,
            stereo_roll_rad: CALIBRATED_STEREO_ROLL_RAD,
            ..Self::ideal()
        }
    }
}

impl CameraParams {
    /// The ideal camera, without the sensor's fixed patterns, vignetting or rolling shutter: a
    /// small CMOS camera pair (TCM8230 class): at the default lighting the auto-exposure
    /// settles at 8 ms and unity gain on a mid-grey room (120 DN), where shot noise is about
    /// 2.3 DN; dimmer rooms get up to 20 ms of exposure (more motion blur), then up to 8x gain
    /// (more noise).
    pub fn ideal() -> Self {
        Self {
            focal_length_px: stereo_board::edge_fs::CAMERA_FOCAL_PX,
            baseline_m: 0.06,
            forward_offset_m: 0.02,
            fps: 25.0,
            supersample: 2,
            blur: true,
            dn_per_albedo_s: 30_000.0,
            target_dn: 120.0,
            max_exposure_s: 0.020,
            max_gain: 8.0,
            ae_step: 1.25,
            electrons_per_dn: 23.5,
            read_noise_e: 8.0,
            noise: true,
            motion_blur: true,
            gain_right: 1.05,
            offset_right_dn: -3.0,
            misalign_px: 0.0,
            misalign_v_px: 0.0,
            stereo_roll_rad: 0.0,
            column_fpn_dn: [0.0; 2],
            row_fpn_dn: 0.0,
            pixel_fpn_dn: 0.0,
            vignetting_k: 0.0,
            rolling_shutter_s: 0.0,
            pattern_seed: 0x5e45_0a1b,
        }
    }

    /// Focal length, px.
    pub fn focal_px(&self) -> f32 {
        self.focal_length_px
    }

    /// Horizontal field of view of the pinhole, rad.
    pub fn hfov_rad(&self) -> f32 {
        2.0 * (WIDTH as f32 * 0.5 / self.focal_length_px).atan()
    }
}

/// Which camera model renders (`--camera` of `fly` and `replay`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum CameraModel {
    /// The camera calibrated to the recorded frames ([`CameraParams::default`]).
    Calibrated,
    /// The ideal camera, for comparison ([`CameraParams::ideal`]).
    Ideal,
}

impl CameraModel {
    /// The model's parameters.
    pub fn params(self) -> CameraParams {
        match self {
            CameraModel::Calibrated => CameraParams::default(),
            CameraModel::Ideal => CameraParams::ideal(),
        }
    }
}

/// The camera's motion during an exposure: world velocity (m/s) and body rates (rad/s) of the
/// body at the exposure's middle.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Motion {
    /// Velocity, world frame, m/s.
    pub vel: V3,
    /// Body rates, rad/s.
    pub rates: V3,
}

/// Exposure state of the camera (what the auto-exposure settled on).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exposure {
    /// Exposure time, s.
    pub time_s: f32,
    /// Analogue gain.
    pub gain: f32,
}

/// The pose at one time slot of an exposure: each eye's world-from-camera rotation (the right
/// one rolled by [`CameraParams::stereo_roll_rad`]) and each eye's origin.
type SlotPose = ([[[f32; 3]; 3]; 2], [[f32; 3]; 2]);

/// Most time samples per pixel over one exposure (motion blur).
const MAX_TIME_SAMPLES: usize = 16;

/// Precomputed stereo renderer with its auto-exposure state.
#[derive(Debug, Clone)]
pub struct StereoCamera {
    /// Parameters.
    pub params: CameraParams,
    /// Body-frame ray directions of every subsample, left then right, row-major per image.
    #[cfg(test)]
    rays: [Vec<[f32; 3]>; 2],
    /// The same rays `(1, u, v)` by time slot within a pass, for a row starting at phase 0
    /// (see [`PhaseRays`]), per eye.
    phase_rays: [Vec<PhaseRays>; 2],
    /// Per eye, the rays' `v` by image row and subsample row (`row * supersample + sub_row`).
    row_v: [Vec<f32>; 2],
    /// One row's traced albedos, per slot of a pass.
    samples: Vec<f32>,
    /// Trace with [`accumulate_reference`].
    #[cfg(test)]
    reference_tracer: bool,
    /// Per-pixel response factor of each camera (vignetting).
    gain_map: [Vec<f32>; 2],
    /// Per-pixel fixed offset of each camera (column, row and pixel patterns), DN.
    offset_map: [Vec<f32>; 2],
    acc: Vec<f32>,
    tmp: Vec<f32>,
    /// Exposure x gain, s (`None` until the first frame: then it starts settled).
    ae_product: Option<f32>,
    last: Exposure,
}

impl StereoCamera {
    /// Builds the renderer (precomputes every ray).
    pub fn new(params: CameraParams) -> Self {
        let f = params.focal_px();
        let ss = params.supersample.max(1);
        let (cx, cy) = (WIDTH as f32 * 0.5, HEIGHT as f32 * 0.5);
        let mut rays = [Vec::new(), Vec::new()];
        for (eye, r) in rays.iter_mut().enumerate() {
            let (du, dv) = if eye == 1 {
                (params.misalign_px, params.misalign_v_px)
            } else {
                (0.0, 0.0)
            };
            for v in 0..HEIGHT {
                for u in 0..WIDTH {
                    for sv in 0..ss {
                        for su in 0..ss {
                            // Pixel u covers [u, u+1); its centre is u + 0.5.
                            let pu = u as f32 + (su as f32 + 0.5) / ss as f32 - du;
                            let pv = v as f32 + (sv as f32 + 0.5) / ss as f32 - dv;
                            r.push([1.0, (pu - cx) / f, (pv - cy) / f]);
                        }
                    }
                }
            }
        }
        let n_sub = ss * ss;
        // A ray is `(1, u, v)`: `u` depends on the column and the subsample's column only, `v`
        // on the row and the subsample's row (the same expressions as the rays above).
        let du = [0.0, params.misalign_px];
        let dv = [0.0, params.misalign_v_px];
        let dir = |pixel: usize, sub: usize, misalign: f32, centre: f32| {
            let p = pixel as f32 + (sub as f32 + 0.5) / ss as f32 - misalign;
            (p - centre) / f
        };
        let phases = |eye: usize| -> Vec<PhaseRays> {
            (0..n_sub)
                .map(|q| {
                    // Pixel x of a row whose first pixel has phase 0 is traced at slot q with
                    // its subsample k = (q - x) mod n_sub.
                    let ks = (0..WIDTH).map(|x| (q + n_sub - x % n_sub) % n_sub);
                    PhaseRays {
                        u: ks
                            .clone()
                            .enumerate()
                            .map(|(x, k)| dir(x, k % ss, du[eye], cx))
                            .collect(),
                        sub_row: ks.map(|k| (k / ss) as u8).collect(),
                    }
                })
                .collect()
        };
        let row_v = |eye: usize| -> Vec<f32> {
            (0..HEIGHT * ss)
                .map(|i| dir(i / ss, i % ss, dv[eye], cy))
                .collect()
        };
        let phase_rays = [phases(0), phases(1)];
        let row_v = [row_v(0), row_v(1)];
        let (gain_map, offset_map) = sensor_maps(&params);
        Self {
            params,
            #[cfg(test)]
            rays,
            phase_rays,
            row_v,
            samples: vec![0.0; n_sub * WIDTH],
            #[cfg(test)]
            reference_tracer: false,
            gain_map,
            offset_map,
            acc: vec![0.0; WIDTH * HEIGHT],
            tmp: vec![0.0; WIDTH * HEIGHT],
            ae_product: None,
            last: Exposure {
                time_s: 0.0,
                gain: 1.0,
            },
        }
    }

    /// The exposure of the last frame rendered.
    pub fn exposure(&self) -> Exposure {
        self.last
    }

    /// Renders one interleaved stereo frame seen from the body pose (`pos`, `att`), still.
    pub fn render(
        &mut self,
        scene: &Scene,
        pos: V3,
        att: Quat,
        rng: &mut ChaCha8Rng,
        out: &mut [u8; STEREO_FRAME_BYTES],
    ) {
        self.render_moving(scene, pos, att, Motion::default(), rng, out);
    }

    /// Renders one interleaved stereo frame exposed around the body pose (`pos`, `att`) while
    /// the body moves with `motion`: the image integrates the scene over the exposure time
    /// (motion blur), its brightness is the scene's `light` through the exposure and gain the
    /// auto-exposure chose from the previous frame, with shot and read noise.
    pub fn render_moving(
        &mut self,
        scene: &Scene,
        pos: V3,
        att: Quat,
        motion: Motion,
        rng: &mut ChaCha8Rng,
        out: &mut [u8; STEREO_FRAME_BYTES],
    ) {
        let p = &self.params;
        let response = p.dn_per_albedo_s * scene.light.max(0.0);
        // Auto-exposure: settled on a mid-grey scene at the first frame, then it follows the
        // previous frame's mean level.
        let product = *self
            .ae_product
            .get_or_insert_with(|| p.target_dn / (0.5 * response).max(1e-9));
        let exposure_s = product.min(p.max_exposure_s);
        let gain = (product / exposure_s.max(1e-9)).clamp(1.0, p.max_gain);
        self.last = Exposure {
            time_s: exposure_s,
            gain,
        };

        // Time samples over the exposure: enough that the image moves at most about a pixel
        // between them (the view turns by the rates; nearby walls at 0.5 m slide by v / 0.5).
        let f = p.focal_px();
        let rate = (motion.rates.y.powi(2) + motion.rates.z.powi(2)).sqrt() as f32;
        let speed = motion.vel.norm() as f32;
        let smear_px = if p.motion_blur {
            f * exposure_s * (rate + speed / 0.5)
        } else {
            0.0
        };
        let ss = p.supersample.max(1);
        let n_sub = ss * ss;
        let slots = (smear_px.ceil() as usize).clamp(1, MAX_TIME_SAMPLES);
        let passes = slots.div_ceil(n_sub);
        let n_slots = passes * n_sub;
        // Rolling shutter: each row has its own exposure time (only when moving).
        let moving = motion != Motion::default();
        let pose_rows = if p.rolling_shutter_s > 0.0 && moving {
            HEIGHT
        } else {
            1
        };
        // The right camera's roll about its optical axis, as (sin, cos).
        let roll = (p.stereo_roll_rad != 0.0).then(|| f64::from(p.stereo_roll_rad).sin_cos());
        // Pose (rotation matrix, per-eye origin) at each row and time slot.
        let mut poses: Vec<SlotPose> = Vec::with_capacity(pose_rows * n_slots);
        for k in 0..pose_rows * n_slots {
            let (row, slot) = (k / n_slots, k % n_slots);
            let row_tau = if pose_rows > 1 {
                ((row as f64 + 0.5) / HEIGHT as f64 - 0.5) * p.rolling_shutter_s as f64
            } else {
                0.0
            };
            let tau = row_tau
                + if slots > 1 {
                    ((slot as f64 + 0.5) / n_slots as f64 - 0.5) * exposure_s as f64
                } else {
                    0.0
                };
            let a = att
                .add_scaled(att.derivative(motion.rates), tau)
                .normalized();
            let c = pos + motion.vel * tau;
            let m = a.to_matrix();
            let to_f32 = |m: [[f64; 3]; 3]| m.map(|row| row.map(|x| x as f32));
            // The right camera turned about its optical axis (the ray's first axis).
            let right = match roll {
                None => m,
                Some((s, c)) => {
                    m.map(|row| [row[0], row[1] * c + row[2] * s, row[2] * c - row[1] * s])
                }
            };
            let r = [to_f32(m), to_f32(right)];
            let mut o = [[0.0f32; 3]; 2];
            for (eye, oe) in o.iter_mut().enumerate() {
                let side = if eye == 0 { -0.5 } else { 0.5 } * p.baseline_m as f64;
                let w = c + a.rotate(V3::new(p.forward_offset_m as f64, side, 0.0));
                *oe = [w.x as f32, w.y as f32, w.z as f32];
            }
            poses.push((r, o));
        }
        let mut level_sum = 0.0f64;
        for eye in 0..2 {
            let slots = Slots {
                poses: &poses,
                passes,
                n_sub,
                pose_rows,
            };
            #[cfg(test)]
            if self.reference_tracer {
                accumulate_reference(&self.rays[eye], &mut self.acc, scene, eye, &slots);
            } else {
                let rays = (&self.phase_rays[eye][..], &self.row_v[eye][..]);
                accumulate(rays, &mut self.samples, &mut self.acc, scene, eye, &slots);
            }
            #[cfg(not(test))]
            {
                let rays = (&self.phase_rays[eye][..], &self.row_v[eye][..]);
                accumulate(rays, &mut self.samples, &mut self.acc, scene, eye, &slots);
            }
            if p.blur {
                blur3(&mut self.acc, &mut self.tmp);
            }
            let (g, offset) = if eye == 0 {
                (gain, 0.0)
            } else {
                (gain * p.gain_right, p.offset_right_dn)
            };
            let dn_per_albedo = response * exposure_s * g;
            // Shot noise: variance of the signal in electrons, back in DN; read noise in DN.
            let e_per_dn = p.electrons_per_dn / g;
            let read_dn = p.read_noise_e / e_per_dn;
            let (gain_map, offset_map) = (&self.gain_map[eye], &self.offset_map[eye]);
            let mut eye_sum = 0u32;
            for (px, a) in self.acc.iter().enumerate() {
                let signal = a * dn_per_albedo * gain_map[px];
                let n = if p.noise {
                    let sigma = (signal.max(0.0) / e_per_dn + read_dn * read_dn).sqrt();
                    gauss(rng) as f32 * sigma
                } else {
                    0.0
                };
                let v = round_to_dn(signal + offset + offset_map[px] + n);
                out[2 * px + eye] = v;
                eye_sum += u32::from(v);
            }
            if eye == 0 {
                level_sum = f64::from(eye_sum);
            }
        }
        // The auto-exposure steers the product towards the target level, a bounded step at a
        // time (a saturated or black frame still moves it by one step).
        let mean = (level_sum / (WIDTH * HEIGHT) as f64) as f32;
        let want = product * p.target_dn / mean.max(1.0);
        let step = p.ae_step.max(1.0);
        let max_product = p.max_exposure_s * p.max_gain;
        self.ae_product = Some(want.clamp(product / step, product * step).min(max_product));
    }
}

/// One time slot's rays along an image row whose first pixel has phase 0 (pixel `px` has
/// phase `px % n_sub`; a row of phase `r` uses slot `j`'s rays from entry `(j - r) mod n_sub`).
#[derive(Debug, Clone)]
struct PhaseRays {
    /// The ray's `u` per column.
    u: Vec<f32>,
    /// The ray's subsample row per column.
    sub_row: Vec<u8>,
}

/// The pose slots of one frame: [`SlotPose`]s by pose row (one, or one per image row under
/// the rolling shutter) and time slot (`passes` passes of `n_sub` slots).
struct Slots<'a> {
    poses: &'a [SlotPose],
    passes: usize,
    n_sub: usize,
    pose_rows: usize,
}

/// Traces one eye's rays at every pose slot and stores each pixel's mean albedo in `acc`.
///
/// Row by row and slot by slot: all of a row's rays at one slot share the pose, so their
/// directions and the room's planes are computed as a batch. Each pixel's samples are then
/// summed in the order of its subsamples, as [`accumulate_reference`] does: the result is the
/// same bit for bit.
fn accumulate(
    (phase_rays, row_v): (&[PhaseRays], &[f32]),
    samples: &mut [f32],
    acc: &mut [f32],
    scene: &Scene,
    eye: usize,
    slots: &Slots,
) {
    let &Slots {
        poses,
        passes,
        n_sub,
        pose_rows,
    } = slots;
    let n_slots = passes * n_sub;
    let inv = 1.0 / n_slots as f32;
    let ss = row_v.len() / HEIGHT;
    let (mut dx, mut dy, mut dz) = ([0.0f32; WIDTH], [0.0f32; WIDTH], [0.0f32; WIDTH]);
    for y in 0..HEIGHT {
        let pose_row = if pose_rows > 1 { y } else { 0 };
        let mut sums = [0.0f32; WIDTH];
        for pass in 0..passes {
            for j in 0..n_sub {
                let (rs, o) = &poses[pose_row * n_slots + pass * n_sub + j];
                let r = &rs[eye];
                let phase = &phase_rays[(j + n_sub - y * WIDTH % n_sub) % n_sub];
                let vs = &row_v[y * ss..(y + 1) * ss];
                for (x, (&u, &sub_row)) in phase.u.iter().zip(&phase.sub_row).enumerate() {
                    let v = vs[usize::from(sub_row)];
                    // The ray is (1, u, v): `r[i][0] * 1` is `r[i][0]` exactly.
                    dx[x] = r[0][0] + r[0][1] * u + r[0][2] * v;
                    dy[x] = r[1][0] + r[1][1] * u + r[1][2] * v;
                    dz[x] = r[2][0] + r[2][1] * u + r[2][2] * v;
                }
                let out = &mut samples[j * WIDTH..(j + 1) * WIDTH];
                scene.trace_batch(o[eye], &dx, &dy, &dz, out);
            }
            // Slot `j` holds pixel `px`'s subsample `k` where `(k + px) % n_sub == j`.
            for (x, sum) in sums.iter_mut().enumerate() {
                let phase = (y * WIDTH + x) % n_sub;
                for k in 0..n_sub {
                    let j = if k + phase >= n_sub {
                        k + phase - n_sub
                    } else {
                        k + phase
                    };
                    *sum += samples[j * WIDTH + x];
                }
            }
        }
        for (a, sum) in acc[y * WIDTH..(y + 1) * WIDTH].iter_mut().zip(sums) {
            *a = sum * inv;
        }
    }
}

/// The plain per-pixel, per-ray loop [`accumulate`] must equal.
#[cfg(test)]
fn accumulate_reference(
    rays: &[[f32; 3]],
    acc: &mut [f32],
    scene: &Scene,
    eye: usize,
    slots: &Slots,
) {
    let &Slots {
        poses,
        passes,
        n_sub,
        pose_rows,
    } = slots;
    let n_slots = passes * n_sub;
    let inv = 1.0 / n_slots as f32;
    for (px, acc) in acc.iter_mut().enumerate() {
        let mut sum = 0.0;
        for pass in 0..passes {
            for (k, b) in rays[px * n_sub..(px + 1) * n_sub].iter().enumerate() {
                // Decorrelate subsample position and time from pixel to pixel.
                let slot = pass * n_sub + (k + px) % n_sub;
                let row = if pose_rows > 1 { px / WIDTH } else { 0 };
                let (rs, o) = &poses[row * n_slots + slot];
                let r = &rs[eye];
                let d = [
                    r[0][0] * b[0] + r[0][1] * b[1] + r[0][2] * b[2],
                    r[1][0] * b[0] + r[1][1] * b[1] + r[1][2] * b[2],
                    r[2][0] * b[0] + r[2][1] * b[1] + r[2][2] * b[2],
                ];
                sum += scene.trace(o[eye], d).0;
            }
        }
        *acc = sum * inv;
    }
}

/// `x` rounded to the nearest whole DN (halves away from zero) and clamped to 0..=255, as
/// `x.round().clamp(0.0, 255.0) as u8` but without `roundf` (a library call on x86-64 without
/// SSE4.1): after the clamp `x` is not negative, and its fraction `x - trunc(x)` is exact.
#[inline]
fn round_to_dn(x: f32) -> u8 {
    let c = x.clamp(0.0, 255.0);
    let whole = c as u32; // NaN to 0, as `as u8` of a NaN
    (whole + u32::from(c - whole as f32 >= 0.5)) as u8
}

/// The sensor's per-pixel response factors (vignetting) and fixed offsets (column, row and
/// pixel patterns), per camera, drawn once from the parameters' pattern seed.
fn sensor_maps(p: &CameraParams) -> ([Vec<f32>; 2], [Vec<f32>; 2]) {
    use rand::SeedableRng;
    let mut rng = ChaCha8Rng::seed_from_u64(p.pattern_seed);
    let (cx, cy) = (WIDTH as f32 * 0.5 - 0.5, HEIGHT as f32 * 0.5 - 0.5);
    let gain: Vec<f32> = (0..WIDTH * HEIGHT)
        .map(|px| {
            let (x, y) = ((px % WIDTH) as f32 - cx, (px / WIDTH) as f32 - cy);
            (1.0 + p.vignetting_k * (x * x + y * y)).max(0.0)
        })
        .collect();
    let mut offsets = [vec![0.0; WIDTH * HEIGHT], vec![0.0; WIDTH * HEIGHT]];
    for (map, column_fpn_dn) in offsets.iter_mut().zip(p.column_fpn_dn) {
        let cols: Vec<f32> = (0..WIDTH)
            .map(|_| gauss(&mut rng) as f32 * column_fpn_dn)
            .collect();
        let rows: Vec<f32> = (0..HEIGHT)
            .map(|_| gauss(&mut rng) as f32 * p.row_fpn_dn)
            .collect();
        for (px, o) in map.iter_mut().enumerate() {
            *o = cols[px % WIDTH] + rows[px / WIDTH] + gauss(&mut rng) as f32 * p.pixel_fpn_dn;
        }
    }
    ([gain.clone(), gain], offsets)
}

/// 3x3 binomial blur ([1 2 1]/4 separable), edges clamped. `tmp` is scratch.
fn blur3(img: &mut [f32], tmp: &mut [f32]) {
    for y in 0..HEIGHT {
        let row = &img[y * WIDTH..(y + 1) * WIDTH];
        for x in 0..WIDTH {
            let l = row[x.saturating_sub(1)];
            let r = row[(x + 1).min(WIDTH - 1)];
            tmp[y * WIDTH + x] = 0.25 * l + 0.5 * row[x] + 0.25 * r;
        }
    }
    for y in 0..HEIGHT {
        let up = y.saturating_sub(1);
        let dn = (y + 1).min(HEIGHT - 1);
        for x in 0..WIDTH {
            img[y * WIDTH + x] =
                0.25 * tmp[up * WIDTH + x] + 0.5 * tmp[y * WIDTH + x] + 0.25 * tmp[dn * WIDTH + x];
        }
    }
}

/// Splits an interleaved frame into the left and right images (row-major).
pub fn deinterleave(frame: &[u8; STEREO_FRAME_BYTES]) -> (Vec<u8>, Vec<u8>) {
    let l = frame.iter().step_by(2).copied().collect();
    let r = frame.iter().skip(1).step_by(2).copied().collect();
    (l, r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Column-wise horizontal edge histogram (sum over rows of |I(x+1) - I(x-1)|), as Edge-FS
    /// builds it.
    fn edge_hist(img: &[u8]) -> Vec<f32> {
        let mut h = vec![0.0; WIDTH];
        for y in 0..HEIGHT {
            for x in 1..WIDTH - 1 {
                h[x] += (img[y * WIDTH + x + 1] as f32 - img[y * WIDTH + x - 1] as f32).abs();
            }
        }
        h
    }

    /// Best integer shift d (0..=max) matching left column x to right column x - d, with
    /// parabolic sub-pixel refinement, over the whole histogram.
    fn global_disparity(l: &[f32], r: &[f32], max: usize) -> f32 {
        let cost = |d: usize| -> f32 { (20..WIDTH - 20).map(|x| (l[x] - r[x - d]).abs()).sum() };
        let costs: Vec<f32> = (0..=max).map(cost).collect();
        let (best, _) = costs
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.partial_cmp(b.1).unwrap())
            .unwrap();
        if best == 0 || best == max {
            return best as f32;
        }
        let (a, b, c) = (costs[best - 1], costs[best], costs[best + 1]);
        best as f32 + 0.5 * (a - c) / (a - 2.0 * b + c)
    }

    /// The batched tracer renders the same frames as the plain per-ray loop, bit for bit
    /// (noise off): still and moving (motion blur up to the most time slots, rolling shutter),
    /// ideal and calibrated, in rooms with and without obstacles, at several supersamplings.
    #[test]
    fn batched_tracer_equals_the_per_ray_reference() {
        let cases = [
            ("room", 2, Motion::default()),
            ("office", 2, Motion::default()),
            (
                "room-obstacles",
                2,
                Motion {
                    vel: V3::new(1.2, -0.4, 0.1),
                    rates: V3::new(0.5, -1.0, 4.0),
                },
            ),
            (
                "office",
                3,
                Motion {
                    vel: V3::new(0.3, 0.8, 0.0),
                    rates: V3::new(0.0, 0.2, 9.0),
                },
            ),
            ("corridor", 1, Motion::default()),
        ];
        for (name, supersample, motion) in cases {
            let scene = Scene::preset(name, 4).unwrap();
            let pos = V3::new(
                scene.start_xy[0] as f64 + 0.3,
                scene.start_xy[1] as f64 - 0.2,
                -1.1,
            );
            let att = Quat::from_euler(0.1, -0.15, 0.7);
            for params in [CameraParams::default(), CameraParams::ideal()] {
                let params = CameraParams {
                    noise: false,
                    supersample,
                    misalign_px: 0.7,
                    misalign_v_px: -0.3,
                    ..params
                };
                let mut frames = Vec::new();
                for reference in [false, true] {
                    let mut cam = StereoCamera::new(params.clone());
                    cam.reference_tracer = reference;
                    let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
                    let mut rng = ChaCha8Rng::seed_from_u64(2);
                    cam.render_moving(&scene, pos, att, motion, &mut rng, &mut frame);
                    frames.push(frame);
                }
                let differing = frames[0]
                    .iter()
                    .zip(frames[1].iter())
                    .filter(|(a, b)| a != b)
                    .count();
                assert_eq!(differing, 0, "{name}, supersample {supersample}");
                // Not a blank frame: the comparison means something.
                let (l, _) = deinterleave(&frames[0]);
                assert!(edge_hist(&l).iter().sum::<f32>() > 1000.0, "{name}");
            }
        }
    }

    /// The rounding without `roundf` equals `round` then clamp, on halves, their neighbours,
    /// the range's ends, infinities and NaN.
    #[test]
    fn round_to_dn_equals_round_then_clamp() {
        let mut xs = vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, 0.0];
        for k in -3..=258 {
            let half = k as f32 + 0.5;
            for x in [k as f32, half, half.next_down(), half.next_up()] {
                xs.extend([x, x.next_down(), x.next_up()]);
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        xs.extend((0..100_000).map(|_| rand::Rng::random_range(&mut rng, -10.0f32..270.0)));
        for x in xs {
            assert_eq!(round_to_dn(x), x.round().clamp(0.0, 255.0) as u8, "{x}");
        }
    }

    #[test]
    fn facing_a_wall_disparity_matches_f_b_over_z() {
        let scene = Scene::preset("room", 3).unwrap();
        let mut cam = StereoCamera::new(CameraParams {
            noise: false,
            ..CameraParams::default()
        });
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
        for z in [1.0f32, 1.5, 2.0] {
            // Camera (2 cm ahead of the body) at distance z from the north wall.
            let x = 4.0 - z - cam.params.forward_offset_m;
            cam.render(
                &scene,
                V3::new(x as f64, 2.0, -1.0),
                Quat::IDENTITY,
                &mut rng,
                &mut frame,
            );
            let (l, r) = deinterleave(&frame);
            let d = global_disparity(&edge_hist(&l), &edge_hist(&r), 12);
            let expect = cam.params.focal_px() * cam.params.baseline_m / z;
            assert!(
                (d - expect).abs() < 0.35,
                "z {z}: disparity {d} vs f*b/Z {expect}"
            );
        }
    }

    /// The right camera's roll turns the right image about its centre against the left: facing
    /// a wall, the disparity of the bottom half differs from the top half's by the angle times
    /// the 48 rows between the halves' centres (the sign as documented on the parameter).
    #[test]
    fn stereo_roll_turns_the_right_image() {
        let scene = Scene::preset("room", 3).unwrap();
        let shear = |roll: f32| {
            let mut cam = StereoCamera::new(CameraParams {
                noise: false,
                stereo_roll_rad: roll,
                ..CameraParams::ideal()
            });
            let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
            let mut rng = ChaCha8Rng::seed_from_u64(0);
            let x = 4.0 - 1.5 - f64::from(cam.params.forward_offset_m);
            cam.render(
                &scene,
                V3::new(x, 2.0, -1.0),
                Quat::IDENTITY,
                &mut rng,
                &mut frame,
            );
            let (l, r) = deinterleave(&frame);
            let half = |img: &[u8], top: bool| {
                let rows = if top {
                    0..HEIGHT / 2
                } else {
                    HEIGHT / 2..HEIGHT
                };
                edge_hist(&img[rows.start * WIDTH..rows.end * WIDTH].repeat(2))
            };
            global_disparity(&half(&l, false), &half(&r, false), 12)
                - global_disparity(&half(&l, true), &half(&r, true), 12)
        };
        assert!(shear(0.0).abs() < 0.08, "no roll: {}", shear(0.0));
        for roll in [0.01f32, -0.01] {
            let want = -roll * (HEIGHT / 2) as f32;
            let got = shear(roll);
            assert!(
                (got - want).abs() < 0.2,
                "roll {roll}: {got} px, want {want}"
            );
        }
    }

    fn left_stats(frame: &[u8; STEREO_FRAME_BYTES]) -> (f32, f32) {
        let (l, _) = deinterleave(frame);
        let mean = l.iter().map(|&v| v as f32).sum::<f32>() / l.len() as f32;
        let var = l.iter().map(|&v| (v as f32 - mean).powi(2)).sum::<f32>() / l.len() as f32;
        (mean, var.sqrt())
    }

    /// Dim light: the auto-exposure lengthens the exposure, then raises the gain; the image
    /// keeps its level while there is gain left, and its noise grows.
    #[test]
    fn dim_light_means_longer_exposure_more_gain_and_noise() {
        let spec = crate::sim::scene_spec::SceneSpec::preset("plain-room").unwrap();
        let p = V3::new(2.0, 2.0, -1.0);
        let noise_at = |light: f32| {
            let scene = Scene::build(
                &crate::sim::scene_spec::SceneSpec {
                    light,
                    ..spec.clone()
                },
                1,
            )
            .unwrap();
            let mut cam = StereoCamera::new(CameraParams::default());
            let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
            let mut rng = ChaCha8Rng::seed_from_u64(9);
            for _ in 0..20 {
                cam.render(&scene, p, Quat::IDENTITY, &mut rng, &mut frame);
            }
            // Pixel noise: two frames of the same still view differ only by noise.
            let (l1, _) = deinterleave(&frame);
            cam.render(&scene, p, Quat::IDENTITY, &mut rng, &mut frame);
            let (l2, _) = deinterleave(&frame);
            let d2 = l1
                .iter()
                .zip(&l2)
                .map(|(&a, &b)| (a as f32 - b as f32).powi(2))
                .sum::<f32>()
                / l1.len() as f32;
            (cam.exposure(), left_stats(&frame).0, (d2 / 2.0).sqrt())
        };
        let (e1, m1, n1) = noise_at(1.0);
        let (e2, m2, n2) = noise_at(0.1);
        let (e3, m3, _) = noise_at(0.01);
        assert!((e1.time_s - 0.008).abs() < 0.003 && e1.gain < 1.2, "{e1:?}");
        assert!(e2.time_s == 0.020 && e2.gain > 3.0, "{e2:?}");
        assert!(e3.gain == 8.0, "{e3:?}");
        assert!(
            (m1 - 120.0).abs() < 20.0 && (m2 - 120.0).abs() < 20.0,
            "{m1} {m2}"
        );
        assert!(m3 < 40.0, "out of gain: a dark image ({m3})");
        assert!((1.5..3.5).contains(&n1), "noise at light 1: {n1} DN");
        assert!(n2 > 1.6 * n1, "noise at light 0.1: {n2} vs {n1} DN");
    }

    /// A fast turn smears vertical edges: the edge energy falls with the exposure's motion.
    #[test]
    fn motion_blur_smears_edges_in_a_turn() {
        let scene = Scene::preset("room", 3).unwrap();
        let p = V3::new(2.0, 2.0, -1.0);
        let energy = |yaw_rate: f64| {
            let mut cam = StereoCamera::new(CameraParams {
                noise: false,
                ..CameraParams::default()
            });
            let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
            let motion = Motion {
                vel: V3::new(0.0, 0.0, 0.0),
                rates: V3::new(0.0, 0.0, yaw_rate),
            };
            let mut rng = ChaCha8Rng::seed_from_u64(1);
            cam.render_moving(&scene, p, Quat::IDENTITY, motion, &mut rng, &mut frame);
            let (l, _) = deinterleave(&frame);
            edge_hist(&l).iter().sum::<f32>()
        };
        let still = energy(0.0);
        let turning = energy(3.0); // 3 rad/s x 8 ms x 128 px = 3 px of smear
        let fast = energy(6.0);
        assert!(turning < 0.9 * still, "{turning} vs still {still}");
        assert!(fast < turning, "{fast} at 6 rad/s vs {turning} at 3 rad/s");
    }

    #[test]
    fn roll_is_exact_horizon_tilts() {
        // Under a 90 deg roll the image of the floor/ceiling boundary rotates: the left image
        // columns become what rows were. Check a simple invariant: rendering is deterministic
        // and the mean brightness of the bottom rows (floor) differs under roll.
        let scene = Scene::preset("room", 3).unwrap();
        let cam = || StereoCamera::new(CameraParams::default());
        let mut f1 = Box::new([0u8; STEREO_FRAME_BYTES]);
        let mut f2 = Box::new([0u8; STEREO_FRAME_BYTES]);
        let p = V3::new(2.0, 2.0, -1.0);
        cam().render(
            &scene,
            p,
            Quat::IDENTITY,
            &mut ChaCha8Rng::seed_from_u64(5),
            &mut f1,
        );
        cam().render(
            &scene,
            p,
            Quat::IDENTITY,
            &mut ChaCha8Rng::seed_from_u64(5),
            &mut f2,
        );
        assert_eq!(f1[..], f2[..]);
        cam().render(
            &scene,
            p,
            Quat::from_euler(0.3, 0.0, 0.0),
            &mut ChaCha8Rng::seed_from_u64(5),
            &mut f2,
        );
        assert_ne!(f1[..], f2[..]);
    }

    /// A plain wall seen still and noiseless by `params`: the left image, twice (two frames).
    fn plain_wall(params: CameraParams) -> (Vec<u8>, Vec<u8>) {
        let scene = Scene::build(
            &crate::sim::scene_spec::SceneSpec::preset("plain-room").unwrap(),
            1,
        )
        .unwrap();
        let mut cam = StereoCamera::new(CameraParams {
            noise: false,
            ..params
        });
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
        let p = V3::new(2.0, 2.0, -1.0);
        let mut shots = Vec::new();
        // The last two of 20 frames: the auto-exposure has settled.
        for k in 0..20 {
            cam.render(&scene, p, Quat::IDENTITY, &mut rng, &mut frame);
            if k >= 18 {
                shots.push(deinterleave(&frame).0);
            }
        }
        (shots.remove(0), shots.remove(0))
    }

    /// Row `y`'s mean over columns `x0..x1`.
    fn block_mean(img: &[u8], rows: std::ops::Range<usize>, cols: std::ops::Range<usize>) -> f32 {
        let n = (rows.len() * cols.len()) as f32;
        rows.flat_map(|y| cols.clone().map(move |x| (y, x)))
            .map(|(y, x)| img[y * WIDTH + x] as f32)
            .sum::<f32>()
            / n
    }

    /// The calibrated camera's column pattern stays where it is from frame to frame and has
    /// the calibrated size; the ideal camera has none.
    #[test]
    fn column_pattern_is_fixed_and_of_the_calibrated_size() {
        let hp = |img: &[u8]| -> Vec<f32> {
            let cols: Vec<f32> = (0..WIDTH)
                .map(|x| block_mean(img, 30..66, x..x + 1))
                .collect();
            (2..WIDTH - 2)
                .map(|x| cols[x] - (cols[x - 1] + cols[x + 1]) * 0.5)
                .collect()
        };
        // A white pattern's [-1/2 1 -1/2] high-pass has variance 1.5 sigma².
        let rms_of = |v: &[f32]| (v.iter().map(|v| v * v).sum::<f32>() / v.len() as f32).sqrt();
        let hp_rms = |img: &[u8]| rms_of(&hp(img)) / 1.5f32.sqrt();
        let (a, b) = plain_wall(CameraParams {
            row_fpn_dn: 0.0,
            pixel_fpn_dn: 0.0,
            vignetting_k: 0.0,
            ..CameraParams::default()
        });
        // Two frames of a still view: the pattern stays (up to the rounding to whole DN).
        let moved: Vec<f32> = hp(&a).iter().zip(hp(&b)).map(|(x, y)| x - y).collect();
        assert!(
            rms_of(&moved) < 0.25 * rms_of(&hp(&a)),
            "the pattern moved: {} of {}",
            rms_of(&moved),
            rms_of(&hp(&a))
        );
        let rms = hp_rms(&a);
        let want = CALIBRATED_COLUMN_FPN_DN[0];
        assert!(
            (rms - want).abs() < 0.45 * want,
            "column pattern {rms} DN vs {want}"
        );
        let (ideal, _) = plain_wall(CameraParams::ideal());
        assert!(hp_rms(&ideal) < 0.3, "ideal: {}", hp_rms(&ideal));
    }

    /// Vignetting darkens the sides against the centre by the calibrated factor.
    #[test]
    fn vignetting_darkens_the_sides() {
        let (img, _) = plain_wall(CameraParams {
            column_fpn_dn: [0.0; 2],
            row_fpn_dn: 0.0,
            pixel_fpn_dn: 0.0,
            ..CameraParams::default()
        });
        let centre = block_mean(&img, 40..56, 60..68);
        let side = block_mean(&img, 40..56, 0..4);
        let want = 1.0 + CALIBRATED_VIGNETTING_K * 62.0 * 62.0;
        assert!(
            (side / centre - want).abs() < 0.05,
            "side/centre {} vs {want}",
            side / centre
        );
    }

    /// Under yaw the rolling shutter shifts the bottom rows against the top rows by
    /// `f x rate x readout / 2` between the halves' centres.
    #[test]
    fn rolling_shutter_skews_vertical_edges_in_a_turn() {
        let scene = Scene::preset("room", 3).unwrap();
        let p = V3::new(2.0, 2.0, -1.0);
        let skew = |params: CameraParams| {
            let mut cam = StereoCamera::new(CameraParams {
                noise: false,
                motion_blur: false,
                ..params
            });
            let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
            let motion = Motion {
                vel: V3::new(0.0, 0.0, 0.0),
                rates: V3::new(0.0, 0.0, 1.0),
            };
            let mut rng = ChaCha8Rng::seed_from_u64(1);
            cam.render_moving(&scene, p, Quat::IDENTITY, motion, &mut rng, &mut frame);
            let (l, _) = deinterleave(&frame);
            let half = |rows: std::ops::Range<usize>| {
                let mut h = vec![0.0; WIDTH];
                for y in rows {
                    for x in 1..WIDTH - 1 {
                        h[x] += (l[y * WIDTH + x + 1] as f32 - l[y * WIDTH + x - 1] as f32).abs();
                    }
                }
                h
            };
            let (top, bottom) = (half(0..48), half(48..96));
            // Best shift of bottom against top, sub-pixel.
            let cost = |d: i32| -> f32 {
                (12..WIDTH as i32 - 12)
                    .map(|x| (top[x as usize] - bottom[(x + d) as usize]).abs())
                    .sum()
            };
            let c: Vec<f32> = (-8..=8).map(cost).collect();
            let (i, _) = c
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(b.1))
                .unwrap();
            let i = i.clamp(1, c.len() - 2);
            let (a, b, cc) = (c[i - 1], c[i], c[i + 1]);
            i as f32 - 8.0 + 0.5 * (a - cc) / (a - 2.0 * b + cc)
        };
        let params = CameraParams {
            rolling_shutter_s: 0.046,
            ..CameraParams::ideal()
        };
        let want = params.focal_px() * 1.0 * 0.046 * 0.5;
        let got = skew(params).abs();
        assert!((got - want).abs() < 0.4 * want, "skew {got} px vs {want}");
        let global = skew(CameraParams::ideal()).abs();
        assert!(global < 0.3, "global shutter: skew {global} px");
    }
}
