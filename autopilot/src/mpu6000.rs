//! MPU-6000 (InvenSense datasheet PS-MPU-6000A-00 rev 3.4, register map RM-MPU-6000A-00
//! rev 4.2): the register set-up, and what makes a sample trustworthy. Hardware-free: the
//! firmware does the SPI transfers and hands the bytes here, so the checks are tested on the
//! host and run unchanged on the board.
//!
//! A sample is **valid** only if, read in the same control step:
//!
//! * `WHO_AM_I` (0x75) still reads 0x68 (an unplugged or reset-to-I2C sensor answers 0x00 or
//!   0xFF on MISO),
//! * `PWR_MGMT_1` (0x6B) shows the sensor awake (SLEEP bit clear) on the configured clock (a
//!   brown-out reset puts it back to sleep with the internal oscillator),
//! * the 14 data bytes are not all 0x00 and not all 0xFF (a dead bus),
//! * no gyro or accelerometer axis sits at full scale (-32768 or +32767: saturated, the value
//!   is a bound, not a measurement),
//! * the six axes are not bit-for-bit the same as in the previous [`STUCK_SAMPLES`] - 1
//!   samples (a frozen sensor or a stale register),
//! * and neither sensor alone is frozen: the three gyro axes not the same as in the previous
//!   [`GYRO_STUCK_SAMPLES`] - 1 samples, the three accelerometer axes not the same as in the
//!   previous [`ACCEL_STUCK_SAMPLES`] - 1 (a gyro that froze while the accelerometer lives, or
//!   the other way round, would otherwise pass).
//!
//! # Why four samples for "stuck", and more for one sensor alone
//!
//! The sensor is set to output 1 kHz and the loop reads at 512 Hz, so every read gets a new
//! conversion; real samples repeat only by chance. The noise floor (datasheet table 6.1 and
//! 6.2: gyro 0.005 deg/s/sqrt(Hz), accelerometer 400 ug/sqrt(Hz)) over the 188 Hz low-pass
//! (about 295 Hz noise bandwidth) is about 1.4 LSB rms per gyro axis at +-2000 deg/s and
//! 28 LSB rms per accelerometer axis at +-8 g. Two readings of one axis agree with probability
//! about 1 / (2 sqrt(pi) sigma): 0.2 for a gyro axis, 0.01 for an accelerometer axis, so all
//! six agree with about 8e-9, once every 67 hours at 512 Hz. Four equal samples in a row (three
//! repeats) happen by chance with about 5e-25: never; a frozen sensor is caught after 5.9 ms,
//! well inside the 20 ms IMU failsafe. A noiseless sensor model is rightly rejected as stuck.
//!
//! One sensor alone has three axes: its three agree by chance with about 0.2^3 = 8e-3 (gyro)
//! and 0.01^3 = 1e-6 (accelerometer). Ten gyro repeats (eleven equal samples, 19.5 ms) happen
//! by chance with about 1e-21 per sample, four accelerometer repeats with 1e-24: never. A gyro
//! frozen alone is caught after 19.5 ms, an accelerometer alone after 7.8 ms.
//!
//! Invalid samples are not handed to the flight code: the IMU failsafe
//! ([`crate::failsafe`]) sees them as missing and turns the motors off after its timeout.
//!
//! # A sensor reset in flight
//!
//! A brown-out or an ESD event resets the MPU-6000: it comes back answering `WHO_AM_I`, asleep
//! (`PWR_MGMT_1` = 0x40), with every configuration register at its default (register map
//! section 3: +-250 deg/s, +-2 g, no low-pass filter, I2C on). [`Reconfigure`] tells the
//! firmware when to write [`CONFIG_SEQUENCE`] again: on a sample that identifies the chip but
//! shows it not awake on the configured clock, at most once per [`RECONFIGURE_INTERVAL`]. The
//! firmware then reads the configuration back ([`config_matches`]) before it trusts a sample
//! again. No `DEVICE_RESET` is sent in flight: the chip has just come out of its own reset, and
//! that reset's 100 ms wait cannot be spent in the 512 Hz loop. The samples stay invalid through
//! the gyro's start-up (30 ms, PS table 6.1), longer than the IMU failsafe's 20 ms, so the
//! motors are off by then and stay off until the pilot arms again (see
//! [`crate::failsafe::FlightMode::ImuFault`]).

