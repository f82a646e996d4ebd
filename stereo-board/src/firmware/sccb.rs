//! SCCB (the cameras' I2C-compatible register bus) on I2C2, polled, every wait bounded.
//!
//! Written on the PAC rather than with the HAL's I2C driver because that one waits for bus
//! flags without a limit: a missing or stuck camera would hang start-up before the watchdog
//! runs. Here a bus that does not answer gives [`SccbError`] and start-up goes on (the camera is
//! then reported stopped). Pins are set up from the board table by [`crate::firmware::pins`].

use stereo_board::board;
use stm32f4xx_hal::pac;

/// Polls of a status flag before a bus step is given up: about 5 ms at 168 MHz, a dozen byte
/// times at 25 kHz.
const POLLS: u32 = 200_000;

/// Why an SCCB transfer failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum SccbError {
    /// No acknowledge (no camera at the address, or it is in reset).
    NoAck,
    /// Bus error or arbitration lost.
    Bus,
    /// A step did not complete in time.
    Timeout,
}

/// I2C2 as the SCCB master.
pub struct Sccb {
    i2c: pac::I2C2,
}

impl Sccb {
    /// Enables and resets I2C2 and sets it to [`board::SCCB_HZ`] (standard mode) from the APB1
    /// clock.
    pub fn new(i2c: pac::I2C2) -> Self {
        // SAFETY: the I2C2 enable and reset bits are owned by this driver only.
        let rcc = unsafe { &*pac::RCC::ptr() };
        rcc.apb1enr().modify(|_, w| w.i2c2en().set_bit());
        rcc.apb1rstr().modify(|_, w| w.i2c2rst().set_bit());
        rcc.apb1rstr().modify(|_, w| w.i2c2rst().clear_bit());
        let pclk_mhz = board::APB1_HZ / board::HZ_PER_MHZ;
        // Standard mode: SCL high and low each CCR periods of the APB1 clock.
        let ccr = board::APB1_HZ / (2 * board::SCCB_HZ);
        i2c.cr1().write(|w| w.pe().clear_bit());
        // SAFETY: 42 (MHz) is inside FREQ's range 2..=50.
        i2c.cr2()
            .write(|w| unsafe { w.freq().bits(pclk_mhz as u8) });
        // SAFETY: 840 fits CCR's 12 bits (and is above its minimum of 4).
        i2c.ccr()
            .write(|w| unsafe { w.f_s().clear_bit().ccr().bits(ccr as u16) });
        // Maximum rise time 1000 ns in standard mode: FREQ + 1.
        i2c.trise().write(|w| w.trise().set(pclk_mhz as u8 + 1));
        i2c.cr1().write(|w| w.pe().set_bit());
        Self { i2c }
    }

    /// Waits until `done` holds for SR1, failing on NACK, bus error or time-out.
    fn wait(&self, done: impl Fn(&pac::i2c1::sr1::R) -> bool) -> Result<(), SccbError> {
        for _ in 0..POLLS {
            let sr1 = self.i2c.sr1().read();
            if sr1.af().bit_is_set() {
                self.i2c.sr1().modify(|_, w| w.af().clear_bit());
                return Err(SccbError::NoAck);
            }
            if sr1.berr().bit_is_set() || sr1.arlo().bit_is_set() {
                self.i2c
                    .sr1()
                    .modify(|_, w| w.berr().clear_bit().arlo().clear_bit());
                return Err(SccbError::Bus);
            }
            if done(&sr1) {
                return Ok(());
            }
        }
        Err(SccbError::Timeout)
    }

    /// START and the address byte (`read`: receiver). Leaves ADDR set for the caller.
    fn start(&self, read: bool) -> Result<(), SccbError> {
        self.i2c.cr1().modify(|_, w| w.start().set_bit());
        self.wait(|s| s.sb().bit_is_set())?;
        let address = (board::TCM8230_ADDRESS << 1) | u8::from(read);
        self.i2c.dr().write(|w| w.dr().set(address));
        self.wait(|s| s.addr().bit_is_set())
    }

    /// Clears ADDR (SR1 then SR2 read).
    fn clear_addr(&self) {
        let _ = self.i2c.sr1().read();
        let _ = self.i2c.sr2().read();
    }

    fn send(&self, byte: u8) -> Result<(), SccbError> {
        self.i2c.dr().write(|w| w.dr().set(byte));
        self.wait(|s| s.btf().bit_is_set())
    }

    fn stop(&self) {
        self.i2c.cr1().modify(|_, w| w.stop().set_bit());
    }

    /// Writes `value` to register `reg`.
    pub fn write(&mut self, reg: u8, value: u8) -> Result<(), SccbError> {
        let result = self.start(false).and_then(|()| {
            self.clear_addr();
            self.send(reg)?;
            self.send(value)
        });
        self.stop();
        result
    }

    /// Reads register `reg` (register address written, then a repeated START to read one byte,
    /// as the original does).
    pub fn read(&mut self, reg: u8) -> Result<u8, SccbError> {
        let result = self.start(false).and_then(|()| {
            self.clear_addr();
            self.send(reg)?;
            self.start(true)?;
            // One byte: NACK it and STOP right after ADDR is cleared.
            self.i2c.cr1().modify(|_, w| w.ack().clear_bit());
            self.clear_addr();
            self.stop();
            self.wait(|s| s.rx_ne().bit_is_set())?;
            Ok(self.i2c.dr().read().dr().bits())
        });
        if result.is_err() {
            self.stop();
        }
        result
    }
}
