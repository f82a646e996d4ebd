//! The TCM8230MD register set-up of the stereo board's two cameras (written once over SCCB; both
//! sensors share the address and answer together through the CPLD).
//!
//! What the board needs from the sensors: 128x96 frames whose every second byte is luminance,
//! at the fast frame rate, with the pixel clock the DCMI samples on its falling edge. The CPLD
//! (pixel-mux mode, [`crate::board::CPLD_MODE`]) puts the left camera's luminance byte in one
//! slot of each pixel and the right camera's in the other, so each camera must send YUV 4:2:2
//! (`Cb Y Cr Y ...`: a luminance byte every second pixel clock); RGB 5:6:5 would put colour bits
//! where luminance belongs. Values and their meaning follow the original stereoboard firmware's
//! register defines (\[SB\] tcm8230.c:32-47, 110-184, 215-232), which the paper flew.

use crate::board;

/// Register 0x02: frame rate, flicker control, clock polarity.
pub const REG_FPS: u8 = 0x02;
/// Register 0x03: output enable, picture size, format, colour.
pub const REG_FORMAT: u8 = 0x03;
/// Register 0x08: auto-luminance mode and convergence range.
pub const REG_ALC_MODE: u8 = 0x08;
/// Register 0x12: brightness (luminance target).
pub const REG_BRIGHTNESS: u8 = 0x12;
/// Register 0x1C: lines per 1/100 s (flicker-free exposure steps under 50 Hz light).
pub const REG_LINES_100HZ: u8 = 0x1C;
/// Register 0x1D: lines per 1/120 s (flicker-free exposure steps under 60 Hz light).
pub const REG_LINES_120HZ: u8 = 0x1D;
/// Register 0x1E: synchronisation code settings.
pub const REG_SYNC: u8 = 0x1E;

/// 0x02 bit 7 clear: the fast mode, 30 fps at the nominal clock (set: 15 fps).
const FPS_FAST: u8 = 0 << 7;
/// 0x02 bit 6: flicker setting for 60 Hz mains when detection is off (clear: 50 Hz).
const ANTI_FLICKER_60HZ: u8 = 1 << 6;
/// 0x02 bit 1: reversed pixel-clock polarity, so that data is stable at the falling edge the
/// DCMI samples on ([`board::DCMI_PIXCLK_RISING`] = false).
const CLOCK_POLARITY_REVERSED: u8 = 1 << 1;
/// 0x02 bit 0 clear: flicker frequency detected automatically (the 60 Hz bit is a fallback).
const FLICKER_AUTO_DETECT: u8 = 0;

/// 0x03 bits 7..6 clear: data output on, not high-impedance.
const OUTPUT_ON: u8 = 0;
/// 0x03 bits 5..2 = 8: subQCIF, 128x96.
const SIZE_SUBQCIF: u8 = 8 << 2;
/// 0x03 bit 1 clear: YUV 4:2:2 (set: RGB 5:6:5).
const FORMAT_YUV422: u8 = 0 << 1;
/// 0x03 bit 0 clear: colour processing (set: black and white). The CPLD keeps only the
/// luminance bytes either way; the original flew with colour processing on.
const COLOUR: u8 = 0;

/// 0x08 bits 5..4 = 1: the auto-luminance loop meters the whole-image average (not the centre),
/// right for walls and clutter anywhere in view.
const ALC_AVERAGE: u8 = 1 << 4;
/// 0x08 bits 3..0 = 8: convergence range of the auto-luminance loop (the sensor's default).
const ALC_CONVERGENCE: u8 = 0b1000;

/// 0x12 = 0x1C: luminance target raised from the default 0x0C, for dim indoor scenes.
const BRIGHTNESS: u8 = 0x1C;

/// 0x1E = 0x48: the original's synchronisation setting (its default is 0x68; the original's
/// comment calls 0x48 the ITU-656 sync mode). The DCMI uses the HSYNC/VSYNC pins, not codes.
const SYNC: u8 = 0x48;

/// One sensor line in master-clock cycles: 780 pixel periods of 2 clocks (\[SB\] tcm8230.c's
/// `CLK/(780*2*...)`).
pub const LINE_CLOCKS: u32 = 780 * 2;

/// Lines in `1 / hz` seconds at the board's master clock, rounded.
const fn lines_per(hz: u32) -> u8 {
    let per = LINE_CLOCKS * hz;
    let lines = (board::CAMERA_CLOCK_HZ + per / 2) / per;
    assert!(lines > 0 && lines < 256);
    lines as u8
}

/// Lines per 1/100 s at 21 MHz: 135.
pub const LINES_100HZ: u8 = lines_per(100);
/// Lines per 1/120 s at 21 MHz: 112.
pub const LINES_120HZ: u8 = lines_per(120);
const _: () = assert!(LINES_100HZ == 135 && LINES_120HZ == 112);

/// Value of register 0x03: output on, 128x96, YUV 4:2:2, colour = 0x20.
pub const FORMAT: u8 = OUTPUT_ON | SIZE_SUBQCIF | FORMAT_YUV422 | COLOUR;
/// Value of register 0x02: fast mode, 60 Hz fallback, reversed clock, auto flicker = 0x42.
pub const FPS: u8 = FPS_FAST | ANTI_FLICKER_60HZ | CLOCK_POLARITY_REVERSED | FLICKER_AUTO_DETECT;
const _: () = assert!(FORMAT == 0x20 && FPS == 0x42);

/// The set-up, in the order written: picture format first, the frame-rate register last (as
/// the original; it starts the timing the DCMI then locks onto). Each is read back.
pub const SETUP: [(u8, u8); 7] = [
    (REG_FORMAT, FORMAT),
    (REG_SYNC, SYNC),
    (REG_BRIGHTNESS, BRIGHTNESS),
    (REG_ALC_MODE, ALC_AVERAGE | ALC_CONVERGENCE),
    (REG_LINES_100HZ, LINES_100HZ),
    (REG_LINES_120HZ, LINES_120HZ),
    (REG_FPS, FPS),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn setup_selects_luminance_not_rgb() {
        let format = SETUP
            .iter()
            .find(|(r, _)| *r == REG_FORMAT)
            .map(|(_, v)| *v);
        assert_eq!(format, Some(0x20));
        assert_eq!(
            format.map(|v| v & 0b10),
            Some(0),
            "bit 1 set would be RGB565"
        );
        assert_eq!(format.map(|v| (v >> 2) & 0xF), Some(8), "subQCIF 128x96");
    }

    #[test]
    fn setup_is_the_originals_register_set() {
        assert_eq!(
            SETUP,
            [
                (0x03, 0x20),
                (0x1E, 0x48),
                (0x12, 0x1C),
                (0x08, 0x18),
                (0x1C, 135),
                (0x1D, 112),
                (0x02, 0x42),
            ]
        );
    }
}
