//! What releases the periodic tasks (`guidance`, `gyro_tx`, `telemetry`) and which clock the
//! library sees.
//!
//! * Real flavour: SysTick. [`Tick::wait`] sleeps until the next release (fixed phase, no
//!   drift) and returns the board time.
//! * `hil` and `qemu` flavours: lockstep with the host (see [`autopilot::lockstep`]). The
//!   library clock is the world time of the host's IMU samples; `imu_indi` releases the
//!   periodic tasks from [`autopilot::lockstep::WorldTimers`] and [`Tick::wait`] returns the
//!   world time of the release.

#[cfg(not(any(feature = "qemu", feature = "hil")))]
use super::{clock, Mono};
#[cfg(not(any(feature = "qemu", feature = "hil")))]
use rtic_monotonics::Timebase as _;

/// Release of one periodic task (real flavour: a SysTick period).
#[cfg(not(any(feature = "qemu", feature = "hil")))]
pub struct Tick {
    period: <Mono as rtic_monotonics::Timebase>::Duration,
    next: Option<<Mono as rtic_monotonics::Timebase>::Instant>,
}

#[cfg(not(any(feature = "qemu", feature = "hil")))]
impl Tick {
    /// Every `period_us` µs (rounded to the 1 ms SysTick tick, at least one tick); the first
    /// release is immediate.
    pub fn every(period_us: u32) -> Self {
        Self {
            period: <Mono as rtic_monotonics::Timebase>::Duration::from_ticks(
                (period_us / 1_000).max(1),
            ),
            next: None,
        }
    }

    /// Waits for the next release; returns the library time (board µs).
    pub async fn wait(&mut self) -> u64 {
        let at = match self.next {
            Some(t) => {
                Mono::delay_until(t).await;
                t
            }
            None => Mono::now(),
        };
        self.next = Some(at + self.period);
        clock::now_us()
    }
}

/// The periodic tasks release themselves on hardware: nothing for `imu_indi` to do.
#[cfg(not(any(feature = "qemu", feature = "hil")))]
pub struct Releases;

#[cfg(not(any(feature = "qemu", feature = "hil")))]
impl Releases {
    /// Nothing (the SysTick releases the periodic tasks).
    pub fn release(&mut self, _now_us: u64) {}
}

/// Release of one periodic task (lockstep flavours): world times sent by `imu_indi`.
#[cfg(any(feature = "qemu", feature = "hil"))]
pub struct Tick(pub rtic_sync::channel::Receiver<'static, u64, 1>);

#[cfg(any(feature = "qemu", feature = "hil"))]
impl Tick {
    /// Waits for the next release; returns its world time, µs.
    pub async fn wait(&mut self) -> u64 {
        match self.0.recv().await {
            Ok(t) => t,
            // The sender lives as long as the program; without one, never release again.
            Err(_) => core::future::pending().await,
        }
    }
}

/// The senders `imu_indi` releases the periodic tasks with (lockstep flavours). A release that
/// finds its task still busy with the previous one is skipped (an overrun, as on hardware).
#[cfg(any(feature = "qemu", feature = "hil"))]
pub struct Releases {
    /// To `guidance`.
    pub guidance: rtic_sync::channel::Sender<'static, u64, 1>,
    /// To `gyro_tx`.
    pub gyro_tx: rtic_sync::channel::Sender<'static, u64, 1>,
    /// To `telemetry`.
    pub telemetry: rtic_sync::channel::Sender<'static, u64, 1>,
    /// Release times on the world clock.
    pub timers: autopilot::lockstep::WorldTimers,
}

#[cfg(any(feature = "qemu", feature = "hil"))]
impl Releases {
    /// Releases what is due at world time `now_us`.
    pub fn release(&mut self, now_us: u64) {
        let due = self.timers.due(now_us);
        if due.guidance {
            let _ = self.guidance.try_send(now_us);
        }
        if due.gyro_tx {
            let _ = self.gyro_tx.try_send(now_us);
        }
        if due.telemetry {
            let _ = self.telemetry.try_send(now_us);
        }
    }
}
