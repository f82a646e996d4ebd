//! Flight mode and failsafes.
//!
//! * A kill (RC or command) always wins: motors off at once, from any mode, until the next arm.
//! * Arming needs a fresh IMU sample and a fresh height measurement.
//! * No valid velocity estimate for [`FailsafeConfig::estimate_timeout_us`] (link lost, camera
//!   blind, quality low) -> [`FlightMode::HoverNoEstimate`]: level hover on the guidance trim at
//!   the current height setpoint. A valid estimate within
//!   [`FailsafeConfig::hover_before_land_us`] resumes the flight; otherwise -> `Landing`. A
//!   drone that has had no valid estimate at all since it was armed goes to `Landing` at once
//!   instead: waiting is for a camera that may come back, and every second of blind hover is
//!   drift nobody measures (a trim error of 0.6 deg is 0.1 m/s² of it).
//! * Height measurement stale for [`FailsafeConfig::height_timeout_us`] in flight -> `Landing`
//!   (the caller descends open-loop on reduced thrust).
//! * IMU stale for [`FailsafeConfig::imu_timeout_us`] while armed -> [`FlightMode::ImuFault`]:
//!   motors off (nothing can stabilise the drone without rates).
//! * `Landing` ends in `Disarmed` when the caller reports touchdown. Every landing keeps its
//!   [`LandReason`] ([`Failsafe::land_reason`]) until the next arming.
//!
//! [`FlightMode`] is the protocol's type: telemetry carries it as it is.

use protocol::PilotCommand;

pub use protocol::FlightMode;

/// Why the drone is landing (or landed last).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LandReason {
    /// A `Land` pilot command.
    Commanded,
    /// No valid velocity estimate (a blind camera, a lost link, no texture in view).
    NoEstimate,
    /// The height measurement went stale.
    HeightLost,
    /// The avoidance FSM found no way to go within its timeouts.
    SearchExhausted,
    /// The battery fell below `bat_low_v`.
    LowBattery,
    /// The battery fell below `bat_critical_v`.
    CriticalBattery,
}

impl LandReason {
    /// Short lower-case name for logs and tables.
    pub fn name(self) -> &'static str {
        match self {
            LandReason::Commanded => "commanded",
            LandReason::NoEstimate => "no texture",
            LandReason::HeightLost => "height lost",
            LandReason::SearchExhausted => "search exhausted",
            LandReason::LowBattery => "low battery",
            LandReason::CriticalBattery => "critical battery",
        }
    }
}

/// Failsafe timings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FailsafeConfig {
    /// No valid estimate for this long -> hover, µs.
    pub estimate_timeout_us: u64,
    /// Hover without estimate for this long -> land, µs.
    pub hover_before_land_us: u64,
    /// No IMU sample for this long while armed -> motors off, µs.
    pub imu_timeout_us: u64,
    /// No height measurement for this long in flight -> land, µs.
    pub height_timeout_us: u64,
}

impl Default for FailsafeConfig {
    fn default() -> Self {
        Self {
            estimate_timeout_us: 500_000,
            hover_before_land_us: 1_500_000,
            imu_timeout_us: 20_000,
            height_timeout_us: 500_000,
        }
    }
}

/// Freshness of the inputs at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Freshness {
    /// Time of the last valid velocity estimate, µs.
    pub last_valid_estimate_us: Option<u64>,
    /// Time of the last usable IMU sample, µs.
    pub last_imu_us: Option<u64>,
    /// Time of the last usable height measurement, µs.
    pub last_height_us: Option<u64>,
}

fn fresh(t: Option<u64>, now: u64, timeout: u64) -> bool {
    matches!(t, Some(t) if now.saturating_sub(t) <= timeout)
}

/// Mode logic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Failsafe {
    cfg: FailsafeConfig,
    mode: FlightMode,
    since_us: u64,
    armed_us: u64,
    /// A valid estimate has come since the last arming.
    seen_estimate: bool,
    land_reason: Option<LandReason>,
}

