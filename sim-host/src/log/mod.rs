//! Flight logs in MCAP (written with the `mcap` crate), readable by PlotJuggler, Foxglove and
//! Lichtblick.
//!
//! Two kinds of channel:
//!
//! * the typed records of [`records`] (estimates with their flags and quality, attitude and
//!   body rates, setpoints, motor duties, FSM state and flight mode by name, velocity, height,
//!   link and status counters, the simulated truth): JSON messages described by a JSON Schema
//!   generated from the record type, which every plotting tool reads by field name;
//! * Foxglove's well-known types in their protobuf encoding, with the schema's descriptor set:
//!   the camera's left and right images (`foxglove.CompressedImage`, grey PNG) and the 3D view of
//!   [`scene3d`] (`foxglove.SceneUpdate`, `foxglove.FrameTransform`), which Foxglove and
//!   Lichtblick display without any setup.
//!
//! Message times (`log_time`) are nanoseconds of the flight's clock: world time from 0 in the
//! simulator and HIL, wall time since the Unix epoch for a live board. Chunks are
//! zstd-compressed.
//!
//! A channel appears with its first message, so a log only lists what its source reports.

pub mod live;
pub mod records;
pub mod scene3d;
pub mod sim;
pub mod view3d;

use anyhow::{anyhow, Context as _};
use protocol::STEREO_FRAME_BYTES;
use records::Record;
use schemars::JsonSchema;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

/// Topic of the left camera's images.
pub const LEFT_IMAGE_TOPIC: &str = "/camera/left";
/// Topic of the right camera's images.
pub const RIGHT_IMAGE_TOPIC: &str = "/camera/right";
/// Width of one camera's image, px.
pub const IMAGE_WIDTH: u32 = 128;
/// Height of one camera's image, px.
pub const IMAGE_HEIGHT: u32 = 96;

/// An MCAP flight log being written.
pub struct FlightLog<W: Write + Seek = BufWriter<File>> {
    writer: mcap::Writer<W>,
    channels: HashMap<&'static str, u16>,
    counts: BTreeMap<&'static str, u64>,
    last_ns: u64,
    path: PathBuf,
    live: Option<live::LiveServer>,
}

/// What a finished log holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogSummary {
    /// Messages per topic.
    pub counts: BTreeMap<&'static str, u64>,
    /// Where it was written.
    pub path: PathBuf,
}

impl LogSummary {
    /// All messages.
    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }
}

impl FlightLog {
    /// Creates (or replaces) the log file at `path`.
    pub fn create(path: &Path) -> anyhow::Result<Self> {
        let file =
            File::create(path).with_context(|| format!("creating the log {}", path.display()))?;
        Self::new(BufWriter::new(file), path)
    }
}

impl<W: Write + Seek> FlightLog<W> {
    /// A log written to `w`; `path` names it in errors.
    pub fn new(w: W, path: &Path) -> anyhow::Result<Self> {
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .profile("")
            .library(concat!("pocket-drone sim-host ", env!("CARGO_PKG_VERSION")))
            .create(w)
            .map_err(|e| anyhow!("starting the log {}: {e}", path.display()))?;
        Ok(Self {
            writer,
            channels: HashMap::new(),
            counts: BTreeMap::new(),
            last_ns: 0,
            path: path.to_path_buf(),
            live: None,
        })
    }

    /// Serves every channel written from now on live as well (see [`live`]).
    pub fn serve_live(&mut self, server: live::LiveServer) {
        self.live = Some(server);
    }

