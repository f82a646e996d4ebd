//! The flight battery: the supply voltage the firmware reads (PC4 through the Lisa/MX's
//! divider, [`crate::board::BATTERY_ADC`]) judged against three thresholds.
//!
//! A 1S LiPo sags under load: its terminal voltage is the resting voltage less the current
//! times its internal resistance, and four brushed motors draw amperes. Judged raw, a drone
//! would land at the first climb on a full battery. So each sample gets the sag added back,
//! estimated from the motor duties the autopilot commands and the voltage read: a brushed
//! motor's speed follows its duty times the supply voltage, a propeller's power the cube of
//! its speed, and the battery's current is that power over its voltage, so the current is
//! `full_throttle_current_a` (at [`NOMINAL_V`]) × the mean of the duties cubed × (V /
//! [`NOMINAL_V`])². A first-order low-pass filter then takes out the ADC noise and the PWM
//! ripple.
//!
//! * Below [`BatteryConfig::arm_v`] an `Arm` is refused (on the ground the motors are off and
//!   the reading is the resting voltage).
//! * Below [`BatteryConfig::low_v`] in flight: [`BatteryState::Low`], the autopilot lands.
//! * Below [`BatteryConfig::critical_v`] in flight: [`BatteryState::Critical`], it lands at
//!   once and descends fast (a cell run this flat is minutes from brown-out).
//!
//! A verdict holds until the next arming: the voltage recovers as soon as the thrust drops,
//! which must not send a landing drone back up.

pub use protocol::BatteryState;
use protocol::BatteryTelemetry;
use timebase::{Duration, Instant};

/// Battery thresholds and the sag model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatteryConfig {
    /// `Arm` is refused below this resting voltage, V.
    pub arm_v: f32,
    /// In flight below this (sag compensated), the autopilot lands, V.
    pub low_v: f32,
    /// In flight below this (sag compensated), it lands at once, descending fast, V.
    pub critical_v: f32,
    /// The battery's internal resistance with its leads, Ω (the sag per ampere).
    pub resistance_ohm: f32,
    /// Battery current with all four motors at full duty on a [`NOMINAL_V`] supply, A.
    pub full_throttle_current_a: f32,
    /// Time constant of the low-pass filter over the compensated voltage.
    pub filter_tau: Duration,
}

impl Default for BatteryConfig {
    /// A 1S LiPo of a 40 g quad: 3.75 V to arm (about a quarter of its charge at rest), land
    /// at 3.6 V (about 5 % left), at once at 3.4 V (nearly flat); 0.12 Ω (a 250-300 mAh cell
    /// with its JST lead); 11 A at full duty (four 7 mm coreless motors; 3 A at the 65 %
    /// hover duty).
    fn default() -> Self {
        Self {
            arm_v: 3.75,
            low_v: 3.6,
            critical_v: 3.4,
            resistance_ohm: 0.12,
            full_throttle_current_a: 11.0,
            filter_tau: Duration::from_secs(1),
        }
    }
}

/// The supply voltage [`BatteryConfig::full_throttle_current_a`] is given at, V.
pub const NOMINAL_V: f32 = 3.9;

/// Plausible supply readings, V: anything else (a broken divider, an ADC fault) is rejected.
const PLAUSIBLE_V: core::ops::RangeInclusive<f32> = 0.5..=10.0;

/// The battery monitor: filter, sag compensation and verdict.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatteryMonitor {
    cfg: BatteryConfig,
    /// The last accepted reading (V) and when it was taken.
    last: Option<(Instant, f32)>,
    /// The filtered, compensated voltage, V.
    resting_v: f32,
    /// The verdict of this flight (latched).
    state: BatteryState,
    rejected: u32,
}

impl BatteryMonitor {
    /// No reading yet.
    pub fn new(cfg: BatteryConfig) -> Self {
        Self {
            cfg,
            last: None,
            resting_v: 0.0,
            state: BatteryState::Ok,
            rejected: 0,
        }
    }

