//! The camera board's two Toshiba TCM8230MD sensors: their SCCB register file, their power-up
//! (master clock and reset), and the stream they put out once set up.
//!
//! Sources: the TCM8230MD (A) datasheet ver. 1.20 (Toshiba, "VGA camera module": 8-bit parallel
//! YUV 4:2:2 or RGB 5:6:5 output with DCLK, HBLK and VBLK; picture sizes VGA to subQCIF by
//! sub-sampling; max 30 fps; I2C bus interface), and for each register field the original board's
//! firmware (\[SB\] `stereoboard/drivers/src/tcm8230.c` and `dcmi.c`, whose defines name the fields
//! it uses), as `../shared/hardware/original-boards.md` lists them.
//!
//! | what | model | source |
//! |---|---|---|
//! | SCCB address | 0x3C (7-bit), write `[sub-address, data...]`, read `[sub-address]` then a repeated start and data; the sub-address steps on after each byte | \[SB\] tcm8230.c `TCM8230_ADDR`, `tcm8230_WriteReg`/`ReadReg` |
//! | the pair | both sensors answer the one address through the CPLD, so a write sets both: one register file | \[SB\] tcm8230.c (one set-up for both) |
//! | 0x02 | bit 7 frame rate (0: 30 fps at the nominal 25.54 MHz clock, 1: half), bit 6 flicker 50/60 Hz, bit 1 DCLK polarity reversed (data launched on the rising edge, to be sampled on the falling one), bit 0 flicker detection | \[SB\] tcm8230.c `TCM_FPS_*`, `TCM_ACF`, `TCM_CLK_POL`, `TCM_ACF_DET`; camera_type.h (falling-edge DCMI with the bit set) |
//! | 0x03 | bit 7 `DOUTSW` data output off (resets to off: the sensor streams only once told to), bit 6 `DATAHZ` outputs high-impedance, bits 5:2 picture size (8 = subQCIF 128x96), bit 1 RGB 5:6:5 instead of YUV 4:2:2, bit 0 black and white | datasheet feature list; \[SB\] tcm8230.c `IMG_SIZE_*`, `IMG_FORMAT_*`, `IMG_COLOR_*` |
//! | other registers | stored and read back (exposure, luminance control, gains, white balance, gamma, contrast, brightness, hue, saturation, `ES100S`/`ES120S`, `SWC`) with the reset values the original firmware's comments give; they do not change the picture | \[SB\] tcm8230.c comments ("Default ...") |
//! | master clock | EXTCLK must run (11.9 to 27 MHz accepted); the byte clock DCLK is EXTCLK, a line period is 1,560 EXTCLK periods, a frame 546 line periods at 30 fps (the 30 fps of the datasheet at its nominal 25.54 MHz: 25.54 MHz / 30 / 1,560 = 546), so 24.65 fps at the board's 21 MHz | datasheet (max 30 fps, nominal clock); \[SB\] tcm8230.c `ES100S = CLK / (780 * 2 * 100)`; dcmi.c (21 MHz, "nominal 25.54 MHz") |
//! | reset | RESET low for at least 100 EXTCLK periods with the clock running resets the sensor (registers to their reset values); the sensor answers SCCB and can stream from 100 EXTCLK periods after RESET rises; RESET low again stops it | \[SB\] dcmi.c `camera_unreset` ("wait for at least 100 clock cycles") |
//! | stream | VBLK (the DCMI's VSYNC) inactive for 480 of the 546 line periods; the `h` output lines of a picture size sit at line periods `j * 480 / h`, HBLK (HSYNC) inactive for the `2 w` bytes at their start; during blanking the data bus carries 0x00 | datasheet (sub-sampling of the 640x480 array); blanking level: our choice |
//!
//! What is left out: the image processing (exposure, gains, white balance, gamma, brightness,
//! contrast) is not applied: the sensor puts out the luminance it is fed, as the data set
//! recorded it through the original set-up. ITU-656 embedded sync codes (`SWC`) are not put
//! in the stream. Sleep mode is not modelled. The exact blanking widths of the smaller sizes are
//! not in the datasheet at hand; the line and frame periods above fix the frame rate, which is
//! what the firmware sees.
//!
//! The sensor pair has two faces: its SCCB port ([`SccbPort`], a [`rigless::chip::i2c::Peer`] on
//! I2C2) and its pixel port, which the DCMI model ([`crate::dcmi`]) drives. Both hold the one
//! [`Sensor`] behind a shared handle ([`SensorHandle`]).

