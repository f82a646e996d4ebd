//! MS5611-01BA03 barometer (TE Connectivity datasheet, and application note AN520 for the
//! PROM check): commands, conversion times, the PROM CRC-4 and the first- and second-order
//! compensation. Hardware-free: the firmware does the SPI transfers and the waits, and hands
//! the words here.
//!
//! The sequence: [`CMD_RESET`], wait [`RESET_TIME`]; read the eight PROM words
//! ([`prom_read_command`]) and check them ([`Calibration::from_prom`]); then repeatedly
//! [`convert_d1_command`], wait [`Osr::conversion_time`], [`CMD_ADC_READ`] (24 bits),
//! [`convert_d2_command`], wait, read, and [`Calibration::compensate`].

use timebase::Duration;

/// Reset command.
pub const CMD_RESET: u8 = 0x1E;
/// ADC read command (24-bit result follows).
pub const CMD_ADC_READ: u8 = 0x00;
/// Time the reset takes (datasheet: 2.8 ms reload of the PROM).
pub const RESET_TIME: Duration = Duration::from_micros(2_800);

/// Oversampling ratio of a conversion.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Osr {
    /// 256 samples.
    X256,
    /// 512 samples.
    X512,
    /// 1024 samples.
    X1024,
    /// 2048 samples.
    X2048,
    /// 4096 samples (resolution 0.012 mbar, about 10 cm).
    X4096,
}

impl Osr {
    /// The command offset (added to 0x40 for D1, 0x50 for D2).
    fn offset(self) -> u8 {
        match self {
            Osr::X256 => 0x0,
            Osr::X512 => 0x2,
            Osr::X1024 => 0x4,
            Osr::X2048 => 0x6,
            Osr::X4096 => 0x8,
        }
    }

    /// Longest conversion time (datasheet, "ADC conversion time", max column).
    pub const fn conversion_time(self) -> Duration {
        Duration::from_micros(match self {
            Osr::X256 => 600,
            Osr::X512 => 1_170,
            Osr::X1024 => 2_280,
            Osr::X2048 => 4_540,
            Osr::X4096 => 9_040,
        })
    }
}

/// Command starting a pressure (D1) conversion.
pub fn convert_d1_command(osr: Osr) -> u8 {
    0x40 | osr.offset()
}

/// Command starting a temperature (D2) conversion.
pub fn convert_d2_command(osr: Osr) -> u8 {
    0x50 | osr.offset()
}

/// Command reading PROM word `index` (0..=7; 16 bits follow, most significant first).
pub fn prom_read_command(index: u8) -> u8 {
    0xA0 | ((index & 0x7) << 1)
}

/// CRC-4 of the PROM (AN520): over the eight words, most significant byte first, with the low
/// byte of word 7 (which holds the CRC in its low nibble) taken as zero, as AN520's reference
/// code does; polynomial x^4 + x^3 + 1 (0x3000 on the 16-bit remainder).
pub fn prom_crc4(prom: &[u16; 8]) -> u8 {
    let mut rem: u16 = 0;
    for i in 0..16 {
        let word = if i / 2 == 7 {
            prom[7] & 0xFF00
        } else {
            prom[i / 2]
        };
        let byte = if i % 2 == 0 { word >> 8 } else { word & 0x00FF };
        rem ^= byte;
        for _ in 0..8 {
            rem = if rem & 0x8000 != 0 {
                (rem << 1) ^ 0x3000
            } else {
                rem << 1
            };
        }
    }
    ((rem >> 12) & 0xF) as u8
}

/// Why a PROM was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PromError {
    /// Every word 0x0000 or every word 0xFFFF: no chip answering (the CRC of zeros is zero, so
    /// this is checked first).
    NoChip,
    /// The CRC does not match (stored, computed).
    Crc(u8, u8),
}

/// The six calibration coefficients C1..C6.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Calibration {
    /// C1..C6 (PROM words 1..=6).
    pub c: [u16; 6],
}

/// A compensated reading: pressure, Pa, and temperature, °C. The telemetry's type, so a reading
/// goes to the host as it is.
pub type BaroReading = protocol::BaroTelemetry;

impl Calibration {
    /// Checks the PROM's CRC and takes C1..C6 from it.
    pub fn from_prom(prom: &[u16; 8]) -> Result<Self, PromError> {
        if prom.iter().all(|&w| w == 0) || prom.iter().all(|&w| w == 0xFFFF) {
            return Err(PromError::NoChip);
        }
        let stored = (prom[7] & 0xF) as u8;
        let computed = prom_crc4(prom);
        if stored != computed {
            return Err(PromError::Crc(stored, computed));
        }
        Ok(Self {
            c: [prom[1], prom[2], prom[3], prom[4], prom[5], prom[6]],
        })
    }

