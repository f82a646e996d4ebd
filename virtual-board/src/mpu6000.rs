//! The InvenSense MPU-6000 six-axis IMU on SPI, as its register map (RM-MPU-6000A-00 rev 4.2,
//! "RM") and product specification (PS-MPU-6000A-00 rev 3.4, "PS") give it.
//!
//! | What | Behaviour | Source |
//! |---|---|---|
//! | SPI framing | first byte: bit 7 read (1) / write (0), bits 6:0 the register; then data, the address incrementing; a deselect ends the burst | PS 6.5, 7.5 |
//! | SPI mode and clock | mode 0 or 3 only, SCLK at most 1 MHz for every register and 20 MHz for reading the sensor and interrupt registers: the board says how the controller drives the bus ([`Mpu6000::set_bus`]); a write at over 1 MHz, or any word in the wrong mode, is not taken (the chip samples the wrong bits) | PS 6.5 table, 7.5 |
//! | `WHO_AM_I` (0x75) | 0x68 | RM 4.32 |
//! | `PWR_MGMT_1` (0x6B) | resets to 0x40 (`SLEEP`); `DEVICE_RESET` (bit 7) puts every register back at its reset value and clears itself; asleep, the sensor registers hold their last values | RM 4.28, PS 6.5 |
//! | reset | `DEVICE_RESET` or a supply reset ([`Mpu6000::power_reset`], a brown-out): every register at its reset value (RM section 3: 0x00, `PWR_MGMT_1` 0x40, `WHO_AM_I` 0x68), asleep; for the reset time, the 100 ms RM 4.28 asks the host to wait, the chip takes no write and MISO reads 0x00 (nothing drives it; the model's choice of level) | RM 3, 4.28 |
//! | `SMPLRT_DIV` (0x19), `CONFIG` (0x1A) | sample rate = gyro output rate / (1 + divider); the gyro output rate is 8 kHz with `DLPF_CFG` 0 or 7, else 1 kHz; `DLPF_CFG` sets the noise bandwidth (gyro 256, 188, 98, 42, 20, 10, 5 Hz) | RM 4.2, 4.3 |
//! | `GYRO_CONFIG` (0x1B), `ACCEL_CONFIG` (0x1C) | full scale +-250/500/1000/2000 deg/s = 131/65.5/32.8/16.4 LSB per deg/s; +-2/4/8/16 g = 16384/8192/4096/2048 LSB/g; outputs saturate at the 16-bit limits | RM 4.4, 4.5, PS 6.1, 6.2 |
//! | `INT_ENABLE` (0x38), `INT_STATUS` (0x3A) | `DATA_RDY_INT` set at each new sample, cleared by reading `INT_STATUS`; the INT output ([`Mpu6000::data_ready`]) is high while it is set and enabled | RM 4.15, 4.16, 4.14 |
//! | sensor registers 0x3B-0x48 | accelerometer, temperature (340 LSB/degC, 36.53 degC at 0), gyroscope, big-endian, one consistent sample per burst | RM 4.17-4.19 |
//! | start-up | first sample 30 ms after waking (gyro start-up time) | PS 6.1 |
//! | noise | white, rate noise density 0.005 deg/s/sqrt(Hz) and accelerometer 400 ug/sqrt(Hz) over the DLPF bandwidth, drawn from a seeded generator per sample; a fixed zero-rate offset per device (`seed`), well inside the +-20 deg/s tolerance | PS 6.1, 6.2 |
//!
//! Faults a test can set: [`Mpu6000::set_unplugged`] (MISO pulled high: every byte 0xFF),
//! [`Mpu6000::set_frozen`] (the sensor registers stop updating), [`Mpu6000::power_reset`] (a
//! brown-out or ESD reset).
//!
//! Left out: the FIFO, the DMP, the I2C master and auxiliary bus, self-test, the motion and
//! free-fall detectors, and the 8 kHz gyro / 1 kHz accelerometer distinction (both sampled at
//! the sample rate).

use rigless::chip::Timeline;
use rigless::chip::spi::Peer;
use rigless::snapshot::Store;

