//! Camera sensor set-up over SCCB (I2C-compatible), behind a trait so that another sensor can
//! be added: implement [`CameraSensor`] with its address, identification check and register
//! table.

use embedded_hal::i2c::I2c;

/// A camera sensor configured by writing registers over SCCB/I2C.
pub trait CameraSensor {
    /// 7-bit bus address.
    const ADDRESS: u8;
    /// `(register, value)` writes that put the sensor into 128x96, 8-bit luminance output.
    const INIT: &'static [(u8, u8)];

    /// Writes the register table; stops at the first bus error.
    fn init<B: I2c>(&self, bus: &mut B) -> Result<(), B::Error> {
        for &(reg, value) in Self::INIT {
            bus.write(Self::ADDRESS, &[reg, value])?;
        }
        Ok(())
    }

    /// Reads one register back (for a presence check after `init`).
    fn read<B: I2c>(&self, bus: &mut B, reg: u8) -> Result<u8, B::Error> {
        let mut v = [0u8; 1];
        bus.write_read(Self::ADDRESS, &[reg], &mut v)?;
        Ok(v[0])
    }
}

/// Toshiba TCM8230MD, the sensor pair of the stereo board (both share the bus through the
/// board's interleaving logic, so one write configures both).
///
/// Register values follow the TCM8230MD datasheet as we read it: register 0x02 = 30 fps,
/// 50 Hz flicker setting, data on the rising clock edge; register 0x03 = output enabled,
/// picture size subQCIF (128x96), format black/white (luminance only). Check them against
/// your sensor revision on hardware before flight.
pub struct Tcm8230;

impl CameraSensor for Tcm8230 {
    const ADDRESS: u8 = 0x3C;
    const INIT: &'static [(u8, u8)] = &[(0x02, 0x00), (0x03, (0x8 << 2) | 0b10)];
}
