//! The camera board's CPLD: it merges the two sensors' byte streams onto the one DCMI bus, in
//! the mode three MCU pins select.
//!
//! Source: the original board's firmware, \[SB\] `stereoboard/drivers/src/cpld.c` (pins and modes)
//! and `main_parameters.h` (the stereo build selects the pixel interleave). The CPLD's own logic
//! is not published; what each mode puts on the bus is read from the names and comments there:
//!
//! | PC10 | PC12 | PB5 | mode (\[SB\] cpld.c) | model |
//! |---|---|---|---|---|
//! | 0 | 0 | 0 | left colour image only | the left sensor's bytes |
//! | 1 | 0 | 0 | right colour image only | the right sensor's bytes |
//! | 0 | 1 | 0 | "left image pixel intensity, right image pixel intensity" | per pixel: the left sensor's second (luminance) byte, then the right sensor's |
//! | 0 | 0 | 1 | line interleave | not modelled: nothing on the bus |
//! | 1 | 1 | 1 | frame interleave | not modelled: nothing on the bus |
//! | 1 | 1 | 0 | colour lines alternating with the pixel interleave | not modelled: nothing on the bus |
//!
//! The two sensors share EXTCLK and RESET, so they run in step and the CPLD passes one byte per
//! DCLK. A mode pin the MCU does not drive as an output leaves the mode undefined: the model then
//! puts nothing on the bus (the board's pull resistors, if any, are not documented).
//!
//! In the pixel interleave the luminance byte is the second byte of each sensor's pixel: with the
//! sensors in YUV 4:2:2 that is Y, and a frame holds `[L0 R0 L1 R1 ...]` (the layout of the data
//! set's BMPs and of `stereo-board`'s frames); with the sensors in RGB 5:6:5 it is the low byte of
//! the pixel, not a luminance.

use crate::tcm8230::StreamSetup;

/// The CPLD's mode, from its three select pins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// The left sensor's stream.
    LeftOnly,
    /// The right sensor's stream.
    RightOnly,
    /// Per pixel, the left then the right sensor's luminance byte.
    PixelInterleave,
    /// Left and right lines alternating (not modelled).
    LineInterleave,
    /// Left and right frames alternating (not modelled).
    FrameInterleave,
    /// Colour lines alternating with the pixel interleave (not modelled).
    PixelInterleaveColour,
    /// A select pin not driven, or a combination cpld.c does not name.
    Undefined,
}

impl Mode {
    /// The mode the pins select: each `Some(level)` where the MCU drives the pin as an output,
    /// `None` where it does not. Pin order: PC10, PC12, PB5.
    #[must_use]
    pub fn from_pins(pins: [Option<bool>; 3]) -> Self {
        match pins {
            [Some(false), Some(false), Some(false)] => Self::LeftOnly,
            [Some(true), Some(false), Some(false)] => Self::RightOnly,
            [Some(false), Some(true), Some(false)] => Self::PixelInterleave,
            [Some(false), Some(false), Some(true)] => Self::LineInterleave,
            [Some(true), Some(true), Some(true)] => Self::FrameInterleave,
            [Some(true), Some(true), Some(false)] => Self::PixelInterleaveColour,
            _ => Self::Undefined,
        }
    }

    /// Whether the model puts this mode's bytes on the bus.
    #[must_use]
    pub fn is_modelled(self) -> bool {
        matches!(
            self,
            Self::LeftOnly | Self::RightOnly | Self::PixelInterleave
        )
    }
}

/// The bytes the CPLD puts on the bus for one output line, from the two sensors' luminance rows
/// (`left` and `right`, `setup.width` pixels each), or `None` where the mode is not modelled.
#[must_use]
pub fn merge_line(mode: Mode, setup: &StreamSetup, left: &[u8], right: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(2 * setup.width);
    match mode {
        Mode::LeftOnly | Mode::RightOnly => {
            let row = if mode == Mode::LeftOnly { left } else { right };
            for &y in row.iter().take(setup.width) {
                out.extend_from_slice(&setup.pixel_bytes(y));
            }
        }
        Mode::PixelInterleave => {
            for (&l, &r) in left.iter().zip(right).take(setup.width) {
                out.push(setup.pixel_bytes(l)[1]);
                out.push(setup.pixel_bytes(r)[1]);
            }
        }
        _ => return None,
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tcm8230::{FRAME_LINES, Format};

    fn setup(format: Format) -> StreamSetup {
        StreamSetup {
            width: 4,
            height: 96,
            format,
            frame_lines: FRAME_LINES,
            launch_on_rising: true,
        }
    }

    #[test]
    fn the_stereo_mode_is_the_one_the_original_firmware_selects() {
        // [SB] cpld.c camera_cpld_stereo_pixmux: PC10 = 0, PC12 = 1, PB5 = 0.
        assert_eq!(
            Mode::from_pins([Some(false), Some(true), Some(false)]),
            Mode::PixelInterleave
        );
        assert_eq!(
            Mode::from_pins([Some(false), None, Some(false)]),
            Mode::Undefined
        );
        assert_eq!(
            Mode::from_pins([Some(false), Some(false), Some(true)]),
            Mode::LineInterleave
        );
        assert!(!Mode::LineInterleave.is_modelled());
    }

    #[test]
    fn the_pixel_interleave_of_yuv_sensors_is_left_then_right_luminance() {
        let line = merge_line(
            Mode::PixelInterleave,
            &setup(Format::Yuv422),
            &[1, 2, 3, 4],
            &[11, 12, 13, 14],
        );
        assert_eq!(line, Some(vec![1, 11, 2, 12, 3, 13, 4, 14]));
    }

    #[test]
    fn rgb565_sensors_give_no_luminance_in_the_stereo_mode() {
        let line = merge_line(
            Mode::PixelInterleave,
            &setup(Format::Rgb565),
            &[0x80; 4],
            &[0x80; 4],
        )
        .expect("modelled");
        assert_eq!(&line[..2], &[0x10, 0x10]);
    }

    #[test]
    fn a_single_sensor_mode_passes_its_yuv_bytes() {
        let line = merge_line(
            Mode::RightOnly,
            &setup(Format::Yuv422),
            &[1, 2, 3, 4],
            &[11, 12, 13, 14],
        );
        assert_eq!(line, Some(vec![0x80, 11, 0x80, 12, 0x80, 13, 0x80, 14]));
        assert_eq!(
            merge_line(Mode::Undefined, &setup(Format::Yuv422), &[1], &[2]),
            None
        );
    }
}
