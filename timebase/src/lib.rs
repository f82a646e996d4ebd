//! The project's one time vocabulary, in microseconds.
//!
//! * [`Duration`]: a span of time.
//! * [`Instant`]: a point on a board's own clock (what the flight libraries are handed: they
//!   never read a clock themselves).
//! * [`WorldTime`]: a point on the simulated world's clock (the simulator, and the lockstep
//!   flavours where the host's world drives the flight code). It is a different type from
//!   [`Instant`] so that board time and world time cannot be mixed by accident; the one place
//!   that maps world time onto a board's flight clock says so with [`WorldTime::as_flight_clock`].
//! * [`WireTime`]: the wrapping 32-bit microsecond timestamp messages carry, and
//!   [`WrapExtender`], the one way back from it to a 64-bit timeline.
//!
//! Arithmetic saturates: an instant never wraps and a duration is never negative. The one
//! wrapping difference says so in its name (`wrapping_since`).
#![no_std]
#![warn(missing_docs)]

use core::marker::PhantomData;
use core::ops::{Add, AddAssign, Sub};
use serde::{Deserialize, Serialize};

/// A span of time, µs.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize,
)]
#[serde(transparent)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Duration(u64);

impl Duration {
    /// No time.
    pub const ZERO: Self = Self(0);
    /// The longest span.
    pub const MAX: Self = Self(u64::MAX);

    /// `us` microseconds.
    pub const fn from_micros(us: u64) -> Self {
        Self(us)
    }
    /// `ms` milliseconds.
    pub const fn from_millis(ms: u64) -> Self {
        Self(ms.saturating_mul(1_000))
    }
    /// `s` seconds.
    pub const fn from_secs(s: u64) -> Self {
        Self(s.saturating_mul(1_000_000))
    }
    /// The period of a rate of `hz` (rounded down to a microsecond; 0 Hz gives [`Self::MAX`]).
    pub const fn from_hz(hz: u32) -> Self {
        if hz == 0 {
            Self::MAX
        } else {
            Self(1_000_000 / hz as u64)
        }
    }
    /// `s` seconds (rounded to the nearest microsecond; negative and NaN give zero).
    pub fn from_secs_f32(s: f32) -> Self {
        if s.is_nan() || s <= 0.0 {
            Self(0)
        } else {
            Self((s * 1e6 + 0.5) as u64)
        }
    }
    /// Microseconds.
    pub const fn as_micros(self) -> u64 {
        self.0
    }
    /// Milliseconds (rounded down).
    pub const fn as_millis(self) -> u64 {
        self.0 / 1_000
    }
    /// Seconds.
    pub fn as_secs_f32(self) -> f32 {
        self.0 as f32 * 1e-6
    }
    /// Seconds, in double precision.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-6
    }
    /// `self - other`, or zero.
    pub const fn saturating_sub(self, other: Self) -> Self {
        Self(self.0.saturating_sub(other.0))
    }
    /// `self * n`, saturating.
    pub const fn saturating_mul(self, n: u64) -> Self {
        Self(self.0.saturating_mul(n))
    }
}

impl Add for Duration {
    type Output = Self;
    fn add(self, rhs: Self) -> Self {
        Self(self.0.saturating_add(rhs.0))
    }
}

impl Sub for Duration {
    type Output = Self;
    fn sub(self, rhs: Self) -> Self {
        self.saturating_sub(rhs)
    }
}

