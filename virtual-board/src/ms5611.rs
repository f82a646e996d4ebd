//! The autopilot's MS5611 as the bench hangs it on SPI2: rigless's chip model
//! ([`rigless::chip::ms5611::Ms5611`]), which a test can freeze.
//!
//! A live MS5611 never answers the same conversion word four times in a row (its noise, which
//! the model keeps as a one-count cycle). A frozen one, a fault the autopilot must catch
//! (`baro_stuck_us`), answers every ADC read with the last word it gave before freezing for that
//! kind of conversion (D1, pressure; D2, temperature). Everything else (the PROM, the reset, the
//! conversion timing and its rules) stays the chip's own.

use rigless::chip::Timeline;
use rigless::chip::ms5611::Ms5611;
use rigless::chip::spi::Peer;

/// The MS5611's commands (datasheet p. 10): the conversions' top bits and the ADC read.
const CONVERT_D1: u8 = 0x40;
const CONVERT_D2: u8 = 0x50;
const ADC_READ: u8 = 0x00;

/// The barometer on the bench: the chip model and its freeze.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub struct Barometer {
    chip: Ms5611,
    frozen: bool,
    selected: bool,
    /// The next byte while selected is a command.
    command_next: bool,
    /// The kind of the last conversion started: 0 for D1, 1 for D2.
    converting: Option<usize>,
    /// An ADC read under way: the conversion's kind, the word so far, bytes left.
    reading: Option<(usize, u32, u8)>,
    /// The last word other than 0 read of each kind (D1, D2).
    last_word: [Option<u32>; 2],
}

rigless::store!(Barometer);

impl Default for Barometer {
    fn default() -> Self {
        Self::new()
    }
}

impl Barometer {
    /// A live chip at power-up ([`Ms5611::new`]).
    #[must_use]
    pub fn new() -> Self {
        Self {
            chip: Ms5611::new(),
            frozen: false,
            selected: false,
            command_next: false,
            converting: None,
            reading: None,
            last_word: [None; 2],
        }
    }

    /// The chip model (pressure and temperature it measures).
    pub fn chip(&mut self) -> &mut Ms5611 {
        &mut self.chip
    }

    /// Freezes the chip (every ADC read answers the last word of its kind read before) or lets
    /// it live again.
    pub fn set_frozen(&mut self, frozen: bool) {
        self.frozen = frozen;
    }

    /// Whether it is frozen.
    #[must_use]
    pub fn frozen(&self) -> bool {
        self.frozen
    }
}

impl Peer for Barometer {
    fn select(&mut self, context: &mut Timeline<'_, '_>) {
        self.selected = true;
        self.command_next = true;
        self.reading = None;
        self.chip.select(context);
    }

    fn deselect(&mut self, context: &mut Timeline<'_, '_>) {
        self.selected = false;
        self.reading = None;
        self.chip.deselect(context);
    }

    fn transfer(&mut self, mosi: u32, bits: u8, context: &mut Timeline<'_, '_>) -> u32 {
        let answer = self.chip.transfer(mosi, bits, context);
        if !self.selected {
            return answer;
        }
        if self.command_next {
            self.command_next = false;
            let byte = (mosi & 0xFF) as u8;
            match byte & 0xF0 {
                CONVERT_D1 => self.converting = Some(0),
                CONVERT_D2 => self.converting = Some(1),
                _ if byte == ADC_READ => {
                    self.reading = self.converting.map(|kind| (kind, 0, 3));
                }
                _ => {}
            }
            return answer;
        }
        let Some((kind, word, left)) = self.reading else {
            return answer;
        };
        let word = (word << 8) | (answer & 0xFF);
        let left = left - 1;
        self.reading = (left > 0).then_some((kind, word, left));
        let frozen_word = if self.frozen {
            self.last_word[kind]
        } else {
            None
        };
        if left == 0 && frozen_word.is_none() && word != 0 {
            self.last_word[kind] = Some(word);
        }
        match frozen_word {
            Some(w) => (w >> (8 * u32::from(left))) & 0xFF,
            None => answer,
        }
    }

    fn on_event(&mut self, event: rigless::time::EventId, context: &mut Timeline<'_, '_>) {
        self.chip.on_event(event, context);
    }

    fn restarted(&mut self, context: &mut Timeline<'_, '_>) {
        self.chip.restarted(context);
    }
}