use std::sync::{Arc, Mutex, MutexGuard};

use rigless::chip::Timeline;
use rigless::chip::i2c::Peer;
use rigless::snapshot::Store;
use rigless::time::VirtualNanos;

/// The sensors' 7-bit SCCB address (\[SB\] tcm8230.c `TCM8230_ADDR` = 0b0011_1100).
pub const ADDRESS: u8 = 0x3C;

/// Number of sub-addresses the register file spans.
pub const REGISTERS: usize = 0x20;

/// Register 0x00 reads 0x70 (\[SB\] tcm8230.c comment on `TCM_WHO_AM_I`); read-only.
pub const IDENTITY: u8 = 0x70;

/// Frame-rate and clock-polarity register.
pub const REG_FPS: u8 = 0x02;
/// Output and picture-format register.
pub const REG_FORMAT: u8 = 0x03;

/// `REG_FPS` bit 7: half frame rate.
pub const FPS_SLOW: u8 = 1 << 7;
/// `REG_FPS` bit 1: DCLK polarity reversed (data launched on the rising edge).
pub const CLOCK_POLARITY_REVERSED: u8 = 1 << 1;
/// `REG_FORMAT` bit 7: data output off.
pub const OUTPUT_OFF: u8 = 1 << 7;
/// `REG_FORMAT` bit 6: outputs high-impedance.
pub const OUTPUT_HIGH_Z: u8 = 1 << 6;
/// `REG_FORMAT` bit 1: RGB 5:6:5 instead of YUV 4:2:2.
pub const FORMAT_RGB565: u8 = 1 << 1;
/// `REG_FORMAT` bit 0: black and white.
pub const COLOUR_BW: u8 = 1 << 0;
/// `REG_FORMAT` bits 5:2 value for subQCIF (128x96).
pub const SIZE_SUBQCIF: u8 = 8;

/// EXTCLK periods per line period (DCLK = EXTCLK, one byte per period).
pub const LINE_CLOCKS: u64 = 1_560;
/// Line periods per frame at the full frame rate.
pub const FRAME_LINES: u64 = 546;
/// Line periods with VBLK inactive (the sensor's 480 active rows).
pub const ACTIVE_LINES: u64 = 480;
/// EXTCLK periods RESET must be held low, and must have been high, before the sensor runs.
pub const RESET_CLOCKS: u64 = 100;
/// Lowest EXTCLK the model accepts, Hz.
pub const EXTCLK_MIN_HZ: u64 = 11_900_000;
/// Highest EXTCLK the model accepts, Hz.
pub const EXTCLK_MAX_HZ: u64 = 27_000_000;

/// Reset values, by sub-address (the original firmware's "Default" comments; 0x03 output off).
const RESET_VALUES: [u8; REGISTERS] = {
    let mut r = [0u8; REGISTERS];
    r[0x00] = IDENTITY;
    r[0x03] = OUTPUT_OFF;
    r[0x05] = 0x02; // shutter speed high bits of the default 0x020D
    r[0x06] = 0x0D;
    r[0x07] = 0xC0; // analog gain
    r[0x08] = 0x08; // ALC convergence range
    r[0x09] = 0x40; // ALC lower level
    r[0x0B] = 0x40; // manual red gain
    r[0x0C] = 0x40; // manual blue gain
    r[0x11] = 0x9A; // contrast
    r[0x12] = 0x0C; // brightness
    r[0x13] = 0x0A; // V hue
    r[0x14] = 0x0A; // U hue
    r[0x15] = 0x38; // V gain
    r[0x16] = 0x38; // U gain
    r[0x18] = 0x27; // saturation
    r[0x1E] = 0x68; // sync code mode
    r
};

/// What the board puts on the sensors' pins, as sampled by the board.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SensorPins {
    /// EXTCLK, Hz, when a clock reaches the sensors' clock input (PA7 on the camera board).
    pub extclk_hz: Option<u64>,
    /// RESET (PD2) driven high.
    pub reset_released: bool,
}

/// Where the sensors are in their power-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Power {
    /// RESET is low (or was never pulsed properly); `low_since` is the first sample with RESET low
    /// and the clock running, `last_low` the latest.
    Held {
        /// First instant RESET was seen low with the clock running.
        low_since: Option<VirtualNanos>,
        /// Latest instant RESET was seen low with the clock running.
        last_low: Option<VirtualNanos>,
    },
    /// RESET rose at `released_at` (first seen high) after a proper reset; the sensor runs from
    /// 100 EXTCLK periods later.
    Starting {
        /// First instant RESET was seen high.
        released_at: VirtualNanos,
    },
    /// Reset done: the sensor answers SCCB and streams while its clock runs and its output is on.
    Running,
    /// RESET rose without having been held low with the clock running for 100 periods: the
    /// sensor's state is undefined and it answers nothing until reset properly.
    Unreset,
}