use crate::board::{AxisMap, Mounting};
use protocol::{ImuSample, WireTime};
use timebase::{Duration, Instant};

/// Read flag of an SPI register address (bit 7 set).
pub const READ: u8 = 0x80;
/// `SMPLRT_DIV`: sample rate = gyro output rate / (1 + value).
pub const SMPLRT_DIV: u8 = 0x19;
/// `CONFIG`: DLPF_CFG in bits 2:0.
pub const CONFIG: u8 = 0x1A;
/// `GYRO_CONFIG`: FS_SEL in bits 4:3.
pub const GYRO_CONFIG: u8 = 0x1B;
/// `ACCEL_CONFIG`: AFS_SEL in bits 4:3.
pub const ACCEL_CONFIG: u8 = 0x1C;
/// `INT_ENABLE`.
pub const INT_ENABLE: u8 = 0x38;
/// `ACCEL_XOUT_H`: first of the 14 data bytes (accel x, y, z, temperature, gyro x, y, z; each
/// big-endian `i16`).
pub const ACCEL_XOUT_H: u8 = 0x3B;
/// `SIGNAL_PATH_RESET`.
pub const SIGNAL_PATH_RESET: u8 = 0x68;
/// `USER_CTRL`: bit 4 I2C_IF_DIS (SPI only).
pub const USER_CTRL: u8 = 0x6A;
/// `PWR_MGMT_1`: bit 7 DEVICE_RESET, bit 6 SLEEP, bits 2:0 CLKSEL.
pub const PWR_MGMT_1: u8 = 0x6B;
/// `WHO_AM_I`.
pub const WHO_AM_I: u8 = 0x75;
/// What `WHO_AM_I` reads on an MPU-6000.
pub const WHO_AM_I_VALUE: u8 = 0x68;
/// `PWR_MGMT_1` value: DEVICE_RESET.
pub const PWR_MGMT_1_RESET: u8 = 0x80;
/// `PWR_MGMT_1` value in flight: awake, clock from the z gyro's PLL (CLKSEL = 3, the
/// datasheet's recommendation over the internal oscillator).
pub const PWR_MGMT_1_RUN: u8 = 0x03;
/// SLEEP bit of `PWR_MGMT_1`.
pub const PWR_MGMT_1_SLEEP: u8 = 0x40;
/// Wait after DEVICE_RESET before the next access (register map section 4.28: 100 ms).
pub const RESET_WAIT: Duration = Duration::from_millis(100);
/// Wait after SIGNAL_PATH_RESET (register map section 4.26 recommends 100 ms over SPI).
pub const SIGNAL_PATH_RESET_WAIT: Duration = Duration::from_millis(100);

/// The register writes after the reset, in order (register, value).
///
/// * `PWR_MGMT_1` = 0x03: awake, z-gyro PLL clock.
/// * `USER_CTRL` = 0x10: I2C interface off (SPI only; register map section 4.27).
/// * `CONFIG` = 0x01: DLPF 188 Hz (accel 184 Hz), gyro output rate 1 kHz.
/// * `SMPLRT_DIV` = 0: sample rate 1 kHz, faster than the 512 Hz loop reads.
/// * `GYRO_CONFIG` = 0x18: +-2000 deg/s, 16.4 LSB per deg/s.
/// * `ACCEL_CONFIG` = 0x10: +-8 g, 4096 LSB per g.
/// * `INT_ENABLE` = 0: no interrupt (no data-ready line is used).
pub const CONFIG_SEQUENCE: [(u8, u8); 7] = [
    (PWR_MGMT_1, PWR_MGMT_1_RUN),
    (USER_CTRL, 0x10),
    (CONFIG, 0x01),
    (SMPLRT_DIV, 0x00),
    (GYRO_CONFIG, 0x18),
    (ACCEL_CONFIG, 0x10),
    (INT_ENABLE, 0x00),
];

