//! The sensors on SPI2: the MPU-6000 (chip select PB12) and the MS5611 (chip select PC13), both
//! in SPI mode 3 at [`autopilot::board::SPI_HZ`]. This module does the transfers; what the
//! bytes mean and when a sample is valid is the library's ([`autopilot::mpu6000`],
//! [`autopilot::ms5611`]), tested on the host.
//!
//! The bus is one RTIC resource: the 512 Hz loop reads the IMU in one locked step (three
//! transfers, about 230 us), the barometer task holds it for one command or one result read at
//! a time (at most 4 bytes, 50 us) and waits for its conversions with the bus free.

use autopilot::board::hw::{BaroCs, ImuCs, SensorSpi};
use autopilot::{mpu6000, ms5611};
use embedded_hal::digital::OutputPin;
use timebase::Duration;

/// A transfer that did not complete.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusError;

/// SPI2 with both chip selects.
pub struct SensorBus {
    spi: SensorSpi,
    imu_cs: ImuCs,
    baro_cs: BaroCs,
}

/// Which chip a transfer addresses.
#[derive(Clone, Copy)]
enum Chip {
    Imu,
    Baro,
}

impl SensorBus {
    /// The bus and both (deselected) chip selects.
    pub fn new(spi: SensorSpi, imu_cs: ImuCs, baro_cs: BaroCs) -> Self {
        Self {
            spi,
            imu_cs,
            baro_cs,
        }
    }

    fn transfer(&mut self, chip: Chip, buf: &mut [u8]) -> Result<(), BusError> {
        let cs: &mut dyn OutputPin<Error = core::convert::Infallible> = match chip {
            Chip::Imu => &mut self.imu_cs,
            Chip::Baro => &mut self.baro_cs,
        };
        let _ = cs.set_low();
        let r = self
            .spi
            .transfer_in_place(buf)
            .and_then(|()| self.spi.flush());
        let cs: &mut dyn OutputPin<Error = core::convert::Infallible> = match chip {
            Chip::Imu => &mut self.imu_cs,
            Chip::Baro => &mut self.baro_cs,
        };
        let _ = cs.set_high();
        r.map_err(|_| BusError)
    }

    fn imu_write(&mut self, reg: u8, value: u8) -> Result<(), BusError> {
        self.transfer(Chip::Imu, &mut [reg, value])
    }

    fn imu_read_register(&mut self, reg: u8) -> Result<u8, BusError> {
        let mut buf = [reg | mpu6000::READ, 0];
        self.transfer(Chip::Imu, &mut buf)?;
        Ok(buf[1])
    }

    /// Resets and configures the MPU-6000 ([`mpu6000::CONFIG_SEQUENCE`]); `delay` busy-waits
    /// (init only). Returns what `WHO_AM_I` reads afterwards.
    pub fn imu_init(&mut self, mut delay: impl FnMut(Duration)) -> Result<u8, BusError> {
        self.imu_write(mpu6000::PWR_MGMT_1, mpu6000::PWR_MGMT_1_RESET)?;
        delay(mpu6000::RESET_WAIT);
        // Over SPI the register map asks for a signal-path reset after the device reset.
        self.imu_write(mpu6000::SIGNAL_PATH_RESET, 0x07)?;
        delay(mpu6000::SIGNAL_PATH_RESET_WAIT);
        self.imu_configure()?;
        self.imu_read_register(mpu6000::WHO_AM_I)
    }

    /// Writes [`mpu6000::CONFIG_SEQUENCE`] (waking the chip) and reads the configuration back.
    /// If it does not read back as written, the chip is put back to sleep, so that its samples
    /// stay invalid and the next [`mpu6000::Reconfigure`] tries again: awake means configured.
    /// Returns whether it read back right. No waits: 7 writes and 3 reads of two bytes, about
    /// 300 us at [`autopilot::board::SPI_HZ`].
    pub fn imu_configure(&mut self) -> Result<bool, BusError> {
        for (reg, value) in mpu6000::CONFIG_SEQUENCE {
            self.imu_write(reg, value)?;
        }
        let mut values = [0u8; 3];
        for (value, reg) in values.iter_mut().zip(mpu6000::CONFIG_READBACK) {
            *value = self.imu_read_register(reg)?;
        }
        let ok = mpu6000::config_matches(values);
        if !ok {
            self.imu_write(mpu6000::PWR_MGMT_1, mpu6000::PWR_MGMT_1_SLEEP)?;
        }
        Ok(ok)
    }

    /// One control step's reads: `WHO_AM_I`, `PWR_MGMT_1` and the 14 data bytes.
    pub fn imu_read(&mut self) -> Result<(u8, u8, [u8; 14]), BusError> {
        let who = self.imu_read_register(mpu6000::WHO_AM_I)?;
        let pwr = self.imu_read_register(mpu6000::PWR_MGMT_1)?;
        let mut buf = [0u8; 15];
        buf[0] = mpu6000::ACCEL_XOUT_H | mpu6000::READ;
        self.transfer(Chip::Imu, &mut buf)?;
        let mut data = [0u8; 14];
        data.copy_from_slice(buf.get(1..).unwrap_or(&[0; 14]));
        Ok((who, pwr, data))
    }

    /// Sends a one-byte MS5611 command (reset, or start a conversion).
    pub fn baro_command(&mut self, cmd: u8) -> Result<(), BusError> {
        self.transfer(Chip::Baro, &mut [cmd])
    }

    /// Reads PROM word `index`.
    pub fn baro_prom(&mut self, index: u8) -> Result<u16, BusError> {
        let mut buf = [ms5611::prom_read_command(index), 0, 0];
        self.transfer(Chip::Baro, &mut buf)?;
        Ok(u16::from_be_bytes([buf[1], buf[2]]))
    }

    /// Reads the last conversion's 24-bit result (0 if none finished).
    pub fn baro_adc(&mut self) -> Result<u32, BusError> {
        let mut buf = [ms5611::CMD_ADC_READ, 0, 0, 0];
        self.transfer(Chip::Baro, &mut buf)?;
        Ok(u32::from_be_bytes([0, buf[1], buf[2], buf[3]]))
    }
}