    /// The channel of `topic`, created with its schema on first use.
    fn channel(
        &mut self,
        topic: &'static str,
        spec: &dyn Fn() -> ChannelSpec,
    ) -> anyhow::Result<u16> {
        if let Some(&id) = self.channels.get(topic) {
            return Ok(id);
        }
        let spec = spec();
        let path = &self.path;
        let schema_id = self
            .writer
            .add_schema(&spec.schema_name, &spec.schema_encoding, &spec.schema_data)
            .map_err(|e| {
                anyhow!(
                    "{}: adding schema {}: {e}",
                    path.display(),
                    spec.schema_name
                )
            })?;
        let id = self
            .writer
            .add_channel(schema_id, topic, &spec.message_encoding, &BTreeMap::new())
            .map_err(|e| anyhow!("{}: adding channel {topic}: {e}", path.display()))?;
        self.channels.insert(topic, id);
        if let Some(live) = self.live.as_mut() {
            let schema =
                foxglove::Schema::new(spec.schema_name, spec.schema_encoding, spec.schema_data);
            live.add_channel(topic, schema, &spec.message_encoding)?;
        }
        Ok(id)
    }

    fn put(
        &mut self,
        channel: u16,
        topic: &'static str,
        t_ns: u64,
        data: &[u8],
    ) -> anyhow::Result<()> {
        let count = self.counts.entry(topic).or_insert(0);
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: *count as u32,
            log_time: t_ns,
            publish_time: t_ns,
        };
        *count += 1;
        self.last_ns = self.last_ns.max(t_ns);
        if let Some(live) = &self.live {
            live.send(topic, data);
        }
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| anyhow!("writing {topic} to {}: {e}", self.path.display()))
    }

    /// Writes `record` on its channel at `t_ns`.
    pub fn write<R: Record>(&mut self, t_ns: u64, record: &R) -> anyhow::Result<()> {
        let id = self.channel(R::TOPIC, &|| ChannelSpec {
            schema_name: R::SCHEMA.to_string(),
            schema_encoding: "jsonschema".to_string(),
            schema_data: schema_of::<R>().into_bytes(),
            message_encoding: "json".to_string(),
        })?;
        let data = serde_json::to_vec(record).context("serialising a log record")?;
        self.put(id, R::TOPIC, t_ns, &data)
    }

    /// Writes a message of one of Foxglove's well-known types (protobuf) on `topic` at `t_ns`.
    pub fn write_foxglove<M: foxglove::Encode>(
        &mut self,
        topic: &'static str,
        t_ns: u64,
        message: &M,
    ) -> anyhow::Result<()> {
        let id = self.channel(topic, &|| {
            let schema = M::get_schema();
            ChannelSpec {
                schema_name: schema.as_ref().map_or(String::new(), |s| s.name.clone()),
                schema_encoding: schema
                    .as_ref()
                    .map_or(String::new(), |s| s.encoding.clone()),
                schema_data: schema.map_or(Vec::new(), |s| s.data.into_owned()),
                message_encoding: M::get_message_encoding(),
            }
        })?;
        let mut data = Vec::with_capacity(message.encoded_len().unwrap_or(64));
        message
            .encode(&mut data)
            .map_err(|e| anyhow!("encoding a {topic} message: {e}"))?;
        self.put(id, topic, t_ns, &data)
    }

    /// Writes an interleaved stereo frame (`[L0 R0 L1 R1 ...]`, 128x96 each) as two
    /// `foxglove.CompressedImage` messages, left and right camera, in the camera frames of
    /// [`scene3d`]: grey PNG, lossless (a third smaller than the raw pixels compressed).
    pub fn stereo_frame(
        &mut self,
        t_ns: u64,
        frame: &[u8; STEREO_FRAME_BYTES],
    ) -> anyhow::Result<()> {
        for (topic, eye, frame_id) in [
            (LEFT_IMAGE_TOPIC, 0, scene3d::LEFT_CAMERA_FRAME),
            (RIGHT_IMAGE_TOPIC, 1, scene3d::RIGHT_CAMERA_FRAME),
        ] {
            let pixels: Vec<u8> = frame.iter().skip(eye).step_by(2).copied().collect();
            let image = foxglove::schemas::CompressedImage {
                timestamp: Some(scene3d::timestamp(t_ns)),
                frame_id: frame_id.to_string(),
                data: png_grey(&pixels, IMAGE_WIDTH, IMAGE_HEIGHT)?.into(),
                format: "png".to_string(),
            };
            self.write_foxglove(topic, t_ns, &image)?;
        }
        Ok(())
    }

    /// Time of the latest message, ns.
    pub fn last_time_ns(&self) -> u64 {
        self.last_ns
    }

    /// Messages written so far, per topic.
    pub fn counts(&self) -> &BTreeMap<&'static str, u64> {
        &self.counts
    }

    /// Writes the summary and index records and closes the file.
    pub fn finish(mut self) -> anyhow::Result<LogSummary> {
        if let Some(mut live) = self.live.take() {
            live.stop();
        }
        let path = self.path.clone();
        self.writer
            .finish()
            .map_err(|e| anyhow!("finishing the log {}: {e}", path.display()))?;
        let mut w = self.writer.into_inner();
        w.flush()
            .with_context(|| format!("writing the log {}", path.display()))?;
        Ok(LogSummary {
            counts: self.counts,
            path,
        })
    }
}