/// A picture size of register 0x03 bits 5:2: output width and height, pixels.
#[must_use]
pub fn picture_size(code: u8) -> Option<(usize, usize)> {
    Some(match code {
        0 => (640, 480),
        1 | 2 => (320, 240),
        3 | 4 => (160, 120),
        5 => (352, 288),
        6 | 7 => (176, 144),
        8 | 9 => (128, 96),
        _ => return None,
    })
}

/// Pixel format of the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// YUV 4:2:2: each pixel a chroma byte then its luminance byte.
    Yuv422,
    /// RGB 5:6:5, high byte first.
    Rgb565,
}

/// What the sensors stream, decoded from their registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamSetup {
    /// Output width, pixels.
    pub width: usize,
    /// Output height, pixels (lines).
    pub height: usize,
    /// Pixel format.
    pub format: Format,
    /// Line periods per frame (546, or twice that at the half rate).
    pub frame_lines: u64,
    /// Data launched on DCLK's rising edge (register 0x02 bit 1), so to be sampled on the falling.
    pub launch_on_rising: bool,
}

impl StreamSetup {
    /// The two bytes one sensor puts out for a pixel of luminance `y` (a grey scene: chroma 0x80).
    #[must_use]
    pub fn pixel_bytes(&self, y: u8) -> [u8; 2] {
        match self.format {
            Format::Yuv422 => [0x80, y],
            Format::Rgb565 => {
                let (r, g, b) = (u16::from(y >> 3), u16::from(y >> 2), u16::from(y >> 3));
                let v = (r << 11) | (g << 5) | b;
                v.to_be_bytes()
            }
        }
    }

    /// The line period output line `line` occupies within the frame.
    #[must_use]
    pub fn line_period(&self, line: usize) -> u64 {
        line as u64 * ACTIVE_LINES / self.height as u64
    }
}

/// The sensor pair's state: registers and power-up.
#[derive(Debug, Clone)]
pub struct Sensor {
    registers: [u8; REGISTERS],
    power: Power,
    pins: SensorPins,
    /// Sub-address of the next SCCB data byte.
    pointer: u8,
    /// The next written byte of this transaction is a sub-address.
    expect_address: bool,
    /// SCCB writes the sensor acknowledged (sub-address bytes included).
    pub sccb_writes: u64,
    /// SCCB transactions the sensor did not acknowledge (not running, wrong address).
    pub sccb_nacks: u64,
}

impl Default for Sensor {
    fn default() -> Self {
        Self {
            registers: RESET_VALUES,
            power: Power::Held {
                low_since: None,
                last_low: None,
            },
            pins: SensorPins::default(),
            pointer: 0,
            expect_address: true,
            sccb_writes: 0,
            sccb_nacks: 0,
        }
    }
}

impl Sensor {
    /// The register file as it stands.
    #[must_use]
    pub fn registers(&self) -> &[u8; REGISTERS] {
        &self.registers
    }

    /// Where the power-up stands.
    #[must_use]
    pub fn power(&self) -> Power {
        self.power
    }

    /// The pins as last sampled.
    #[must_use]
    pub fn pins(&self) -> SensorPins {
        self.pins
    }

    /// The master clock, Hz, when it runs within the sensor's range.
    #[must_use]
    pub fn clock_hz(&self) -> Option<u64> {
        self.pins
            .extclk_hz
            .filter(|hz| (EXTCLK_MIN_HZ..=EXTCLK_MAX_HZ).contains(hz))
    }

    fn periods(hz: u64, count: u64) -> u64 {
        (u128::from(count) * 1_000_000_000).div_ceil(u128::from(hz)) as u64
    }

    /// Takes the pins as the board last sampled them, to be timed at the next [`Sensor::observe`].
    pub fn set_pins(&mut self, pins: SensorPins) {
        self.pins = pins;
    }

