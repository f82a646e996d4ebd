//! MPU-6000 over SPI: configuration and one burst read per control step.
//!
//! The sensor runs its gyro and accelerometer at 1 kHz behind the 188 Hz low-pass filter;
//! the 512 Hz control loop is paced by a timer and reads the newest sample in one 14-byte
//! burst (a fixed-rate loop needs no data-ready line; a stale or failed read is simply
//! skipped and the autopilot's IMU-stale failsafe watches the rate).
//!
//! Axes: the chip's x forward, y left, z up on the board; the body frame is x forward,
//! y right, z down, so y and z change sign.

use embedded_hal::digital::OutputPin;
use embedded_hal::spi::SpiBus;
use protocol::ImuSample;

const PWR_MGMT_1: u8 = 0x6B;
const USER_CTRL: u8 = 0x6A;
const SMPLRT_DIV: u8 = 0x19;
const CONFIG: u8 = 0x1A;
const GYRO_CONFIG: u8 = 0x1B;
const ACCEL_CONFIG: u8 = 0x1C;
const ACCEL_XOUT_H: u8 = 0x3B;
const WHO_AM_I: u8 = 0x75;
const INT_PIN_CFG: u8 = 0x37;
const INT_ENABLE: u8 = 0x38;
const READ: u8 = 0x80;

/// Gyro scale at ±2000 °/s: 16.4 LSB per °/s, in rad/s per LSB.
const GYRO_RADPS_PER_LSB: f32 = core::f32::consts::PI / 180.0 / 16.4;
/// Accelerometer scale at ±8 g: 4096 LSB per g, in m/s² per LSB.
const ACCEL_MPS2_PER_LSB: f32 = 9.806_65 / 4096.0;

/// Why the IMU could not be used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImuError {
    /// SPI or chip-select failure.
    Bus,
    /// `WHO_AM_I` did not read 0x68.
    NotFound(u8),
}

/// An MPU-6000 on an SPI bus with its chip-select pin.
pub struct Mpu6000<S, CS> {
    spi: S,
    cs: CS,
}

impl<S: SpiBus, CS: OutputPin> Mpu6000<S, CS> {
    /// Takes the bus (mode 3, at most 1 MHz for configuration, 20 MHz for reads) and CS.
    pub fn new(spi: S, cs: CS) -> Self {
        Self { spi, cs }
    }

    fn transfer(&mut self, buf: &mut [u8]) -> Result<(), ImuError> {
        self.cs.set_low().map_err(|_| ImuError::Bus)?;
        let r = self
            .spi
            .transfer_in_place(buf)
            .and_then(|()| self.spi.flush());
        self.cs.set_high().map_err(|_| ImuError::Bus)?;
        r.map_err(|_| ImuError::Bus)
    }

    fn write(&mut self, reg: u8, value: u8) -> Result<(), ImuError> {
        self.transfer(&mut [reg, value])
    }

    /// Resets and configures the sensor; `delay_ms` waits (the reset needs 100 ms).
    pub fn init(&mut self, mut delay_ms: impl FnMut(u32)) -> Result<(), ImuError> {
        self.write(PWR_MGMT_1, 0x80)?;
        delay_ms(100);
        // Clock from the z gyro PLL; SPI only (I2C interface off).
        self.write(PWR_MGMT_1, 0x03)?;
        self.write(USER_CTRL, 0x10)?;
        let mut who = [WHO_AM_I | READ, 0];
        self.transfer(&mut who)?;
        if who[1] != 0x68 {
            return Err(ImuError::NotFound(who[1]));
        }
        // 1 kHz internal rate (DLPF 188 Hz), divided by 2: a new sample (and a data-ready
        // pulse) every 2 ms. 512 Hz is not reachable with the MPU-6000's dividers.
        self.write(CONFIG, 0x01)?;
        self.write(SMPLRT_DIV, 0x01)?;
        self.write(GYRO_CONFIG, 0x18)?;
        self.write(ACCEL_CONFIG, 0x10)?;
        // INT pin: active high, push-pull, 50 µs pulse per new sample (not latched).
        self.write(INT_PIN_CFG, 0x00)?;
        self.write(INT_ENABLE, 0x01)?;
        Ok(())
    }

    /// Reads the newest sample (SI units, body frame), stamped `timestamp_us`.
    pub fn read(&mut self, timestamp_us: u32) -> Result<ImuSample, ImuError> {
        let mut buf = [0u8; 15];
        buf[0] = ACCEL_XOUT_H | READ;
        self.transfer(&mut buf)?;
        let word = |i: usize| f32::from(i16::from_be_bytes([buf[1 + 2 * i], buf[2 + 2 * i]]));
        // Words: ax ay az temp gx gy gz.
        Ok(ImuSample {
            timestamp_us,
            gyro_radps: [
                word(4) * GYRO_RADPS_PER_LSB,
                -word(5) * GYRO_RADPS_PER_LSB,
                -word(6) * GYRO_RADPS_PER_LSB,
            ],
            accel_mps2: [
                word(0) * ACCEL_MPS2_PER_LSB,
                -word(1) * ACCEL_MPS2_PER_LSB,
                -word(2) * ACCEL_MPS2_PER_LSB,
            ],
        })
    }
}