/// The configuration registers that [`CONFIG_SEQUENCE`] sets and a reset changes, read back
/// after a re-configuration, in the order [`config_matches`] takes them: `CONFIG`,
/// `GYRO_CONFIG`, `ACCEL_CONFIG`.
pub const CONFIG_READBACK: [u8; 3] = [CONFIG, GYRO_CONFIG, ACCEL_CONFIG];

/// Whether `values` (read from [`CONFIG_READBACK`], in its order) are what
/// [`CONFIG_SEQUENCE`] wrote.
pub fn config_matches(values: [u8; 3]) -> bool {
    CONFIG_READBACK.iter().zip(values).all(|(&reg, value)| {
        CONFIG_SEQUENCE
            .iter()
            .any(|&(r, expected)| r == reg && expected == value)
    })
}

/// The shortest time between two re-configurations of a sensor that keeps showing asleep
/// (the gyro's start-up time: a chip that does not take the configuration is not written to
/// at every 512 Hz step).
pub const RECONFIGURE_INTERVAL: Duration = Duration::from_millis(30);

/// When to configure the sensor again after it reset (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Reconfigure {
    last: Option<Instant>,
    count: u32,
}

impl Reconfigure {
    /// No re-configuration yet.
    pub const fn new() -> Self {
        Self {
            last: None,
            count: 0,
        }
    }

    /// After a rejected sample at `now`: whether to write [`CONFIG_SEQUENCE`] now. Only a
    /// chip that identifies itself but is not awake on the configured clock is reset; anything
    /// else (a dead bus, a frozen or saturated sensor) is not cured by writing registers.
    pub fn due(&mut self, fault: SampleFault, now: Instant) -> bool {
        let SampleFault::NotAwake(pwr_mgmt_1) = fault else {
            return false;
        };
        if pwr_mgmt_1 & PWR_MGMT_1_RESET != 0 {
            return false; // still resetting
        }
        if matches!(self.last, Some(t) if now.since(t) < RECONFIGURE_INTERVAL) {
            return false;
        }
        self.last = Some(now);
        self.count = self.count.wrapping_add(1);
        true
    }

    /// Re-configurations since boot (wrapping).
    pub fn count(&self) -> u32 {
        self.count
    }
}

/// Gyro scale at +-2000 deg/s: 16.4 LSB per deg/s, in rad/s per LSB.
pub const GYRO_RADPS_PER_LSB: f32 = core::f32::consts::PI / 180.0 / 16.4;
/// Accelerometer scale at +-8 g: 4096 LSB per g, in m/s^2 per LSB.
pub const ACCEL_MPS2_PER_LSB: f32 = 9.806_65 / 4096.0;

/// Equal consecutive samples (gyro and accelerometer, bit for bit) that make a sensor stuck:
/// the fourth equal one is rejected (see the module documentation for the choice).
pub const STUCK_SAMPLES: u8 = 4;

/// Equal consecutive gyro readings (its three axes, bit for bit) that make the gyro stuck
/// however the accelerometer moves (see the module documentation for the choice).
pub const GYRO_STUCK_SAMPLES: u8 = 11;

/// Equal consecutive accelerometer readings (its three axes, bit for bit) that make it stuck
/// however the gyro moves.
pub const ACCEL_STUCK_SAMPLES: u8 = 5;

/// Counts how many times in a row a reading has repeated bit for bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Repeats<const N: usize> {
    last: Option<[i16; N]>,
    repeats: u8,
}

impl<const N: usize> Repeats<N> {
    const NEW: Self = Self {
        last: None,
        repeats: 0,
    };

    /// Takes `reading`; true when it is the `samples`-th equal one in a row or later.
    fn stuck(&mut self, reading: [i16; N], samples: u8) -> bool {
        if self.last == Some(reading) {
            self.repeats = self.repeats.saturating_add(1);
        } else {
            self.repeats = 0;
            self.last = Some(reading);
        }
        self.repeats.saturating_add(1) >= samples
    }
}