impl Failsafe {
    /// Takes a new configuration, keeping the state (used from the next step on).
    pub fn set_config(&mut self, cfg: FailsafeConfig) {
        self.cfg = cfg;
    }

    /// Disarmed at time 0.
    pub fn new(cfg: FailsafeConfig) -> Self {
        Self {
            cfg,
            mode: FlightMode::Disarmed,
            since_us: 0,
            armed_us: 0,
            seen_estimate: false,
            land_reason: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &FailsafeConfig {
        &self.cfg
    }

    /// Current mode.
    pub fn mode(&self) -> FlightMode {
        self.mode
    }

    /// When the current mode began, µs.
    pub fn since_us(&self) -> u64 {
        self.since_us
    }

    /// Why the drone is landing, or why it landed last (`None`: no landing since the last
    /// arming).
    pub fn land_reason(&self) -> Option<LandReason> {
        self.land_reason
    }

    /// Lands for `reason` if the motors run and it is not landing already (the first reason
    /// is kept). Returns the new mode.
    pub fn land(&mut self, reason: LandReason, now_us: u64) -> FlightMode {
        if self.mode.motors_enabled() && self.mode != FlightMode::Landing {
            self.land_reason = Some(reason);
            self.set(FlightMode::Landing, now_us);
        }
        self.mode
    }

    fn set(&mut self, m: FlightMode, now: u64) {
        if m != self.mode {
            self.mode = m;
            self.since_us = now;
        }
    }

    /// True when the IMU is fresh at `now_us`.
    pub fn imu_fresh(&self, f: &Freshness, now_us: u64) -> bool {
        fresh(f.last_imu_us, now_us, self.cfg.imu_timeout_us)
    }

    /// Applies a pilot command. Returns the new mode. `Arm` is refused (mode unchanged) unless
    /// disarmed/killed/faulted with a fresh IMU and height.
    pub fn command(&mut self, cmd: PilotCommand, f: &Freshness, now_us: u64) -> FlightMode {
        match cmd {
            PilotCommand::Kill => self.set(FlightMode::Killed, now_us),
            PilotCommand::Land => {
                self.land(LandReason::Commanded, now_us);
            }
            PilotCommand::Arm => {
                let grounded = matches!(
                    self.mode,
                    FlightMode::Disarmed | FlightMode::Killed | FlightMode::ImuFault
                );
                if grounded
                    && self.imu_fresh(f, now_us)
                    && fresh(f.last_height_us, now_us, self.cfg.height_timeout_us)
                {
                    self.set(FlightMode::Flying, now_us);
                    self.armed_us = now_us;
                    self.seen_estimate = false;
                    self.land_reason = None;
                }
            }
        }
        self.mode
    }

    /// Reports touchdown while landing: disarms.
    pub fn landed(&mut self, now_us: u64) {
        if self.mode == FlightMode::Landing {
            self.set(FlightMode::Disarmed, now_us);
        }
    }

    /// Re-evaluates the timeouts at `now_us`. Returns the new mode.
    pub fn update(&mut self, f: &Freshness, now_us: u64) -> FlightMode {
        if !self.mode.motors_enabled() {
            return self.mode;
        }
        if !self.imu_fresh(f, now_us) {
            self.set(FlightMode::ImuFault, now_us);
            return self.mode;
        }
        if !fresh(f.last_height_us, now_us, self.cfg.height_timeout_us) {
            return self.land(LandReason::HeightLost, now_us);
        }
        // The estimate clock starts at arming: a drone armed without estimates gets the same
        // grace period as one that lost them.
        let last_est = match f.last_valid_estimate_us {
            Some(t) => t.max(self.armed_us),
            None => self.armed_us,
        };
        let est_ok = now_us.saturating_sub(last_est) <= self.cfg.estimate_timeout_us;
        if matches!(f.last_valid_estimate_us, Some(t) if t > self.armed_us) {
            self.seen_estimate = true;
        }
        match self.mode {
            FlightMode::Flying if !est_ok && !self.seen_estimate => {
                self.land(LandReason::NoEstimate, now_us);
            }
            FlightMode::Flying if !est_ok => self.set(FlightMode::HoverNoEstimate, now_us),
            FlightMode::HoverNoEstimate => {
                if est_ok {
                    self.set(FlightMode::Flying, now_us);
                } else if now_us.saturating_sub(self.since_us) >= self.cfg.hover_before_land_us {
                    self.land(LandReason::NoEstimate, now_us);
                }
            }
            _ => {}
        }
        self.mode
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000;

    fn all_fresh(now: u64) -> Freshness {
        Freshness {
            last_valid_estimate_us: Some(now),
            last_imu_us: Some(now),
            last_height_us: Some(now),
        }
    }

    fn armed(now: u64) -> Failsafe {
        let mut fs = Failsafe::new(FailsafeConfig::default());
        assert_eq!(
            fs.command(PilotCommand::Arm, &all_fresh(now), now),
            FlightMode::Flying
        );
        fs
    }

    #[test]
    fn arm_needs_fresh_imu_and_height() {
        let mut fs = Failsafe::new(FailsafeConfig::default());
        let mut f = all_fresh(1000 * MS);
        f.last_imu_us = None;
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, 1000 * MS),
            FlightMode::Disarmed
        );
        let mut f = all_fresh(1000 * MS);
        f.last_height_us = Some(0);
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, 1000 * MS),
            FlightMode::Disarmed
        );
        // Estimates are not needed to arm.
        let mut f = all_fresh(1000 * MS);
        f.last_valid_estimate_us = None;
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, 1000 * MS),
            FlightMode::Flying
        );
    }

    #[test]
    fn kill_always_wins() {
        for start in [
            FlightMode::Flying,
            FlightMode::HoverNoEstimate,
            FlightMode::Landing,
        ] {
            let mut fs = armed(0);
            fs.set(start, 0);
            assert_eq!(
                fs.command(PilotCommand::Kill, &all_fresh(10 * MS), 10 * MS),
                FlightMode::Killed
            );
            assert!(!fs.mode().motors_enabled());
            // Land does not revive a killed drone; timeouts leave it alone.
            fs.command(PilotCommand::Land, &all_fresh(20 * MS), 20 * MS);
            fs.update(&Freshness::default(), 30 * MS);
            assert_eq!(fs.mode(), FlightMode::Killed);
        }
        let mut fs = Failsafe::new(FailsafeConfig::default());
        fs.command(PilotCommand::Kill, &all_fresh(0), 0);
        assert_eq!(fs.mode(), FlightMode::Killed);
        // Re-arming after a kill is allowed.
        assert_eq!(
            fs.command(PilotCommand::Arm, &all_fresh(MS), MS),
            FlightMode::Flying
        );
    }

    #[test]
    fn estimate_loss_hovers_then_lands_or_recovers() {
        let mut fs = armed(0);
        let mut f = all_fresh(0);
        f.last_valid_estimate_us = Some(100 * MS);
        let at = |t: u64, f: &Freshness| Freshness {
            last_imu_us: Some(t),
            last_height_us: Some(t),
            ..*f
        };
        // 500 ms after the last valid estimate: still flying; 1 µs later: hover.
        assert_eq!(fs.update(&at(600 * MS, &f), 600 * MS), FlightMode::Flying);
        assert_eq!(
            fs.update(&at(600 * MS + 1, &f), 600 * MS + 1),
            FlightMode::HoverNoEstimate
        );
        // An estimate comes back: flying again.
        f.last_valid_estimate_us = Some(1000 * MS);
        assert_eq!(fs.update(&at(1000 * MS, &f), 1000 * MS), FlightMode::Flying);
        // Lost again at 1.5 s: hover from 1.5 s, land 1.5 s later.
        fs.update(&at(1501 * MS, &f), 1501 * MS);
        assert_eq!(fs.mode(), FlightMode::HoverNoEstimate);
        assert_eq!(
            fs.update(&at(3000 * MS, &f), 3000 * MS),
            FlightMode::HoverNoEstimate
        );
        assert_eq!(
            fs.update(&at(3001 * MS, &f), 3001 * MS),
            FlightMode::Landing
        );
        // Landing does not go back to flying on its own, and ends on touchdown.
        f.last_valid_estimate_us = Some(4600 * MS);
        assert_eq!(
            fs.update(&at(4600 * MS, &f), 4600 * MS),
            FlightMode::Landing
        );
        fs.landed(5000 * MS);
        assert_eq!(fs.mode(), FlightMode::Disarmed);
        assert_eq!(fs.land_reason(), Some(LandReason::NoEstimate));
    }

    /// Armed without estimates: the estimate timeout's grace, then a landing at once (nothing
    /// was ever seen that could come back).
    #[test]
    fn armed_without_estimates_gets_the_grace_period_then_lands() {
        let mut fs = Failsafe::new(FailsafeConfig::default());
        let mut f = all_fresh(10 * 1000 * MS);
        f.last_valid_estimate_us = None;
        fs.command(PilotCommand::Arm, &f, 10_000 * MS);
        let f2 = |t| Freshness {
            last_valid_estimate_us: None,
            last_imu_us: Some(t),
            last_height_us: Some(t),
        };
        assert_eq!(fs.update(&f2(10_400 * MS), 10_400 * MS), FlightMode::Flying);
        assert_eq!(
            fs.update(&f2(10_501 * MS), 10_501 * MS),
            FlightMode::Landing
        );
        // An estimate from before the arming does not count as seen in this flight.
        let mut fs = Failsafe::new(FailsafeConfig::default());
        fs.command(PilotCommand::Arm, &f, 10_000 * MS);
        let before = |t| Freshness {
            last_valid_estimate_us: Some(9_900 * MS),
            ..f2(t)
        };
        assert_eq!(
            fs.update(&before(10_501 * MS), 10_501 * MS),
            FlightMode::Landing
        );
    }

    #[test]
    fn imu_stale_turns_motors_off() {
        let mut fs = armed(0);
        let mut f = all_fresh(0);
        f.last_imu_us = Some(100 * MS);
        f.last_height_us = Some(120 * MS);
        f.last_valid_estimate_us = Some(120 * MS);
        assert_eq!(fs.update(&f, 120 * MS), FlightMode::Flying);
        assert_eq!(fs.update(&f, 120 * MS + 1), FlightMode::ImuFault);
        assert!(!fs.mode().motors_enabled());
        // A fresh IMU does not restart the motors by itself.
        assert_eq!(
            fs.update(&all_fresh(200 * MS), 200 * MS),
            FlightMode::ImuFault
        );
    }

    #[test]
    fn height_stale_lands_and_land_command_lands() {
        let mut fs = armed(0);
        let mut f = all_fresh(600 * MS);
        f.last_height_us = Some(100 * MS);
        assert_eq!(fs.update(&f, 600 * MS), FlightMode::Flying);
        assert_eq!(fs.update(&f, 600 * MS + 1), FlightMode::Landing);
        assert_eq!(fs.land_reason(), Some(LandReason::HeightLost));
        let mut fs = armed(0);
        assert_eq!(
            fs.command(PilotCommand::Land, &all_fresh(MS), MS),
            FlightMode::Landing
        );
        // The first reason is kept; the next arming clears it.
        fs.land(LandReason::LowBattery, 2 * MS);
        assert_eq!(fs.land_reason(), Some(LandReason::Commanded));
        fs.command(PilotCommand::Kill, &all_fresh(3 * MS), 3 * MS);
        fs.command(PilotCommand::Arm, &all_fresh(4 * MS), 4 * MS);
        assert_eq!(fs.land_reason(), None);
        assert_eq!(fs.land(LandReason::LowBattery, 5 * MS), FlightMode::Landing);
        assert_eq!(fs.land_reason(), Some(LandReason::LowBattery));
        // Land while disarmed does nothing.
        let mut fs = Failsafe::new(FailsafeConfig::default());
        assert_eq!(
            fs.command(PilotCommand::Land, &all_fresh(MS), MS),
            FlightMode::Disarmed
        );
    }
}