    /// Pressure and temperature from the raw conversions `d1` (pressure) and `d2`
    /// (temperature), 24-bit each, with the datasheet's second-order correction below 20 deg C.
    /// Returns the integer results too: (pressure in 0.01 mbar = Pa, temperature in 0.01 deg C).
    pub fn compensate_raw(&self, d1: u32, d2: u32) -> (i32, i32) {
        let c = self.c.map(i64::from);
        let d1 = i64::from(d1 & 0xFF_FFFF);
        let d2 = i64::from(d2 & 0xFF_FFFF);
        let dt = d2 - (c[4] << 8);
        let mut temp = 2000 + ((dt * c[5]) >> 23);
        let mut off = (c[1] << 16) + ((c[3] * dt) >> 7);
        let mut sens = (c[0] << 15) + ((c[2] * dt) >> 8);
        if temp < 2000 {
            let t2 = (dt * dt) >> 31;
            let low = (temp - 2000) * (temp - 2000);
            let mut off2 = 5 * low / 2;
            let mut sens2 = 5 * low / 4;
            if temp < -1500 {
                let very_low = (temp + 1500) * (temp + 1500);
                off2 += 7 * very_low;
                sens2 += 11 * very_low / 2;
            }
            temp -= t2;
            off -= off2;
            sens -= sens2;
        }
        let p = (((d1 * sens) >> 21) - off) >> 15;
        (p as i32, temp as i32)
    }

    /// [`Calibration::compensate_raw`] in SI units.
    pub fn compensate(&self, d1: u32, d2: u32) -> BaroReading {
        let (p, t) = self.compensate_raw(d1, d2);
        BaroReading {
            pressure_pa: p as f32,
            temperature_c: t as f32 / 100.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The datasheet's example coefficients (typical values table).
    const C: [u16; 6] = [40127, 36924, 23317, 23282, 33464, 28312];

    fn prom_with_crc(c: [u16; 6]) -> [u16; 8] {
        let mut prom = [0x0C00, c[0], c[1], c[2], c[3], c[4], c[5], 0x4D00];
        prom[7] |= u16::from(prom_crc4(&prom));
        prom
    }

    #[test]
    fn datasheet_example_compensates_to_its_published_result() {
        let cal = Calibration::from_prom(&prom_with_crc(C)).expect("valid PROM");
        // D1 = 9085466, D2 = 8569150 -> TEMP = 2007 (20.07 deg C), P = 100009 (1000.09 mbar).
        assert_eq!(cal.compensate_raw(9_085_466, 8_569_150), (100_009, 2007));
        let r = cal.compensate(9_085_466, 8_569_150);
        assert!((r.pressure_pa - 100_009.0).abs() < 0.5);
        assert!((r.temperature_c - 20.07).abs() < 1e-4);
    }

    #[test]
    fn crc4_matches_the_application_note_example() {
        // AN520's example PROM (its last word carries CRC 0xB).
        let prom = [
            0x3132, 0x3334, 0x3536, 0x3738, 0x3940, 0x4142, 0x4344, 0x450B,
        ];
        assert_eq!(prom_crc4(&prom), 0xB);
        assert!(Calibration::from_prom(&prom).is_ok());
    }

    #[test]
    fn a_flipped_bit_or_a_missing_chip_is_refused() {
        let good = prom_with_crc(C);
        for word in 0..8 {
            for bit in 0..16 {
                if word == 7 && bit < 8 {
                    continue; // the low byte of word 7 is outside the CRC (the CRC itself)
                }
                let mut bad = good;
                bad[word] ^= 1 << bit;
                assert!(
                    matches!(Calibration::from_prom(&bad), Err(PromError::Crc(_, _))),
                    "word {word} bit {bit}"
                );
            }
        }
        let mut bad_crc = good;
        bad_crc[7] ^= 0x1;
        assert!(Calibration::from_prom(&bad_crc).is_err());
        assert_eq!(Calibration::from_prom(&[0; 8]), Err(PromError::NoChip));
        assert_eq!(Calibration::from_prom(&[0xFFFF; 8]), Err(PromError::NoChip));
    }

    #[test]
    fn second_order_correction_applies_below_20_degrees() {
        let cal = Calibration::from_prom(&prom_with_crc(C)).expect("valid PROM");
        // A colder D2: below 2000 the correction lowers TEMP further and raises P's offset.
        let d2 = 8_569_150 - 400_000;
        let (p, t) = cal.compensate_raw(9_085_466, d2);
        let c = C.map(i64::from);
        let dt = i64::from(d2) - (c[4] << 8);
        let t1 = 2000 + ((dt * c[5]) >> 23);
        assert!(t1 < 2000);
        assert_eq!(i64::from(t), t1 - ((dt * dt) >> 31));
        assert!(p > 90_000 && p < 110_000, "{p}");
        assert_eq!(convert_d1_command(Osr::X4096), 0x48);
        assert_eq!(convert_d2_command(Osr::X256), 0x50);
        assert_eq!(prom_read_command(7), 0xAE);
    }
}