/// A grey image as PNG (best compression, adaptive row filters).
fn png_grey(pixels: &[u8], width: u32, height: u32) -> anyhow::Result<Vec<u8>> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder as _;
    let mut png = Vec::with_capacity(pixels.len());
    PngEncoder::new_with_quality(&mut png, CompressionType::Best, FilterType::Adaptive)
        .write_image(pixels, width, height, image::ColorType::L8)
        .context("encoding a camera image as PNG")?;
    Ok(png)
}

/// How a channel's messages are encoded and described.
struct ChannelSpec {
    schema_name: String,
    schema_encoding: String,
    schema_data: Vec<u8>,
    message_encoding: String,
}

/// The JSON Schema of a record type.
fn schema_of<R: JsonSchema>() -> String {
    serde_json::to_string_pretty(&schemars::schema_for!(R)).unwrap_or_else(|_| "{}".into())
}

/// What a logger knows beyond a telemetry message: the simulator's truth, the IMU's rates.
#[derive(Debug, Clone, Copy, Default)]
pub struct TelemetryExtras {
    /// Body rates, rad/s.
    pub gyro_radps: Option<[f32; 3]>,
    /// True forward and sideways velocity, m/s.
    pub true_velocity_mps: Option<[f32; 2]>,
    /// True height, m.
    pub true_height_m: Option<f32>,
}

/// Writes an autopilot telemetry message as its records (state, attitude, setpoint, velocity,
/// height, barometer and battery when it has a reading) at `t_ns`, with what else the logger knows.
pub fn write_telemetry<W: Write + Seek>(
    log: &mut FlightLog<W>,
    t_ns: u64,
    tel: &protocol::Telemetry,
    extras: &TelemetryExtras,
) -> anyhow::Result<()> {
    use records::{
        AttitudeRecord, BaroRecord, HeightRecord, SetpointRecord, StateRecord, VelocityRecord,
    };
    log.write(t_ns, &StateRecord::new(tel.fsm_state, tel.flight_mode))?;
    let rate = |axis: usize| extras.gyro_radps.map(|g| g[axis]);
    log.write(
        t_ns,
        &AttitudeRecord {
            roll_rad: tel.attitude_rad[0],
            pitch_rad: tel.attitude_rad[1],
            yaw_rad: tel.attitude_rad[2],
            roll_rate_radps: rate(0),
            pitch_rate_radps: rate(1),
            yaw_rate_radps: rate(2),
        },
    )?;
    log.write(
        t_ns,
        &SetpointRecord {
            forward_mps: tel.velocity_setpoint_mps[0],
            sideways_mps: tel.velocity_setpoint_mps[1],
            roll_rad: None,
            pitch_rad: None,
            yaw_rad: None,
            height_m: None,
            thrust: None,
        },
    )?;
    log.write(
        t_ns,
        &VelocityRecord {
            forward_mps: Some(tel.velocity_mps[0]),
            sideways_mps: Some(tel.velocity_mps[1]),
            true_forward_mps: extras.true_velocity_mps.map(|v| v[0]),
            true_sideways_mps: extras.true_velocity_mps.map(|v| v[1]),
        },
    )?;
    log.write(
        t_ns,
        &HeightRecord {
            height_m: tel.height_m,
            setpoint_m: None,
            true_m: extras.true_height_m,
        },
    )?;
    if let Some(baro) = tel.baro {
        log.write(
            t_ns,
            &BaroRecord {
                pressure_pa: baro.pressure_pa,
                temperature_c: baro.temperature_c,
            },
        )?;
    }
    if let Some(battery) = &tel.battery {
        log.write(t_ns, &records::BatteryRecord::new(battery))?;
    }
    log.write(t_ns, &records::LinkAuthRecord::new(&tel.link_auth))?;
    Ok(())
}