macro_rules! instant_type {
    ($(#[$doc:meta])* $name:ident) => {
        $(#[$doc])*
        #[derive(
            Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize,
        )]
        #[serde(transparent)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub struct $name(u64);

        impl $name {
            /// The clock's epoch (a board's boot, the world's start).
            pub const ZERO: Self = Self(0);

            /// `us` microseconds after the epoch.
            pub const fn from_micros(us: u64) -> Self {
                Self(us)
            }
            /// Microseconds since the epoch.
            pub const fn as_micros(self) -> u64 {
                self.0
            }
            /// Seconds since the epoch, in double precision.
            pub fn as_secs_f64(self) -> f64 {
                self.0 as f64 * 1e-6
            }
            /// Time from `earlier` to `self` (zero if `earlier` is later).
            pub const fn since(self, earlier: Self) -> Duration {
                Duration(self.0.saturating_sub(earlier.0))
            }
            /// Time from `earlier` to `self` as the unsigned difference of the two counts,
            /// modulo 2^64 µs: an `earlier` that is later gives nearly the whole clock where
            /// [`Self::since`] gives zero. For arithmetic that relies on that difference.
            pub const fn wrapping_since(self, earlier: Self) -> Duration {
                Duration(self.0.wrapping_sub(earlier.0))
            }
            /// `self + d`, or `None` past the end of the clock.
            pub const fn checked_add(self, d: Duration) -> Option<Self> {
                match self.0.checked_add(d.0) {
                    Some(t) => Some(Self(t)),
                    None => None,
                }
            }
            /// The 32-bit wire timestamp of this instant.
            pub const fn to_wire(self) -> WireTime {
                WireTime(self.0 as u32)
            }
        }

        impl Add<Duration> for $name {
            type Output = Self;
            fn add(self, d: Duration) -> Self {
                Self(self.0.saturating_add(d.0))
            }
        }

        impl AddAssign<Duration> for $name {
            fn add_assign(&mut self, d: Duration) {
                *self = *self + d;
            }
        }

        impl Sub<Duration> for $name {
            type Output = Self;
            fn sub(self, d: Duration) -> Self {
                Self(self.0.saturating_sub(d.0))
            }
        }

        impl Sub for $name {
            type Output = Duration;
            fn sub(self, earlier: Self) -> Duration {
                self.since(earlier)
            }
        }
    };
}

instant_type!(
    /// A point on a board's own clock, µs since its boot: what the flight libraries run on.
    Instant
);

instant_type!(
    /// A point on the simulated world's clock, µs since the world started.
    WorldTime
);

/// A 64-bit microsecond timeline a [`WrapExtender`] can extend wire times onto: [`Instant`]
/// or [`WorldTime`].
pub trait Timeline: Copy + Ord {
    /// The point `us` microseconds after the timeline's epoch.
    fn from_micros(us: u64) -> Self;
}

impl Timeline for Instant {
    fn from_micros(us: u64) -> Self {
        Self(us)
    }
}

impl Timeline for WorldTime {
    fn from_micros(us: u64) -> Self {
        Self(us)
    }
}

impl WorldTime {
    /// Lockstep: the world's time drives a board's flight clock (the `hil` and `qemu` flavours,
    /// where the host's world paces the flight code). The one sanctioned crossing from world
    /// time to board time.
    pub const fn as_flight_clock(self) -> Instant {
        Instant(self.0)
    }
}

/// A timestamp as messages carry it: microseconds, wrapping at 2^32 (every 71.6 minutes).
/// Back on a 64-bit timeline through a [`WrapExtender`].
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize,
)]
#[serde(transparent)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WireTime(pub u32);

impl WireTime {
    /// The wire time `us` microseconds after the sender's epoch, modulo 2^32.
    pub const fn from_micros(us: u32) -> Self {
        Self(us)
    }
    /// The raw microseconds.
    pub const fn as_micros(self) -> u32 {
        self.0
    }
    /// Time from `earlier` to `self` on the wrapping clock: correct across one wrap, for
    /// timestamps less than 2^32 µs apart. Wire times are compared this way, never with `<`.
    pub const fn wrapping_since(self, earlier: Self) -> Duration {
        Duration(self.0.wrapping_sub(earlier.0) as u64)
    }
}

/// Extends [`WireTime`]s from one sender onto a monotonic 64-bit timeline `T` ([`Instant`] for
/// a board's clock, [`WorldTime`] for the simulated world's).
///
/// A decrease of more than half the 32-bit range is a wrap; a smaller decrease is a sample out
/// of order and maps just below the previous one (the timeline itself never goes back:
/// [`WrapExtender::latest`]). The first timestamp maps to itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WrapExtender<T> {
    last: Option<u32>,
    high: u64,
    latest: u64,
    timeline: PhantomData<T>,
}

impl<T: Timeline> Default for WrapExtender<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Timeline> WrapExtender<T> {
    /// An extender that has seen nothing.
    pub const fn new() -> Self {
        Self {
            last: None,
            high: 0,
            latest: 0,
            timeline: PhantomData,
        }
    }