    /// Takes a new configuration (used from the next sample on).
    pub fn set_config(&mut self, cfg: BatteryConfig) {
        self.cfg = cfg;
    }

    /// The battery current the motor duties (0..=1) draw from a supply at `volts`, A (the
    /// model in the module docs).
    pub fn current_a(&self, duties: &[f32; 4], volts: f32) -> f32 {
        let mean_cube = duties
            .iter()
            .map(|d| {
                let d = d.clamp(0.0, 1.0);
                d * d * d
            })
            .sum::<f32>()
            / 4.0;
        let v = volts / NOMINAL_V;
        self.cfg.full_throttle_current_a * mean_cube * v * v
    }

    /// A supply reading of `volts` taken at `now` while the motors ran at `duties`. In
    /// flight (`flying`), the verdict may worsen; it never improves until
    /// [`BatteryMonitor::rearm`]. An implausible reading (not finite, outside 0.5-10 V) is
    /// counted in [`BatteryMonitor::rejected`] and changes nothing.
    pub fn on_sample(&mut self, volts: f32, duties: &[f32; 4], flying: bool, now: Instant) {
        if !volts.is_finite() || !PLAUSIBLE_V.contains(&volts) {
            self.rejected = self.rejected.wrapping_add(1);
            return;
        }
        let compensated = volts + self.cfg.resistance_ohm * self.current_a(duties, volts);
        self.resting_v = match self.last {
            Some((t, _)) => {
                // µs, as are the time constant's.
                let dt = now.since(t).as_micros() as f32;
                let alpha = dt / (dt + self.cfg.filter_tau.as_micros() as f32).max(1.0);
                self.resting_v + alpha * (compensated - self.resting_v)
            }
            None => compensated,
        };
        self.last = Some((now, volts));
        if flying {
            let verdict = if self.resting_v < self.cfg.critical_v {
                BatteryState::Critical
            } else if self.resting_v < self.cfg.low_v {
                BatteryState::Low
            } else {
                BatteryState::Ok
            };
            self.state = worst(self.state, verdict);
        }
    }

    /// A new flight begins: the verdict starts again from the voltage of now.
    pub fn rearm(&mut self) {
        self.state = BatteryState::Ok;
    }

    /// The verdict of this flight.
    pub fn state(&self) -> BatteryState {
        self.state
    }

    /// The filtered, sag-compensated voltage, V (`None`: no reading yet).
    pub fn resting_v(&self) -> Option<f32> {
        self.last.map(|_| self.resting_v)
    }

    /// The last accepted reading, V, and when it was taken.
    pub fn last_reading(&self) -> Option<(Instant, f32)> {
        self.last
    }

    /// True when an `Arm` may proceed: no reading yet (a build without a supply input, such
    /// as a hardware-in-the-loop board) or a resting voltage at or above
    /// [`BatteryConfig::arm_v`].
    pub fn arm_ok(&self) -> bool {
        self.resting_v().is_none_or(|v| v >= self.cfg.arm_v)
    }

    /// Implausible readings rejected since boot (wrapping).
    pub fn rejected(&self) -> u32 {
        self.rejected
    }

    /// What telemetry reports (`None`: no reading yet).
    pub fn telemetry(&self) -> Option<BatteryTelemetry> {
        self.last.map(|(_, v)| BatteryTelemetry {
            voltage_v: v,
            resting_v: self.resting_v,
            state: self.state,
        })
    }
}

fn rank(s: BatteryState) -> u8 {
    match s {
        BatteryState::Ok => 0,
        BatteryState::Low => 1,
        BatteryState::Critical => 2,
    }
}