/// Thins a stream of samples out to one per period: a sample is taken when at least 95 % of
/// the period has passed since the last one taken, so samples on a slightly irregular grid
/// (IMU ticks of 1953.125 µs rounded to whole µs, frames on that grid) are not skipped for
/// being a few microseconds early.
#[derive(Debug, Clone, Copy)]
pub struct Thinner {
    period_us: u64,
    last_us: Option<u64>,
}

impl Thinner {
    /// About `hz` samples per second (none for a rate that is not positive).
    pub fn new(hz: f64) -> Self {
        let period_us = if hz > 0.0 && hz.is_finite() {
            (1e6 / hz).round().max(1.0) as u64
        } else {
            u64::MAX
        };
        Self {
            period_us,
            last_us: None,
        }
    }

    /// Whether the sample at `t_us` is taken.
    pub fn take(&mut self, t_us: u64) -> bool {
        if self.period_us == u64::MAX {
            return false;
        }
        let due = self
            .last_us
            .is_none_or(|last| t_us.saturating_sub(last) >= self.period_us - self.period_us / 20);
        if due {
            self.last_us = Some(t_us);
        }
        due
    }
}

/// Nanoseconds of `t_us` microseconds.
pub fn ns(t_us: u64) -> u64 {
    t_us.saturating_mul(1_000)
}

#[cfg(test)]
mod tests {
    use super::records::*;
    use super::*;
    use protocol::{Estimate, EstimateFlags};

