//! Median-5 filter over the last velocity estimates, one filter per axis.
//!
//! The paper filters the raw Edge-FS velocities with a median over the last 5 measurements
//! (vision only: the accelerometers of a 40 g drone are too noisy to fuse). A median removes the
//! isolated spikes that the forward estimate shows while adding at most two frames of delay.
//!
//! # Start-up behaviour
//!
//! The reference implementation fills the window with zeros, so its first four outputs are
//! pulled towards zero (the median of `[v, 0, 0, 0, 0]` is 0 whatever `v` is). This filter
//! instead outputs the median of the samples it actually holds:
//!
//! | samples held | output |
//! |---|---|
//! | 0 | `None` (no estimate yet) |
//! | 1 | that sample |
//! | 2 | mean of the two |
//! | 3 | middle one |
//! | 4 | mean of the middle two |
//! | 5 | middle one (the steady state) |
//!
//! Non-finite inputs (NaN, ±inf) are rejected and do not enter the window. [`Median5::reset`]
//! empties the window (used after a long gap in the estimates, so that stale velocities do not
//! survive a link loss).

/// Window length.
pub const WINDOW: usize = 5;

/// Running median over the last [`WINDOW`] finite samples of one signal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Median5 {
    buf: [f32; WINDOW],
    /// Next slot to overwrite.
    head: usize,
    /// Samples held, 0..=WINDOW.
    len: usize,
}

impl Default for Median5 {
    fn default() -> Self {
        Self::new()
    }
}

impl Median5 {
    /// An empty filter.
    pub const fn new() -> Self {
        Self {
            buf: [0.0; WINDOW],
            head: 0,
            len: 0,
        }
    }

    /// Empties the window.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Number of samples held (0..=5).
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when no sample is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Adds a sample (ignored when not finite) and returns the new output.
    pub fn push(&mut self, x: f32) -> Option<f32> {
        if x.is_finite() {
            if let Some(slot) = self.buf.get_mut(self.head) {
                *slot = x;
            }
            self.head = (self.head + 1) % WINDOW;
            self.len = (self.len + 1).min(WINDOW);
        }
        self.output()
    }

    /// Median of the samples held (see the module docs for fewer than 5), `None` when empty.
    pub fn output(&self) -> Option<f32> {
        let n = self.len.min(WINDOW);
        if n == 0 {
            return None;
        }
        // The newest `n` samples are the last `n` written; with n < WINDOW they are the first n
        // slots because the window never wrapped.
        let mut s = [0.0f32; WINDOW];
        s[..n].copy_from_slice(&self.buf[..n]);
        let s = &mut s[..n];
        // Insertion sort: at most 5 elements, all finite.
        for i in 1..s.len() {
            let mut j = i;
            while j > 0 && s[j - 1] > s[j] {
                s.swap(j - 1, j);
                j -= 1;
            }
        }
        let mid = n / 2;
        if n % 2 == 1 {
            Some(s[mid])
        } else {
            // Halves first: the sum of two large samples would overflow to infinity.
            Some(0.5 * s[mid - 1] + 0.5 * s[mid])
        }
    }
}

/// Median-5 on the forward and sideways velocity.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VelocityMedian {
    /// Forward velocity filter, m/s.
    pub forward: Median5,
    /// Sideways velocity filter, m/s.
    pub sideways: Median5,
}

impl VelocityMedian {
    /// Adds one estimate (m/s) and returns the filtered `[forward, sideways]`, m/s, or `None`
    /// until both axes hold a sample.
    pub fn push(&mut self, forward_mps: f32, sideways_mps: f32) -> Option<[f32; 2]> {
        let f = self.forward.push(forward_mps);
        let s = self.sideways.push(sideways_mps);
        Some([f?, s?])
    }

    /// Current filtered `[forward, sideways]`, m/s.
    pub fn output(&self) -> Option<[f32; 2]> {
        Some([self.forward.output()?, self.sideways.output()?])
    }

    /// Empties both windows.
    pub fn reset(&mut self) {
        self.forward.reset();
        self.sideways.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_outputs_none() {
        let m = Median5::new();
        assert_eq!(m.output(), None);
        assert!(m.is_empty());
    }

    #[test]
    fn start_up_uses_only_real_samples() {
        let mut m = Median5::new();
        // A constant 0.3 m/s from the first sample on is reported as 0.3, not biased to zero.
        for n in 1..=5 {
            assert_eq!(m.push(0.3), Some(0.3), "after {n} samples");
        }
        let mut m = Median5::new();
        assert_eq!(m.push(1.0), Some(1.0));
        assert_eq!(m.push(2.0), Some(1.5));
        assert_eq!(m.push(10.0), Some(2.0));
        assert_eq!(m.push(-4.0), Some(1.5));
        assert_eq!(m.push(3.0), Some(2.0));
        assert_eq!(m.len(), 5);
    }

    #[test]
    fn rejects_spikes_and_slides() {
        let mut m = Median5::new();
        for x in [0.2, 0.2, 5.0, 0.2, 0.2] {
            m.push(x);
        }
        assert_eq!(m.output(), Some(0.2));
        // Two spikes out of five are still rejected.
        m.push(-7.0);
        assert_eq!(m.output(), Some(0.2));
        // The window slides: after five new values, old ones are gone.
        for x in [1.0, 1.1, 0.9, 1.2, 0.8] {
            m.push(x);
        }
        assert_eq!(m.output(), Some(1.0));
    }

    #[test]
    fn non_finite_inputs_are_ignored() {
        let mut m = Median5::new();
        assert_eq!(m.push(f32::NAN), None);
        assert_eq!(m.push(0.5), Some(0.5));
        assert_eq!(m.push(f32::INFINITY), Some(0.5));
        assert_eq!(m.push(f32::NEG_INFINITY), Some(0.5));
        assert_eq!(m.len(), 1);
    }

    #[test]
    fn reset_empties() {
        let mut v = VelocityMedian::default();
        assert_eq!(v.push(0.3, -0.1), Some([0.3, -0.1]));
        v.reset();
        assert_eq!(v.output(), None);
    }
}