fn worst(a: BatteryState, b: BatteryState) -> BatteryState {
    if rank(b) > rank(a) {
        b
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;

    const HOVER: [f32; 4] = [0.65; 4];
    const OFF: [f32; 4] = [0.0; 4];

    /// Feeds `volts` at 10 Hz for `seconds` from `t0_us`; returns the time after.
    fn feed(
        m: &mut BatteryMonitor,
        volts: f32,
        duties: &[f32; 4],
        flying: bool,
        t0_us: u64,
        seconds: u64,
    ) -> u64 {
        let mut t = t0_us;
        for _ in 0..seconds * 10 {
            t += 100_000;
            m.on_sample(volts, duties, flying, at(t));
        }
        t
    }

    #[test]
    fn the_sag_under_hover_thrust_is_added_back() {
        let cfg = BatteryConfig::default();
        let mut m = BatteryMonitor::new(cfg);
        let i = m.current_a(&HOVER, NOMINAL_V);
        assert!((i - 11.0 * 0.65f32.powi(3)).abs() < 1e-4, "{i}");
        // Lower voltage, slower rotors: less current for the same duties.
        assert!(m.current_a(&HOVER, 3.5) < i);
        assert_eq!(m.current_a(&OFF, NOMINAL_V), 0.0);
        // Under hover thrust a reading below the landing threshold is a good battery.
        let reading = 3.55;
        assert!(reading < cfg.low_v);
        feed(&mut m, reading, &HOVER, true, 0, 10);
        let resting = reading + cfg.resistance_ohm * m.current_a(&HOVER, reading);
        assert!((m.resting_v().unwrap() - resting).abs() < 1e-3);
        assert!(resting > 3.85, "{resting}");
        assert_eq!(m.state(), BatteryState::Ok);
    }

    #[test]
    fn thresholds_land_then_land_now_and_latch() {
        let mut m = BatteryMonitor::new(BatteryConfig::default());
        let mut t = feed(&mut m, 3.8, &OFF, false, 0, 2);
        assert!(m.arm_ok());
        m.rearm();
        t = feed(&mut m, 3.65, &OFF, true, t, 5);
        assert_eq!(m.state(), BatteryState::Ok);
        // One bad sample does not trip it (the filter); a sustained drop does.
        m.on_sample(3.3, &OFF, true, at(t + 100_000));
        assert_eq!(m.state(), BatteryState::Ok);
        t = feed(&mut m, 3.5, &OFF, true, t + 100_000, 5);
        assert_eq!(m.state(), BatteryState::Low);
        t = feed(&mut m, 3.2, &OFF, true, t, 5);
        assert_eq!(m.state(), BatteryState::Critical);
        // The voltage recovers when the thrust drops: the verdict holds for the flight.
        t = feed(&mut m, 3.9, &OFF, true, t, 10);
        assert_eq!(m.state(), BatteryState::Critical);
        // On the ground it is not judged; the next arming starts afresh.
        feed(&mut m, 3.9, &OFF, false, t, 1);
        m.rearm();
        assert_eq!(m.state(), BatteryState::Ok);
    }

    #[test]
    fn arming_needs_the_arm_voltage_or_no_reading() {
        let mut m = BatteryMonitor::new(BatteryConfig::default());
        assert!(m.arm_ok(), "no supply input: not judged");
        feed(&mut m, 3.7, &OFF, false, 0, 5);
        assert!(!m.arm_ok());
        // On the ground the verdict is not changed, whatever the voltage.
        assert_eq!(m.state(), BatteryState::Ok);
        feed(&mut m, 4.1, &OFF, false, 500_000, 10);
        assert!(m.arm_ok());
    }

    #[test]
    fn implausible_readings_are_counted_and_ignored() {
        let mut m = BatteryMonitor::new(BatteryConfig::default());
        for v in [f32::NAN, f32::INFINITY, -1.0, 0.0, 12.0] {
            m.on_sample(v, &OFF, true, at(1_000));
        }
        assert_eq!(m.rejected(), 5);
        assert_eq!(m.resting_v(), None);
        assert_eq!(m.telemetry(), None);
        m.on_sample(3.9, &OFF, true, at(2_000));
        let tel = m.telemetry().unwrap();
        assert_eq!((tel.voltage_v, tel.resting_v), (3.9, 3.9));
    }
}