/// `WHO_AM_I`'s value.
pub const WHO_AM_I: u8 = 0x68;
/// Registers the model keeps (RM section 3).
const REGISTERS: usize = 0x80;
const SMPLRT_DIV: usize = 0x19;
const CONFIG: usize = 0x1A;
const GYRO_CONFIG: usize = 0x1B;
const ACCEL_CONFIG: usize = 0x1C;
const INT_ENABLE: usize = 0x38;
const INT_STATUS: usize = 0x3A;
const ACCEL_XOUT_H: usize = 0x3B;
const GYRO_ZOUT_L: usize = 0x48;
const PWR_MGMT_1: usize = 0x6B;
const WHO_AM_I_REG: usize = 0x75;
const SLEEP: u8 = 0x40;
const DEVICE_RESET: u8 = 0x80;
/// PS 6.1: gyroscope start-up time, ns.
const START_UP_NS: u64 = 30_000_000;
/// RM 4.28: the wait after a reset before the chip is accessed, ns.
pub const RESET_TIME_NS: u64 = 100_000_000;
/// PS 6.5: SCLK limits, Hz.
const SCLK_ALL_MAX_HZ: u64 = 1_000_000;
const SCLK_SENSOR_MAX_HZ: u64 = 20_000_000;
/// Standard gravity, m/s^2.
const G: f64 = 9.806_65;

/// How the SPI controller drives the bus, as the board reads it off the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Bus {
    /// Clock polarity and phase are mode 0 or mode 3.
    pub mode_ok: bool,
    /// SCLK, Hz.
    pub sclk_hz: u64,
}

/// One MPU-6000.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub struct Mpu6000 {
    regs: Vec<u8>,
    address: Option<u8>,
    read: bool,
    /// Angular rate in chip axes, rad/s.
    rate: [f64; 3],
    /// Specific force in chip axes (what the accelerometer measures), m/s^2.
    accel: [f64; 3],
    /// Die temperature, degC.
    temperature: f64,
    seed: u64,
    /// Zero-rate offset, rad/s.
    bias: [f64; 3],
    /// When the chip last woke (left sleep), ns; `None` while asleep.
    awake_since: Option<u64>,
    /// The end of the reset in progress, ns: until then the chip does not answer.
    resetting_until: Option<u64>,
    /// Resets since power-up (`DEVICE_RESET` and supply resets).
    resets: u32,
    /// The index of the sample in the sensor registers.
    sample: Option<u64>,
    /// The sample `INT_STATUS` was last read at.
    status_read_at: Option<u64>,
    bus: Bus,
    unplugged: bool,
    frozen: bool,
    /// Transfers refused because of the bus (wrong mode, too fast a write).
    refused: u64,
    /// Bytes exchanged.
    transfers: u64,
    /// Instants (ns) of the read bursts that began at a sensor register, and the sample each
    /// showed, oldest first (the firmware's IMU reads).
    sensor_reads: Vec<(u64, Option<u64>)>,
}