    /// Takes the pins as sampled at `now` and moves the power-up on.
    pub fn observe(&mut self, now: VirtualNanos, pins: SensorPins) {
        self.pins = pins;
        let clock = self.clock_hz();
        if !pins.reset_released {
            let (low_since, last_low) = match self.power {
                Power::Held {
                    low_since: Some(since),
                    ..
                } if clock.is_some() => (Some(since), Some(now)),
                _ if clock.is_some() => (Some(now), Some(now)),
                _ => (None, None),
            };
            if !matches!(self.power, Power::Held { .. }) {
                // RESET low again: the sensor is reset (datasheet: RESET is asynchronous).
                self.registers = RESET_VALUES;
            }
            self.power = Power::Held {
                low_since,
                last_low,
            };
            return;
        }
        match self.power {
            Power::Held {
                low_since: Some(since),
                last_low: Some(last),
            } => {
                let held = clock.is_some_and(|hz| {
                    last.0.saturating_sub(since.0) >= Self::periods(hz, RESET_CLOCKS)
                });
                if held {
                    self.registers = RESET_VALUES;
                    self.power = Power::Starting { released_at: now };
                } else {
                    self.power = Power::Unreset;
                }
            }
            Power::Held { .. } => self.power = Power::Unreset,
            Power::Starting { released_at } => {
                if clock.is_some_and(|hz| {
                    now.0.saturating_sub(released_at.0) >= Self::periods(hz, RESET_CLOCKS)
                }) {
                    self.power = Power::Running;
                }
            }
            Power::Running | Power::Unreset => {}
        }
    }

    /// Whether the sensor has come out of reset and its clock runs.
    #[must_use]
    pub fn is_running(&self) -> bool {
        self.power == Power::Running && self.clock_hz().is_some()
    }

    /// What the sensors stream, or `None` while they do not (not running, output off or
    /// high-impedance, a picture size the datasheet does not list).
    #[must_use]
    pub fn stream(&self) -> Option<StreamSetup> {
        if !self.is_running() {
            return None;
        }
        let format = self.registers[usize::from(REG_FORMAT)];
        if format & (OUTPUT_OFF | OUTPUT_HIGH_Z) != 0 {
            return None;
        }
        let (width, height) = picture_size((format >> 2) & 0x0F)?;
        let fps = self.registers[usize::from(REG_FPS)];
        Some(StreamSetup {
            width,
            height,
            format: if format & FORMAT_RGB565 != 0 {
                Format::Rgb565
            } else {
                Format::Yuv422
            },
            frame_lines: if fps & FPS_SLOW != 0 {
                2 * FRAME_LINES
            } else {
                FRAME_LINES
            },
            launch_on_rising: fps & CLOCK_POLARITY_REVERSED != 0,
        })
    }

    /// Whether the power-up needs its pins sampled closely now: while RESET is held with the
    /// clock running, or while starting.
    #[must_use]
    pub fn needs_close_watch(&self) -> bool {
        match self.power {
            Power::Held { .. } => self.clock_hz().is_some() && !self.pins.reset_released,
            Power::Starting { .. } => true,
            Power::Running | Power::Unreset => false,
        }
    }

    /// SCCB start condition at `now` for `address`: acknowledged only by a running sensor at
    /// its own address.
    pub fn sccb_start(&mut self, now: VirtualNanos, address: u8, read: bool) -> bool {
        let pins = self.pins;
        self.observe(now, pins);
        if address != ADDRESS || !self.is_running() {
            self.sccb_nacks += 1;
            return false;
        }
        if !read {
            self.expect_address = true;
        }
        true
    }

    /// One written SCCB byte at `now`: the sub-address first, then data for it and the next ones.
    pub fn sccb_write(&mut self, now: VirtualNanos, byte: u8) -> bool {
        let pins = self.pins;
        self.observe(now, pins);
        if !self.is_running() {
            self.sccb_nacks += 1;
            return false;
        }
        self.sccb_writes += 1;
        if self.expect_address {
            self.pointer = byte;
            self.expect_address = false;
        } else {
            let at = usize::from(self.pointer) % REGISTERS;
            if at != 0 {
                self.registers[at] = byte;
            }
            self.pointer = self.pointer.wrapping_add(1);
        }
        true
    }

    /// One SCCB byte read: the register at the sub-address, which then steps on (0xFF, the
    /// released bus, from a sensor that is not running).
    pub fn sccb_read(&mut self) -> u8 {
        if !self.is_running() {
            return 0xFF;
        }
        let value = self.registers[usize::from(self.pointer) % REGISTERS];
        self.pointer = self.pointer.wrapping_add(1);
        value
    }

    /// SCCB stop condition.
    pub fn sccb_stop(&mut self) {
        self.expect_address = true;
    }