    #[test]
    fn records_and_images_round_trip_through_the_crate_reader() {
        let mut buf = std::io::Cursor::new(Vec::new());
        let mut log = FlightLog::new(&mut buf, Path::new("mem.mcap")).unwrap();
        let e = Estimate {
            seq: 3,
            capture_us: protocol::WireTime(40_000),
            forward_mps: 0.25,
            sideways_mps: -0.5,
            obstacle_m: None,
            quality: 99,
            flags: EstimateFlags::NO_TEXTURE | EstimateFlags::NO_GYRO,
            processing_us: 9_000,
            depth_coverage: 255,
            near_columns: 0,
            fit: None,
            up_mps: 0.0,
            up_flags: EstimateFlags::NO_FLOW_MATCH,
            fit_r2: 0,
            divergence: None,
        };
        log.write(1_000, &EstimateRecord::from(&e)).unwrap();
        log.write(
            2_000,
            &StateRecord::new(Some(protocol::FsmState::Turn), protocol::FlightMode::Flying),
        )
        .unwrap();
        let mut frame = Box::new([0u8; STEREO_FRAME_BYTES]);
        for (i, p) in frame.iter_mut().enumerate() {
            *p = if i % 2 == 0 { 10 } else { 200 };
        }
        log.stereo_frame(3_000, &frame).unwrap();
        let summary = log.finish().unwrap();
        assert_eq!(summary.total(), 4);

        let bytes = buf.into_inner();
        let mut topics = Vec::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap_or_default();
            topics.push((m.channel.topic.clone(), m.log_time));
            match m.channel.topic.as_str() {
                "/estimate" => {
                    assert_eq!(
                        v["flag_names"],
                        serde_json::json!(["no_texture", "no_gyro"])
                    );
                    assert_eq!(v["valid"], false);
                    assert_eq!(v["obstacle_m"], serde_json::Value::Null);
                    let schema = m.channel.schema.as_ref().unwrap();
                    assert_eq!(schema.encoding, "jsonschema");
                    let s = String::from_utf8(schema.data.to_vec()).unwrap();
                    assert!(s.contains("Confidence, 0 (none)"), "{s}");
                }
                "/state" => {
                    assert_eq!(v["fsm_state"], "turn");
                    assert_eq!(v["mode"], "flying");
                }
                t @ ("/camera/left" | "/camera/right") => {
                    let schema = m.channel.schema.as_ref().unwrap();
                    assert_eq!(schema.name, "foxglove.CompressedImage");
                    assert_eq!(schema.encoding, "protobuf");
                    assert_eq!(m.channel.message_encoding, "protobuf");
                    let image = <foxglove::schemas::CompressedImage as foxglove::Decode>::decode(
                        &m.data[..],
                    )
                    .unwrap();
                    assert_eq!(image.format, "png");
                    let pixels = image::load_from_memory(&image.data).unwrap().to_luma8();
                    assert_eq!(pixels.dimensions(), (128, 96));
                    let want = if t == "/camera/left" { 10 } else { 200 };
                    assert!(pixels.pixels().all(|p| p.0[0] == want), "{t}");
                }
                other => panic!("unexpected topic {other}"),
            }
        }
        let want: Vec<(String, u64)> = [
            ("/estimate", 1_000),
            ("/state", 2_000),
            ("/camera/left", 3_000),
            ("/camera/right", 3_000),
        ]
        .iter()
        .map(|(t, n)| (t.to_string(), *n))
        .collect();
        assert_eq!(topics, want);
    }

    #[test]
    fn thinner_keeps_one_sample_per_period_on_an_irregular_grid() {
        // 512 Hz ticks rounded down to whole µs, thinned to 128 Hz: every fourth.
        let mut th = Thinner::new(128.0);
        let taken: Vec<u64> = (0..16u64)
            .map(|k| k * 1_000_000 / 512)
            .filter(|&t| th.take(t))
            .collect();
        assert_eq!(taken, [0, 7_812, 15_625, 23_437]);
        // 10 fps frames on the IMU grid, thinned to 5 Hz: every second.
        let mut th = Thinner::new(5.0);
        let frames = [101_562, 201_171, 300_781, 400_390, 500_000];
        let taken: Vec<u64> = frames.into_iter().filter(|&t| th.take(t)).collect();
        assert_eq!(taken, [101_562, 300_781, 500_000]);
        // 25 fps frames, thinned to 5 Hz: every fifth.
        let mut th = Thinner::new(5.0);
        let taken = (0..11u64).filter(|k| th.take(100_000 + k * 40_000)).count();
        assert_eq!(taken, 3);
        assert!(!Thinner::new(0.0).take(0));
    }

    #[test]
    fn states_and_modes_are_named_and_numbered() {
        let s = StateRecord::new(None, protocol::FlightMode::Disarmed);
        assert_eq!(
            (s.fsm_state, s.fsm_state_id, s.mode, s.mode_id),
            ("inactive", -1, "disarmed", 0)
        );
        let s = StateRecord::new(
            Some(protocol::FsmState::Hover),
            protocol::FlightMode::ImuFault,
        );
        assert_eq!(
            (s.fsm_state, s.fsm_state_id, s.mode, s.mode_id),
            ("hover", 2, "imu-fault", 5)
        );
    }

    #[test]
    fn an_unwritable_path_is_named() {
        let e = FlightLog::create(Path::new("/nonexistent-dir/flight.mcap"))
            .err()
            .unwrap();
        assert!(
            format!("{e:#}").contains("/nonexistent-dir/flight.mcap"),
            "{e:#}"
        );
    }
}
