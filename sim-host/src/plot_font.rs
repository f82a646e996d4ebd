//! The font of every PNG plot: DejaVu Sans, embedded in the binary (the `dejavu` crate), so
//! plots have titles, axis labels and legends on any machine without system fonts.

use plotters::style::FontStyle;
use std::sync::Once;

/// The font family name plots use.
pub const FAMILY: &str = "sans-serif";

/// Registers the embedded font with plotters (idempotent, thread-safe). Call before drawing.
pub fn register() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is a valid TrueType file shipped by the crate; failure would be a build
        // problem, and plots are then drawn without text rather than aborting the run.
        let _ = plotters::style::register_font(FAMILY, FontStyle::Normal, dejavu::sans::regular());
        let _ = plotters::style::register_font(FAMILY, FontStyle::Bold, dejavu::sans::bold());
    });
}

#[cfg(test)]
mod tests {
    use plotters::prelude::*;

    /// Text renders into a bitmap (the embedded font works without system fonts).
    #[test]
    fn text_draws_pixels() {
        super::register();
        let mut buf = vec![255u8; 200 * 50 * 3];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (200, 50)).into_drawing_area();
            root.draw_text(
                "v [m/s]",
                &(super::FAMILY, 20).into_font().color(&BLACK),
                (5, 5),
            )
            .expect("draw text");
            root.present().expect("present");
        }
        assert!(
            buf.iter().any(|&b| b < 128),
            "no dark pixel: the text was not drawn"
        );
    }
}