    /// A whole SCCB register write at `now`, as the firmware's `write(0x3C, [register, value])`:
    /// whether every byte was acknowledged.
    pub fn sccb_write_register(&mut self, now: VirtualNanos, register: u8, value: u8) -> bool {
        let ok = self.sccb_start(now, ADDRESS, false)
            && self.sccb_write(now, register)
            && self.sccb_write(now, value);
        self.sccb_stop();
        ok
    }

    /// A whole SCCB register read at `now` (sub-address write, repeated start, one byte).
    pub fn sccb_read_register(&mut self, now: VirtualNanos, register: u8) -> Option<u8> {
        let ok = self.sccb_start(now, ADDRESS, false)
            && self.sccb_write(now, register)
            && self.sccb_start(now, ADDRESS, true);
        let value = self.sccb_read();
        self.sccb_stop();
        ok.then_some(value)
    }
}

/// The shared handle both faces of the sensor pair hold.
#[derive(Debug, Clone, Default)]
pub struct SensorHandle(Arc<Mutex<Sensor>>);

impl SensorHandle {
    /// A sensor pair fresh from power-up (held in reset).
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// The sensor state, locked.
    ///
    /// # Panics
    /// Only if a thread panicked while holding the lock (the bench is single-threaded).
    pub fn lock(&self) -> MutexGuard<'_, Sensor> {
        self.0.lock().expect("the sensor lock is never poisoned")
    }

    /// The SCCB face, to attach to the board's I2C interface.
    #[must_use]
    pub fn sccb_port(&self) -> SccbPort {
        SccbPort {
            sensor: self.clone(),
        }
    }
}

/// The sensors' SCCB port: a [`Peer`] on the board's I2C2.
#[derive(Debug)]
pub struct SccbPort {
    sensor: SensorHandle,
}

/// Snapshots do not keep the camera (its frame source is outside the bench).
impl Store for SccbPort {}

impl SccbPort {
    /// The sensor behind this port.
    #[must_use]
    pub fn sensor(&self) -> &SensorHandle {
        &self.sensor
    }
}

impl Peer for SccbPort {
    fn start(&mut self, address: u8, read: bool, context: &mut Timeline<'_, '_>) -> bool {
        self.sensor.lock().sccb_start(context.now(), address, read)
    }

    fn write(&mut self, byte: u8, context: &mut Timeline<'_, '_>) -> bool {
        self.sensor.lock().sccb_write(context.now(), byte)
    }

    fn read(&mut self, _last: bool, _context: &mut Timeline<'_, '_>) -> u8 {
        self.sensor.lock().sccb_read()
    }