/// The 14 data bytes as words.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawSample {
    /// Accelerometer x, y, z (chip axes), LSB.
    pub accel: [i16; 3],
    /// Temperature, LSB.
    pub temperature: i16,
    /// Gyro x, y, z (chip axes), LSB.
    pub gyro: [i16; 3],
}

impl RawSample {
    /// From the burst read starting at `ACCEL_XOUT_H`.
    pub fn from_bytes(b: &[u8; 14]) -> Self {
        let w = |i: usize| i16::from_be_bytes([b[2 * i], b[2 * i + 1]]);
        Self {
            accel: [w(0), w(1), w(2)],
            temperature: w(3),
            gyro: [w(4), w(5), w(6)],
        }
    }

    fn axes(&self) -> [i16; 6] {
        [
            self.accel[0],
            self.accel[1],
            self.accel[2],
            self.gyro[0],
            self.gyro[1],
            self.gyro[2],
        ]
    }
}

/// Why a sample was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleFault {
    /// The SPI transfer failed.
    Bus,
    /// `WHO_AM_I` read something else (the value).
    NotIdentified(u8),
    /// `PWR_MGMT_1` shows the sensor asleep or on another clock (the value).
    NotAwake(u8),
    /// All data bytes 0x00.
    AllZero,
    /// All data bytes 0xFF.
    AllOnes,
    /// An axis at full scale.
    FullScale,
    /// The same sample [`STUCK_SAMPLES`] times in a row, or the same gyro reading
    /// [`GYRO_STUCK_SAMPLES`] times, or the same accelerometer reading
    /// [`ACCEL_STUCK_SAMPLES`] times.
    Stuck,
}

/// Rejected samples since boot, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FaultCounts {
    /// SPI failures.
    pub bus: u32,
    /// Wrong `WHO_AM_I`.
    pub not_identified: u32,
    /// Asleep or reset.
    pub not_awake: u32,
    /// All 0x00 or all 0xFF.
    pub dead_bus: u32,
    /// At full scale.
    pub full_scale: u32,
    /// Stuck.
    pub stuck: u32,
}

impl FaultCounts {
    /// Every rejected sample.
    pub fn total(&self) -> u32 {
        self.bus
            .wrapping_add(self.not_identified)
            .wrapping_add(self.not_awake)
            .wrapping_add(self.dead_bus)
            .wrapping_add(self.full_scale)
            .wrapping_add(self.stuck)
    }

    /// Counts one fault.
    pub fn count(&mut self, fault: SampleFault) {
        let c = match fault {
            SampleFault::Bus => &mut self.bus,
            SampleFault::NotIdentified(_) => &mut self.not_identified,
            SampleFault::NotAwake(_) => &mut self.not_awake,
            SampleFault::AllZero | SampleFault::AllOnes => &mut self.dead_bus,
            SampleFault::FullScale => &mut self.full_scale,
            SampleFault::Stuck => &mut self.stuck,
        };
        *c = c.wrapping_add(1);
    }
}

/// The validity checks over consecutive samples, and the conversion to the body frame.
#[derive(Debug, Clone)]
pub struct SampleCheck {
    axes: AxisMap,
    mounting: Mounting,
    all: Repeats<6>,
    gyro: Repeats<3>,
    accel: Repeats<3>,
    faults: FaultCounts,
}

impl SampleCheck {
    /// Checks for a sensor whose chip axes map to the board by `axes`, on a board mounted in
    /// the airframe by `mounting`.
    pub fn new(axes: AxisMap, mounting: Mounting) -> Self {
        Self {
            axes,
            mounting,
            all: Repeats::NEW,
            gyro: Repeats::NEW,
            accel: Repeats::NEW,
            faults: FaultCounts::default(),
        }
    }

    /// Rejected samples so far.
    pub fn faults(&self) -> FaultCounts {
        self.faults
    }

    /// Counts a failed transfer (the caller could not read the sensor at all).
    pub fn bus_error(&mut self) -> SampleFault {
        self.faults.count(SampleFault::Bus);
        SampleFault::Bus
    }