impl Store for Mpu6000 {}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// A standard normal draw keyed by `seed` and `index` (Box-Muller).
fn normal(seed: u64, index: u64) -> f64 {
    let a = splitmix(seed ^ splitmix(index));
    let b = splitmix(a);
    let u1 = ((a >> 11) as f64 + 1.0) / (1u64 << 53) as f64;
    let u2 = (b >> 11) as f64 / (1u64 << 53) as f64;
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

impl Mpu6000 {
    /// A chip out of power-on reset, level and still at 25 degC, its noise and offset drawn from
    /// `seed`.
    #[must_use]
    pub fn new(seed: u64) -> Self {
        let bias = std::array::from_fn(|axis| {
            // A zero-rate offset of up to about 1 deg/s.
            (normal(seed, 1_000 + axis as u64) * 0.5).to_radians()
        });
        let mut chip = Self {
            regs: vec![0; REGISTERS],
            address: None,
            read: false,
            rate: [0.0; 3],
            accel: [0.0, 0.0, G],
            temperature: 25.0,
            seed,
            bias,
            awake_since: None,
            resetting_until: None,
            resets: 0,
            sample: None,
            status_read_at: None,
            bus: Bus {
                mode_ok: true,
                sclk_hz: SCLK_ALL_MAX_HZ,
            },
            unplugged: false,
            frozen: false,
            refused: 0,
            transfers: 0,
            sensor_reads: Vec::new(),
        };
        chip.power_on_reset();
        chip
    }

    fn power_on_reset(&mut self) {
        self.regs.iter_mut().for_each(|r| *r = 0);
        self.regs[PWR_MGMT_1] = SLEEP;
        self.regs[WHO_AM_I_REG] = WHO_AM_I;
        self.awake_since = None;
        self.sample = None;
        self.status_read_at = None;
    }

    /// A reset at `now_ns` as by `DEVICE_RESET` (register defaults, asleep), the chip not
    /// answering for [`RESET_TIME_NS`].
    fn reset(&mut self, now_ns: u64) {
        self.power_on_reset();
        self.resetting_until = Some(now_ns.saturating_add(RESET_TIME_NS));
        self.resets = self.resets.saturating_add(1);
    }

    /// The supply dropped out and came back at `now_ns` (a brown-out, an ESD event): the chip
    /// resets as at power-on, every register at its reset value, asleep, and does not answer
    /// for [`RESET_TIME_NS`].
    pub fn power_reset(&mut self, now_ns: u64) {
        self.reset(now_ns);
    }

    /// Resets since power-up.
    #[must_use]
    pub fn resets(&self) -> u32 {
        self.resets
    }

    /// The angular rate the chip senses, in its own axes, rad/s.
    pub fn set_rate(&mut self, rate: [f64; 3]) {
        self.rate = rate;
    }

    /// The specific force the chip senses (gravity's reaction included), its axes, m/s^2.
    pub fn set_accel(&mut self, accel: [f64; 3]) {
        self.accel = accel;
    }

    /// Die temperature, degC.
    pub fn set_temperature(&mut self, celsius: f64) {
        self.temperature = celsius;
    }

    /// How the controller drives the bus now.
    pub fn set_bus(&mut self, bus: Bus) {
        self.bus = bus;
    }

    /// Unplugged: nothing drives MISO, which reads all ones; writes go nowhere.
    pub fn set_unplugged(&mut self, unplugged: bool) {
        self.unplugged = unplugged;
    }

    /// Frozen: the sensor registers keep the sample they hold.
    pub fn set_frozen(&mut self, frozen: bool) {
        self.frozen = frozen;
    }

    /// Whether the chip is awake (not in sleep).
    #[must_use]
    pub fn awake(&self) -> bool {
        self.regs[PWR_MGMT_1] & SLEEP == 0
    }

    /// Samples the firmware has had a chance to read: the index of the latest one shown.
    #[must_use]
    pub fn sample_index(&self) -> Option<u64> {
        self.sample
    }

    /// The firmware's sensor reads: (instant ns, index of the sample it saw), oldest first.
    #[must_use]
    pub fn sensor_reads(&self) -> &[(u64, Option<u64>)] {
        &self.sensor_reads
    }

    /// Bytes exchanged over SPI.
    #[must_use]
    pub fn transfers(&self) -> u64 {
        self.transfers
    }

    /// Words not taken because the controller drove the bus in the wrong mode or too fast.
    #[must_use]
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// A register's value, for a test's look.
    #[must_use]
    pub fn register(&self, address: u8) -> u8 {
        self.regs[usize::from(address & 0x7F)]
    }

    /// The sample period, ns.
    #[must_use]
    pub fn sample_period_ns(&self) -> u64 {
        let dlpf = self.regs[CONFIG] & 0x07;
        let output_hz: u64 = if dlpf == 0 || dlpf == 7 { 8_000 } else { 1_000 };
        1_000_000_000 * (1 + u64::from(self.regs[SMPLRT_DIV])) / output_hz
    }

    /// The noise bandwidth of the DLPF setting, Hz (RM 4.3, gyroscope column).
    fn bandwidth_hz(&self) -> f64 {
        match self.regs[CONFIG] & 0x07 {
            0 | 7 => 256.0,
            1 => 188.0,
            2 => 98.0,
            3 => 42.0,
            4 => 20.0,
            5 => 10.0,
            _ => 5.0,
        }
    }

    /// The INT output: high while a data-ready interrupt is pending and enabled.
    #[must_use]
    pub fn data_ready(&self, now_ns: u64) -> bool {
        self.regs[INT_ENABLE] & 1 != 0 && self.latest_sample(now_ns) != self.status_read_at
    }

    fn latest_sample(&self, now_ns: u64) -> Option<u64> {
        let since = self.awake_since?;
        let first = since + START_UP_NS;
        if now_ns < first || !self.awake() {
            return None;
        }
        Some((now_ns - first) / self.sample_period_ns())
    }

    /// Brings the sensor registers up to the sample due at `now_ns`.
    fn update(&mut self, now_ns: u64) {
        if self.frozen {
            return;
        }
        let Some(index) = self.latest_sample(now_ns) else {
            return;
        };
        if self.sample == Some(index) {
            return;
        }
        self.sample = Some(index);
        let bandwidth = self.bandwidth_hz().sqrt();
        let gyro_lsb = 131.0 / f64::from(1u32 << ((self.regs[GYRO_CONFIG] >> 3) & 3));
        let accel_lsb = 16_384.0 / f64::from(1u32 << ((self.regs[ACCEL_CONFIG] >> 3) & 3));
        let gyro_noise = 0.005 * bandwidth; // deg/s rms
        let accel_noise = 400e-6 * bandwidth; // g rms
        let key = self.seed.wrapping_mul(0x1000_0000_01B3);
        let word = |value: f64| -> [u8; 2] {
            let clamped = value
                .round()
                .clamp(f64::from(i16::MIN), f64::from(i16::MAX));
            (clamped as i16).to_be_bytes()
        };
        for axis in 0..3 {
            let n = index * 8 + axis as u64;
            let g = self.accel[axis] / G + accel_noise * normal(key, n);
            let [h, l] = word(g * accel_lsb);
            self.regs[ACCEL_XOUT_H + 2 * axis] = h;
            self.regs[ACCEL_XOUT_H + 2 * axis + 1] = l;
            let deg =
                (self.rate[axis] + self.bias[axis]).to_degrees() + gyro_noise * normal(key, n + 3);
            let [h, l] = word(deg * gyro_lsb);
            self.regs[0x43 + 2 * axis] = h;
            self.regs[0x43 + 2 * axis + 1] = l;
        }
        let [h, l] = word((self.temperature - 36.53) * 340.0 + 0.5 * normal(key, index * 8 + 6));
        self.regs[0x41] = h;
        self.regs[0x42] = l;
    }

    fn write_register(&mut self, address: usize, value: u8, now_ns: u64) {
        match address {
            PWR_MGMT_1 => {
                if value & DEVICE_RESET != 0 {
                    self.reset(now_ns);
                    return;
                }
                let was_awake = self.awake();
                self.regs[PWR_MGMT_1] = value;
                if !was_awake && self.awake() {
                    self.awake_since = Some(now_ns);
                    self.sample = None;
                } else if !self.awake() {
                    self.awake_since = None;
                }
            }
            // Read-only: the sensor and status registers and WHO_AM_I.
            INT_STATUS | ACCEL_XOUT_H..=GYRO_ZOUT_L | WHO_AM_I_REG => {}
            _ => self.regs[address] = value,
        }
    }
}

impl Peer for Mpu6000 {
    fn transfer(&mut self, mosi: u32, _bits: u8, context: &mut Timeline<'_, '_>) -> u32 {
        self.transfers += 1;
        if self.unplugged {
            return 0xFF;
        }
        if !self.bus.mode_ok {
            self.refused += 1;
            // Sampling on the wrong edge: the chip sees the bits shifted by one, answers them so.
            return 0xFF;
        }
        let now = context.now().0;
        if let Some(until) = self.resetting_until {
            if now < until {
                return 0x00;
            }
            self.resetting_until = None;
        }
        let byte = (mosi & 0xFF) as u8;
        let Some(address) = self.address else {
            self.address = Some(byte & 0x7F);
            self.read = byte & 0x80 != 0;
            if self.read {
                // A burst reads one consistent sample (RM 4.17: the registers are shadowed
                // while the serial interface is active).
                self.update(now);
                let first = usize::from(byte & 0x7F);
                if (ACCEL_XOUT_H..=GYRO_ZOUT_L).contains(&first)
                    && self.sensor_reads.len() < 1 << 20
                {
                    self.sensor_reads.push((now, self.sample));
                }
            }
            return 0;
        };
        let register = usize::from(address);
        let sensor = (ACCEL_XOUT_H..=GYRO_ZOUT_L).contains(&register) || register == INT_STATUS;
        let limit = if self.read && sensor {
            SCLK_SENSOR_MAX_HZ
        } else {
            SCLK_ALL_MAX_HZ
        };
        if self.bus.sclk_hz > limit {
            self.refused += 1;
            self.address = Some((address + 1) & 0x7F);
            return 0xFF;
        }
        let out = self.regs[register];
        if self.read {
            if register == INT_STATUS {
                let latest = self.latest_sample(now);
                let pending = latest.is_some() && latest != self.status_read_at;
                self.status_read_at = latest;
                self.address = Some((address + 1) & 0x7F);
                return u32::from(pending);
            }
        } else {
            self.write_register(register, byte, now);
        }
        self.address = Some((address + 1) & 0x7F);
        u32::from(out)
    }

    fn select(&mut self, _context: &mut Timeline<'_, '_>) {
        self.address = None;
    }

    fn deselect(&mut self, _context: &mut Timeline<'_, '_>) {
        self.address = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_noise_is_standard_normal() {
        let n = 20_000;
        let draws: Vec<f64> = (0..n).map(|i| normal(7, i)).collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(mean.abs() < 0.03, "mean {mean}");
        assert!((var - 1.0).abs() < 0.05, "variance {var}");
    }

    #[test]
    fn the_sample_rate_follows_the_divider_and_the_filter() {
        let mut chip = Mpu6000::new(1);
        assert_eq!(chip.sample_period_ns(), 125_000);
        chip.regs[CONFIG] = 3;
        chip.regs[SMPLRT_DIV] = 1;
        assert_eq!(chip.sample_period_ns(), 2_000_000);
    }

    #[test]
    fn a_sleeping_chip_shows_no_samples_and_a_woken_one_after_start_up() {
        let mut chip = Mpu6000::new(1);
        chip.update(50_000_000);
        assert_eq!(chip.sample, None);
        chip.write_register(PWR_MGMT_1, 0x03, 1_000_000);
        chip.update(20_000_000);
        assert_eq!(chip.sample, None, "still starting up");
        chip.update(40_000_000);
        assert!(chip.sample.is_some());
        assert_ne!(chip.regs[ACCEL_XOUT_H + 4], 0, "1 g on z");
    }

    #[test]
    fn a_rate_reads_at_the_configured_scale() {
        let mut chip = Mpu6000::new(3);
        chip.write_register(GYRO_CONFIG, 3 << 3, 0); // +-2000 deg/s
        chip.write_register(PWR_MGMT_1, 0x03, 0);
        chip.set_rate([0.0, 0.0, 1.0]); // 57.3 deg/s about z
        chip.update(100_000_000);
        let z = i16::from_be_bytes([chip.regs[0x47], chip.regs[0x48]]);
        let expected = 1f64.to_degrees() * 16.4;
        assert!((f64::from(z) - expected).abs() < 40.0, "{z} vs {expected}");
    }

    #[test]
    fn a_device_reset_puts_the_chip_to_sleep_with_its_registers_at_reset() {
        let mut chip = Mpu6000::new(3);
        chip.write_register(GYRO_CONFIG, 0x18, 0);
        chip.write_register(PWR_MGMT_1, 0x01, 0);
        chip.write_register(PWR_MGMT_1, DEVICE_RESET, 10);
        assert_eq!(chip.regs[GYRO_CONFIG], 0);
        assert_eq!(chip.regs[PWR_MGMT_1], SLEEP);
        assert_eq!(chip.regs[WHO_AM_I_REG], WHO_AM_I);
        assert_eq!(chip.resetting_until, Some(10 + RESET_TIME_NS));
    }

    #[test]
    fn a_power_reset_in_flight_stops_the_samples_until_the_chip_is_woken_again() {
        let mut chip = Mpu6000::new(5);
        chip.write_register(GYRO_CONFIG, 0x18, 0);
        chip.write_register(PWR_MGMT_1, 0x03, 0);
        chip.update(100_000_000);
        let before = chip.sample.expect("sampling");
        chip.power_reset(200_000_000);
        assert_eq!(chip.resets(), 1);
        assert!(!chip.awake());
        assert_eq!(chip.regs[GYRO_CONFIG], 0, "the configuration is lost");
        assert_eq!(
            chip.regs[ACCEL_XOUT_H + 4],
            0,
            "the data registers are at reset"
        );
        chip.update(400_000_000);
        assert_eq!(chip.sample, None, "asleep: no new sample");
        // Woken again: samples after the start-up time, from index 0.
        chip.write_register(PWR_MGMT_1, 0x03, 400_000_000);
        chip.update(400_000_000 + START_UP_NS + 1_000_000);
        assert!(chip.sample.is_some_and(|s| s < before));
    }
}