    /// Maps `t` onto the 64-bit timeline.
    pub fn extend(&mut self, t: WireTime) -> T {
        let t = t.0;
        if let Some(last) = self.last {
            if t < last && last - t > u32::MAX / 2 {
                self.high = self.high.saturating_add(1 << 32);
            } else if t > last && t - last > u32::MAX / 2 && self.high > 0 {
                // A sample from before the last wrap, arriving late: it does not move the
                // reference.
                return T::from_micros((self.high - (1 << 32)) | u64::from(t));
            }
        }
        self.last = Some(t);
        let v = self.high | u64::from(t);
        self.latest = self.latest.max(v);
        T::from_micros(v)
    }

    /// The latest point seen on the timeline (the epoch before the first timestamp).
    pub fn latest(&self) -> T {
        T::from_micros(self.latest)
    }

    /// True once a timestamp has been seen.
    pub const fn started(&self) -> bool {
        self.last.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn durations_and_instants() {
        assert_eq!(Duration::from_hz(512).as_micros(), 1953);
        assert_eq!(Duration::from_millis(20), Duration::from_micros(20_000));
        assert_eq!(Duration::from_secs_f32(-1.0), Duration::ZERO);
        assert_eq!(Duration::from_secs_f32(f32::NAN), Duration::ZERO);
        let t = Instant::from_micros(1_000);
        assert_eq!((t + Duration::from_micros(500)).as_micros(), 1_500);
        assert_eq!(t - Instant::from_micros(2_000), Duration::ZERO);
        assert_eq!(t.wrapping_since(Instant::from_micros(1_001)), Duration::MAX);
        assert_eq!(
            t.wrapping_since(Instant::from_micros(400)),
            Duration::from_micros(600)
        );
        assert_eq!(
            Instant::from_micros(u64::MAX) + Duration::from_secs(1),
            Instant::from_micros(u64::MAX)
        );
        assert_eq!(
            WorldTime::from_micros(7).as_flight_clock(),
            Instant::from_micros(7)
        );
        assert_eq!(Instant::from_micros((1 << 32) + 5).to_wire(), WireTime(5));
    }

    #[test]
    fn wire_times_compare_across_a_wrap() {
        assert_eq!(
            WireTime(5).wrapping_since(WireTime(u32::MAX - 4)),
            Duration::from_micros(10)
        );
        assert_eq!(
            WireTime(300).wrapping_since(WireTime(100)),
            Duration::from_micros(200)
        );
    }

    #[test]
    fn serialised_as_plain_integers() {
        let mut buf = [0u8; 8];
        let a = postcard::to_slice(&WireTime(300), &mut buf)
            .unwrap()
            .to_vec();
        let b = postcard::to_slice(&300u32, &mut buf).unwrap().to_vec();
        assert_eq!(a, b);
    }

    #[test]
    fn extender_wraps_and_tolerates_reordering() {
        let mut x = WrapExtender::<Instant>::new();
        let us = |x: Instant| x.as_micros();
        assert!(!x.started());
        assert_eq!(
            us(x.extend(WireTime(u32::MAX - 10))),
            u64::from(u32::MAX - 10)
        );
        assert_eq!(us(x.extend(WireTime(5))), (1 << 32) + 5);
        // A late sample from before the wrap.
        assert_eq!(
            us(x.extend(WireTime(u32::MAX - 20))),
            u64::from(u32::MAX - 20)
        );
        assert_eq!(us(x.extend(WireTime(6))), (1 << 32) + 6);
        // Small reordering after the wrap.
        assert_eq!(us(x.extend(WireTime(4))), (1 << 32) + 4);
        assert_eq!(us(x.latest()), (1 << 32) + 6);
    }

    proptest! {
        /// A monotonic 64-bit timeline sent as wire times in steps below half the range comes
        /// back exactly.
        #[test]
        fn extender_recovers_monotonic_timelines(start in 0u64..(1 << 40), steps in proptest::collection::vec(0u64..(1 << 31), 1..200)) {
            let mut x = WrapExtender::<WorldTime>::new();
            let mut t = start & 0xFFFF_FFFF;
            prop_assert_eq!(x.extend(WireTime(t as u32)).as_micros(), t);
            for s in steps {
                t += s;
                prop_assert_eq!(x.extend(WorldTime::from_micros(t).to_wire()).as_micros(), t);
                prop_assert_eq!(x.latest().as_micros(), t);
            }
        }
    }
}