    /// Checks one control step's reads: `who_am_i` and `pwr_mgmt_1` (each read in the step)
    /// and the 14 data bytes. A valid sample comes back in SI units in the body frame (x
    /// forward, y right, z down), stamped `timestamp`.
    pub fn check(
        &mut self,
        who_am_i: u8,
        pwr_mgmt_1: u8,
        data: &[u8; 14],
        timestamp: WireTime,
    ) -> Result<ImuSample, SampleFault> {
        let verdict = self.verdict(who_am_i, pwr_mgmt_1, data);
        match verdict {
            Ok(raw) => Ok(self.to_body(&raw, timestamp)),
            Err(fault) => {
                self.faults.count(fault);
                Err(fault)
            }
        }
    }

    fn verdict(
        &mut self,
        who_am_i: u8,
        pwr_mgmt_1: u8,
        data: &[u8; 14],
    ) -> Result<RawSample, SampleFault> {
        if who_am_i != WHO_AM_I_VALUE {
            return Err(SampleFault::NotIdentified(who_am_i));
        }
        if pwr_mgmt_1 != PWR_MGMT_1_RUN {
            return Err(SampleFault::NotAwake(pwr_mgmt_1));
        }
        if data.iter().all(|&b| b == 0x00) {
            return Err(SampleFault::AllZero);
        }
        if data.iter().all(|&b| b == 0xFF) {
            return Err(SampleFault::AllOnes);
        }
        let raw = RawSample::from_bytes(data);
        let axes = raw.axes();
        // Stuck is judged before full scale, so a sensor frozen at a bound counts as stuck too.
        let all = self.all.stuck(axes, STUCK_SAMPLES);
        let gyro = self.gyro.stuck(raw.gyro, GYRO_STUCK_SAMPLES);
        let accel = self.accel.stuck(raw.accel, ACCEL_STUCK_SAMPLES);
        if all || gyro || accel {
            return Err(SampleFault::Stuck);
        }
        if axes.iter().any(|&a| a == i16::MAX || a == i16::MIN) {
            return Err(SampleFault::FullScale);
        }
        Ok(raw)
    }

    /// A raw sample in SI units, chip axes -> board axes -> body axes.
    pub fn to_body(&self, raw: &RawSample, timestamp: WireTime) -> ImuSample {
        let chip_gyro = raw.gyro.map(|v| f32::from(v) * GYRO_RADPS_PER_LSB);
        let chip_accel = raw.accel.map(|v| f32::from(v) * ACCEL_MPS2_PER_LSB);
        ImuSample {
            timestamp_us: timestamp,
            gyro_radps: self.mounting.board_to_body(self.axes.apply(chip_gyro)),
            accel_mps2: self.mounting.board_to_body(self.axes.apply(chip_accel)),
        }
    }
}