    fn stop(&mut self, _context: &mut Timeline<'_, '_>) {
        self.sensor.lock().sccb_stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HZ: u64 = 21_000_000;

    fn pins(clock: bool, released: bool) -> SensorPins {
        SensorPins {
            extclk_hz: clock.then_some(HZ),
            reset_released: released,
        }
    }

    fn running() -> Sensor {
        let mut s = Sensor::default();
        s.observe(VirtualNanos(0), pins(true, false));
        s.observe(VirtualNanos(10_000), pins(true, false));
        s.observe(VirtualNanos(11_000), pins(true, true));
        s.observe(VirtualNanos(20_000), pins(true, true));
        assert_eq!(s.power(), Power::Running);
        s
    }

    #[test]
    fn a_reset_pulse_with_the_clock_running_brings_the_sensor_up_100_clocks_after_release() {
        let mut s = Sensor::default();
        s.observe(VirtualNanos(0), pins(true, false));
        s.observe(VirtualNanos(5_000), pins(true, false)); // 105 periods of 47.6 ns
        s.observe(VirtualNanos(5_500), pins(true, true));
        assert_eq!(
            s.power(),
            Power::Starting {
                released_at: VirtualNanos(5_500)
            }
        );
        s.observe(VirtualNanos(5_500 + 4_700), pins(true, true));
        assert!(!s.is_running(), "98.7 periods after release is too early");
        s.observe(VirtualNanos(5_500 + 4_800), pins(true, true));
        assert!(s.is_running());
    }

    #[test]
    fn no_clock_or_a_short_reset_pulse_leaves_the_sensor_dead() {
        let mut s = Sensor::default();
        s.observe(VirtualNanos(0), pins(false, false));
        s.observe(VirtualNanos(1_000_000), pins(false, false));
        s.observe(VirtualNanos(1_000_100), pins(true, true));
        assert_eq!(s.power(), Power::Unreset, "reset held without a clock");
        let mut s = Sensor::default();
        s.observe(VirtualNanos(0), pins(true, false));
        s.observe(VirtualNanos(1_000), pins(true, false)); // 21 periods
        s.observe(VirtualNanos(2_000), pins(true, true));
        s.observe(VirtualNanos(1_000_000), pins(true, true));
        assert_eq!(s.power(), Power::Unreset, "reset pulse of 21 periods");
        let mut s = Sensor::default();
        s.observe(VirtualNanos(0), pins(true, true));
        assert_eq!(s.power(), Power::Unreset, "never reset");
        assert!(s.stream().is_none());
    }

    #[test]
    fn the_sensor_streams_only_once_its_output_is_switched_on_at_a_listed_size() {
        let mut s = running();
        assert_eq!(s.stream(), None, "output off after reset");
        s.registers[3] = SIZE_SUBQCIF << 2;
        let setup = s.stream().expect("streams");
        assert_eq!((setup.width, setup.height), (128, 96));
        assert_eq!(setup.format, Format::Yuv422);
        assert_eq!(setup.frame_lines, FRAME_LINES);
        s.registers[3] = (SIZE_SUBQCIF << 2) | OUTPUT_HIGH_Z;
        assert_eq!(s.stream(), None, "outputs high-impedance");
        s.registers[3] = 0x0F << 2;
        assert_eq!(s.stream(), None, "size code 15 is not listed");
        s.registers[3] = (SIZE_SUBQCIF << 2) | FORMAT_RGB565;
        assert_eq!(s.stream().expect("streams").format, Format::Rgb565);
        // Clock stops: no stream; it comes back: the stream resumes.
        s.observe(VirtualNanos(30_000), pins(false, true));
        assert_eq!(s.stream(), None);
        s.observe(VirtualNanos(40_000), pins(true, true));
        assert!(s.stream().is_some());
        // RESET low again: registers back to their reset values.
        s.observe(VirtualNanos(50_000), pins(true, false));
        assert_eq!(s.registers()[3], OUTPUT_OFF);
    }

    #[test]
    fn sccb_reads_back_what_was_written_and_only_from_a_running_sensor() {
        let mut s = Sensor::default();
        let t = VirtualNanos(1);
        assert!(!s.sccb_write_register(t, REG_FORMAT, 0x20), "held in reset");
        assert_eq!(s.sccb_read_register(t, REG_FORMAT), None);
        let mut s = running();
        let t = VirtualNanos(30_000);
        assert!(s.sccb_write_register(t, REG_FORMAT, 0x20));
        assert!(s.sccb_write_register(t, 0x12, 0x1C));
        assert_eq!(s.sccb_read_register(t, REG_FORMAT), Some(0x20));
        assert_eq!(s.sccb_read_register(t, 0x12), Some(0x1C));
        assert_eq!(
            s.sccb_read_register(t, 0x11),
            Some(0x9A),
            "reset value kept"
        );
        assert!(s.sccb_write_register(t, 0x00, 0x12), "acknowledged");
        assert_eq!(
            s.sccb_read_register(t, 0x00),
            Some(IDENTITY),
            "but read-only"
        );
        assert!(!s.sccb_start(t, 0x21, false), "another address");
        // Sub-address steps on: one transaction sets 0x1C and 0x1D.
        assert!(s.sccb_start(t, ADDRESS, false));
        assert!(s.sccb_write(t, 0x1C) && s.sccb_write(t, 135) && s.sccb_write(t, 112));
        s.sccb_stop();
        assert_eq!((s.registers()[0x1C], s.registers()[0x1D]), (135, 112));
    }

    #[test]
    fn a_frame_at_21_mhz_lasts_40_56_ms() {
        let frame_ns = FRAME_LINES * LINE_CLOCKS * 1_000_000_000 / HZ;
        assert_eq!(frame_ns, 40_560_000);
    }

    #[test]
    fn rgb565_of_grey_keeps_the_top_bits_of_each_channel() {
        let setup = StreamSetup {
            width: 128,
            height: 96,
            format: Format::Rgb565,
            frame_lines: FRAME_LINES,
            launch_on_rising: false,
        };
        assert_eq!(setup.pixel_bytes(0xFF), [0xFF, 0xFF]);
        assert_eq!(setup.pixel_bytes(0x80), [0x84, 0x10]);
        assert_eq!(setup.line_period(95), 475);
    }
}