/// The longest time from the IMU failing (frozen, unplugged, asleep, gone) to every motor at 0,
/// with the failsafe timings `failsafe`: a frozen sensor's samples still pass for
/// [`STUCK_SAMPLES`] - 1 loop periods, then no valid sample for the failsafe's
/// `imu_timeout`, then the loop period whose check turns the motors off.
pub fn fault_motors_off(failsafe: &crate::failsafe::FailsafeConfig) -> Duration {
    // The loop period rounded up.
    let period =
        Duration::from_micros(1_000_000u64.div_ceil(u64::from(crate::board::LOOP_RATE_HZ)));
    failsafe.imu_timeout + period.saturating_mul(u64::from(STUCK_SAMPLES))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::IMU_AXES;
    use crate::test_support::at;

    /// The 14 data bytes for the given chip-axis words (temperature fixed).
    fn bytes(accel: [i16; 3], gyro: [i16; 3]) -> [u8; 14] {
        let words = [
            accel[0], accel[1], accel[2], 1500, gyro[0], gyro[1], gyro[2],
        ];
        let mut b = [0u8; 14];
        for (i, w) in words.iter().enumerate() {
            b[2 * i..2 * i + 2].copy_from_slice(&w.to_be_bytes());
        }
        b
    }

    fn check() -> SampleCheck {
        SampleCheck::new(IMU_AXES, Mounting::IDENTITY)
    }

    #[test]
    fn a_noisy_sensor_at_rest_is_valid_and_in_the_body_frame() {
        let mut c = check();
        // Specific force at rest is -1 g along the downward z axis: -4096 LSB on chip z.
        for k in 0..100i16 {
            let s = c
                .check(
                    0x68,
                    0x03,
                    &bytes([k % 3, -(k % 5), -4096 + k % 7], [k % 2, 1, -1]),
                    WireTime(7),
                )
                .expect("valid");
            assert!((s.accel_mps2[2] + 9.8).abs() < 0.1, "{s:?}");
            assert_eq!(s.timestamp_us, WireTime(7));
        }
        assert_eq!(c.faults().total(), 0);
    }

    #[test]
    fn chip_axes_map_to_the_board_as_paparazzi_does() {
        let c = check();
        // A positive rate about chip x is a positive rate about board y; about chip y, a
        // negative rate about board x.
        let s = c.to_body(
            &RawSample {
                accel: [0; 3],
                temperature: 0,
                gyro: [164, 328, 0],
            },
            WireTime(0),
        );
        let deg = 180.0 / core::f32::consts::PI;
        assert!((s.gyro_radps[0] * deg + 20.0).abs() < 1e-3, "{s:?}");
        assert!((s.gyro_radps[1] * deg - 10.0).abs() < 1e-3, "{s:?}");
    }

    #[test]
    fn identity_power_and_dead_bus_faults_are_rejected_and_counted() {
        let mut c = check();
        let good = bytes([10, 20, -4000], [1, 2, 3]);
        assert_eq!(
            c.check(0x00, 0x03, &good, WireTime(0)),
            Err(SampleFault::NotIdentified(0))
        );
        assert_eq!(
            c.check(0xFF, 0x03, &good, WireTime(0)),
            Err(SampleFault::NotIdentified(0xFF))
        );
        // Asleep after a brown-out reset: SLEEP set, internal oscillator.
        assert_eq!(
            c.check(0x68, PWR_MGMT_1_SLEEP, &good, WireTime(0)),
            Err(SampleFault::NotAwake(0x40))
        );
        assert_eq!(
            c.check(0x68, 0x03, &[0; 14], WireTime(0)),
            Err(SampleFault::AllZero)
        );
        assert_eq!(
            c.check(0x68, 0x03, &[0xFF; 14], WireTime(0)),
            Err(SampleFault::AllOnes)
        );
        let f = c.faults();
        assert_eq!((f.not_identified, f.not_awake, f.dead_bus), (2, 1, 2));
    }

    #[test]
    fn a_reset_sensor_is_configured_again_at_most_once_per_interval() {
        let mut r = Reconfigure::new();
        let mut c = check();
        let good = bytes([10, 20, -4000], [1, 2, 3]);
        // Power-on defaults after a brown-out: asleep, internal oscillator, data registers 0.
        let fault = c.check(0x68, 0x40, &[0; 14], WireTime(0)).unwrap_err();
        assert!(r.due(fault, at(1_000)));
        // Still asleep at the next steps: not written again before the interval.
        assert!(!r.due(fault, at(1_000 + 1_953)));
        assert!(!r.due(fault, at(1_000 + RECONFIGURE_INTERVAL.as_micros() - 1)));
        assert!(r.due(fault, at(1_000 + RECONFIGURE_INTERVAL.as_micros())));
        assert_eq!(r.count(), 2);
        // Mid-reset (DEVICE_RESET still set), another chip, a dead bus, a frozen sensor: no
        // register write cures those.
        for fault in [
            SampleFault::NotAwake(0xC0),
            SampleFault::NotIdentified(0x00),
            SampleFault::AllOnes,
            SampleFault::Stuck,
            SampleFault::Bus,
        ] {
            assert!(!r.due(fault, at(10_000_000)), "{fault:?}");
        }
        assert_eq!(r.count(), 2);
        // Awake on the internal oscillator (CLKSEL 0) is not the configured state either.
        assert!(r.due(SampleFault::NotAwake(0x00), at(20_000_000)));
        // Configured again: valid.
        assert!(c.check(0x68, PWR_MGMT_1_RUN, &good, WireTime(0)).is_ok());
    }

    #[test]
    fn the_read_back_configuration_must_be_the_one_written() {
        assert!(config_matches([0x01, 0x18, 0x10]));
        // Reset defaults (register map section 3), and one register lost.
        assert!(!config_matches([0x00, 0x00, 0x00]));
        assert!(!config_matches([0x01, 0x00, 0x10]));
        assert!(!config_matches([0x01, 0x18, 0x00]));
    }

    #[test]
    fn full_scale_is_rejected() {
        let mut c = check();
        for bad in [
            bytes([i16::MAX, 0, -4096], [1, 2, 3]),
            bytes([1, 0, -4096], [1, i16::MIN, 3]),
        ] {
            assert_eq!(
                c.check(0x68, 0x03, &bad, WireTime(0)),
                Err(SampleFault::FullScale)
            );
        }
        assert_eq!(c.faults().full_scale, 2);
    }

    #[test]
    fn the_fourth_equal_sample_in_a_row_is_stuck_and_a_new_value_recovers() {
        let mut c = check();
        let frozen = bytes([12, -7, -4090], [3, -2, 1]);
        for _ in 1..STUCK_SAMPLES {
            assert!(c.check(0x68, 0x03, &frozen, WireTime(0)).is_ok());
        }
        for _ in 0..10 {
            assert_eq!(
                c.check(0x68, 0x03, &frozen, WireTime(0)),
                Err(SampleFault::Stuck)
            );
        }
        assert_eq!(c.faults().stuck, 10);
        // A different temperature alone does not unfreeze it: only the axes count.
        let mut same_axes = frozen;
        same_axes[6] ^= 1;
        assert_eq!(
            c.check(0x68, 0x03, &same_axes, WireTime(0)),
            Err(SampleFault::Stuck)
        );
        // Both sensors must move again: a new accelerometer value beside the same gyro
        // reading leaves the gyro frozen.
        assert!(c
            .check(0x68, 0x03, &bytes([13, -7, -4090], [4, -2, 1]), WireTime(0))
            .is_ok());
    }

    /// Bytes whose gyro axes change with `k` and whose accelerometer stays `accel`, or the
    /// other way round.
    fn moving(k: i16, accel: Option<[i16; 3]>, gyro: Option<[i16; 3]>) -> [u8; 14] {
        bytes(
            accel.unwrap_or([12 + k, -7, -4090]),
            gyro.unwrap_or([3, -2 + k, 1]),
        )
    }

    #[test]
    fn a_gyro_frozen_alone_is_stuck_while_the_accelerometer_lives() {
        let mut c = check();
        let frozen_gyro = Some([5, -9, 2]);
        for k in 1..GYRO_STUCK_SAMPLES {
            assert!(c
                .check(
                    0x68,
                    0x03,
                    &moving(k as i16, None, frozen_gyro),
                    WireTime(0)
                )
                .is_ok());
        }
        assert_eq!(
            c.check(0x68, 0x03, &moving(99, None, frozen_gyro), WireTime(0)),
            Err(SampleFault::Stuck)
        );
        assert!(c
            .check(0x68, 0x03, &moving(100, None, None), WireTime(0))
            .is_ok());
    }

    #[test]
    fn an_accelerometer_frozen_alone_is_stuck_while_the_gyro_lives() {
        let mut c = check();
        let frozen_accel = Some([100, 200, -4000]);
        for k in 1..ACCEL_STUCK_SAMPLES {
            assert!(c
                .check(
                    0x68,
                    0x03,
                    &moving(k as i16, frozen_accel, None),
                    WireTime(0)
                )
                .is_ok());
        }
        assert_eq!(
            c.check(0x68, 0x03, &moving(50, frozen_accel, None), WireTime(0)),
            Err(SampleFault::Stuck)
        );
        assert_eq!(c.faults().stuck, 1);
    }
}
