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
//! * No host heartbeat for [`FailsafeConfig::host_timeout_us`] while armed (the telemetry link,
//!   the pocket drone's only kill path, is gone) -> [`FailsafeConfig::host_action`]: land (the
//!   default), hold (the avoidance FSM stops, the drone hovers where it is until heartbeats
//!   come back) or kill. Arming needs a fresh host heartbeat unless
//!   [`FailsafeConfig::autonomous_arm`] allows arming without one; a drone armed that way with
//!   no host heard since boot has no host to lose.
//! * `Landing` ends in `Disarmed` when the caller reports touchdown; a landing that cannot end
//!   is cut by the caller ([`Failsafe::cut`]).
//!
//! Each failsafe (and each `Land` or `Kill` command) records its [`FailsafeReason`], which
//! stands until the next arming.
//!
//! [`FlightMode`] and [`FailsafeReason`] are the protocol's types: telemetry carries them as
//! they are.

use protocol::PilotCommand;

pub use protocol::{FailsafeReason, FlightMode};

/// What the autopilot does when its host's heartbeats stop while armed (parameter
/// `fs_host_action`: 0 land, 1 hold, 2 kill).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HostLossAction {
    /// Land where it is, then disarm.
    Land,
    /// Stop the avoidance FSM and hover in place until the heartbeats come back.
    Hold,
    /// Motors off at once.
    Kill,
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
    /// No host heartbeat for this long while armed -> [`FailsafeConfig::host_action`], µs.
    pub host_timeout_us: u64,
    /// What a lost host link does.
    pub host_action: HostLossAction,
    /// Arming is allowed without a host heartbeat (a drone that flies with no ground station).
    pub autonomous_arm: bool,
}

impl Default for FailsafeConfig {
    fn default() -> Self {
        Self {
            estimate_timeout_us: 500_000,
            hover_before_land_us: 1_500_000,
            imu_timeout_us: 20_000,
            height_timeout_us: 500_000,
            host_timeout_us: 3_000_000,
            host_action: HostLossAction::Land,
            autonomous_arm: false,
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
    /// Time of the last host heartbeat, µs.
    pub last_host_us: Option<u64>,
    /// The barometer is frozen (a stale height is then blamed on it).
    pub baro_frozen: bool,
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
    /// Why normal flight was last left since the last arming.
    reason: Option<FailsafeReason>,
    /// The host link is lost and its action is to hold.
    holding: bool,
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
            reason: None,
            holding: false,
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

    /// Why normal flight was last left since the last arming (`None`: it has not).
    pub fn reason(&self) -> Option<FailsafeReason> {
        self.reason
    }

    /// True while the host link is lost and [`HostLossAction::Hold`] keeps the drone hovering
    /// in place (the avoidance FSM stopped).
    pub fn holding(&self) -> bool {
        self.holding
    }

    /// Lands for `reason` if the motors run and it is not landing already (the first reason
    /// is kept). Returns the new mode.
    pub fn land(&mut self, reason: FailsafeReason, now_us: u64) -> FlightMode {
        if self.mode.motors_enabled() && self.mode != FlightMode::Landing {
            self.fail(FlightMode::Landing, reason, now_us);
        }
        self.mode
    }

    fn set(&mut self, m: FlightMode, now: u64) {
        if m != self.mode {
            self.mode = m;
            self.since_us = now;
        }
    }

    /// Changes to `m` for `reason`; the reason is recorded when the mode changes.
    fn fail(&mut self, m: FlightMode, reason: FailsafeReason, now: u64) {
        if m != self.mode {
            self.reason = Some(reason);
            self.set(m, now);
        }
    }

    /// True when the host's heartbeats have stopped: none for the host timeout, or none ever
    /// (unless autonomous arming allows flying without a host).
    pub fn host_lost(&self, f: &Freshness, now_us: u64) -> bool {
        match f.last_host_us {
            None => !self.cfg.autonomous_arm,
            t => !fresh(t, now_us, self.cfg.host_timeout_us),
        }
    }

    /// Motors off at once for `reason` (from any armed mode), e.g. a landing that cannot
    /// end; the drone stays down until the next arm.
    pub fn cut(&mut self, reason: FailsafeReason, now_us: u64) {
        if self.mode.motors_enabled() {
            self.fail(FlightMode::Disarmed, reason, now_us);
        }
    }

    /// True when the IMU is fresh at `now_us`.
    pub fn imu_fresh(&self, f: &Freshness, now_us: u64) -> bool {
        fresh(f.last_imu_us, now_us, self.cfg.imu_timeout_us)
    }

    /// Applies a pilot command. Returns the new mode. `Arm` is refused (mode unchanged) unless
    /// disarmed/killed/faulted with a fresh IMU and height and a host heartbeat (see
    /// [`Failsafe::host_lost`]).
    pub fn command(&mut self, cmd: PilotCommand, f: &Freshness, now_us: u64) -> FlightMode {
        match cmd {
            PilotCommand::Kill => self.fail(FlightMode::Killed, FailsafeReason::Command, now_us),
            PilotCommand::Land => {
                if self.mode.motors_enabled() {
                    self.fail(FlightMode::Landing, FailsafeReason::Command, now_us);
                }
            }
            PilotCommand::Arm => {
                let grounded = matches!(
                    self.mode,
                    FlightMode::Disarmed | FlightMode::Killed | FlightMode::ImuFault
                );
                if grounded
                    && self.imu_fresh(f, now_us)
                    && fresh(f.last_height_us, now_us, self.cfg.height_timeout_us)
                    && !self.host_lost(f, now_us)
                {
                    self.set(FlightMode::Flying, now_us);
                    self.armed_us = now_us;
                    self.seen_estimate = false;
                    self.reason = None;
                    self.holding = false;
                }
            }
            // The PWM gate of the lockstep images: no change of mode.
            PilotCommand::HilOutputs(_) => {}
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
            self.holding = false;
            return self.mode;
        }
        if !self.imu_fresh(f, now_us) {
            self.fail(FlightMode::ImuFault, FailsafeReason::ImuLost, now_us);
            return self.mode;
        }
        let host_lost = self.host_lost(f, now_us);
        self.holding = host_lost && self.cfg.host_action == HostLossAction::Hold;
        if host_lost {
            let lost = FailsafeReason::TelemetryLost;
            match self.cfg.host_action {
                HostLossAction::Kill => {
                    self.fail(FlightMode::Killed, lost, now_us);
                    return self.mode;
                }
                HostLossAction::Land => {
                    self.fail(FlightMode::Landing, lost, now_us);
                    return self.mode;
                }
                HostLossAction::Hold => {}
            }
        }
        if !fresh(f.last_height_us, now_us, self.cfg.height_timeout_us) {
            let reason = if f.baro_frozen {
                FailsafeReason::BaroFrozen
            } else {
                FailsafeReason::HeightLost
            };
            self.fail(FlightMode::Landing, reason, now_us);
            return self.mode;
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
                self.fail(FlightMode::Landing, FailsafeReason::EstimateLost, now_us)
            }
            FlightMode::Flying if !est_ok => self.fail(
                FlightMode::HoverNoEstimate,
                FailsafeReason::EstimateLost,
                now_us,
            ),
            FlightMode::HoverNoEstimate => {
                if est_ok {
                    self.set(FlightMode::Flying, now_us);
                } else if now_us.saturating_sub(self.since_us) >= self.cfg.hover_before_land_us {
                    self.fail(FlightMode::Landing, FailsafeReason::EstimateLost, now_us);
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
            last_host_us: Some(now),
            baro_frozen: false,
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
            last_host_us: Some(t),
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
        assert_eq!(fs.reason(), Some(FailsafeReason::EstimateLost));
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
            last_host_us: Some(t),
            baro_frozen: false,
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
        assert_eq!(fs.reason(), Some(FailsafeReason::HeightLost));
        let mut fs = armed(0);
        assert_eq!(
            fs.command(PilotCommand::Land, &all_fresh(MS), MS),
            FlightMode::Landing
        );
        // The first reason is kept; the next arming clears it.
        fs.land(FailsafeReason::BatteryLow, 2 * MS);
        assert_eq!(fs.reason(), Some(FailsafeReason::Command));
        fs.command(PilotCommand::Kill, &all_fresh(3 * MS), 3 * MS);
        fs.command(PilotCommand::Arm, &all_fresh(4 * MS), 4 * MS);
        assert_eq!(fs.reason(), None);
        assert_eq!(
            fs.land(FailsafeReason::BatteryLow, 5 * MS),
            FlightMode::Landing
        );
        assert_eq!(fs.reason(), Some(FailsafeReason::BatteryLow));
        // Land while disarmed does nothing.
        let mut fs = Failsafe::new(FailsafeConfig::default());
        assert_eq!(
            fs.command(PilotCommand::Land, &all_fresh(MS), MS),
            FlightMode::Disarmed
        );
    }

    fn host_silent_since(fs: &mut Failsafe, last_host: u64, now: u64) -> FlightMode {
        let f = Freshness {
            last_host_us: Some(last_host),
            ..all_fresh(now)
        };
        fs.update(&f, now)
    }

    #[test]
    fn host_silence_lands_by_default_and_says_why() {
        let mut fs = armed(0);
        let timeout = fs.config().host_timeout_us;
        assert_eq!(
            host_silent_since(&mut fs, 100 * MS, 100 * MS + timeout),
            FlightMode::Flying
        );
        assert_eq!(fs.reason(), None);
        assert_eq!(
            host_silent_since(&mut fs, 100 * MS, 100 * MS + timeout + 1),
            FlightMode::Landing
        );
        assert_eq!(fs.reason(), Some(FailsafeReason::TelemetryLost));
        // A heartbeat coming back does not stop the landing; touchdown disarms, the reason
        // stays for the flight summary until the next arming.
        assert_eq!(
            fs.update(&all_fresh(5000 * MS), 5000 * MS),
            FlightMode::Landing
        );
        fs.landed(6000 * MS);
        assert_eq!(fs.mode(), FlightMode::Disarmed);
        assert_eq!(fs.reason(), Some(FailsafeReason::TelemetryLost));
        fs.command(PilotCommand::Arm, &all_fresh(7000 * MS), 7000 * MS);
        assert_eq!(fs.reason(), None);
    }

    #[test]
    fn host_silence_kills_or_holds_on_request() {
        let mut fs = armed(0);
        fs.set_config(FailsafeConfig {
            host_action: HostLossAction::Kill,
            ..FailsafeConfig::default()
        });
        let late = fs.config().host_timeout_us + 1;
        assert_eq!(host_silent_since(&mut fs, 0, late), FlightMode::Killed);
        assert_eq!(fs.reason(), Some(FailsafeReason::TelemetryLost));

        let mut fs = armed(0);
        fs.set_config(FailsafeConfig {
            host_action: HostLossAction::Hold,
            ..FailsafeConfig::default()
        });
        assert_eq!(host_silent_since(&mut fs, 0, late), FlightMode::Flying);
        assert!(fs.holding());
        // The other failsafes still act while holding.
        let mut f = all_fresh(late + 600 * MS);
        f.last_host_us = Some(0);
        f.last_height_us = Some(late);
        assert_eq!(fs.update(&f, late + 600 * MS), FlightMode::Landing);
        // Heartbeats back: no longer holding.
        fs.update(&all_fresh(late + 700 * MS), late + 700 * MS);
        assert!(!fs.holding());
    }

    #[test]
    fn arming_needs_a_host_heartbeat_unless_autonomous_arming_is_allowed() {
        let mut fs = Failsafe::new(FailsafeConfig::default());
        let mut f = all_fresh(10_000 * MS);
        f.last_host_us = None;
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, 10_000 * MS),
            FlightMode::Disarmed
        );
        f.last_host_us = Some(5_000 * MS);
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, 10_000 * MS),
            FlightMode::Disarmed,
            "a heartbeat older than the host timeout does not count"
        );
        let mut fs = Failsafe::new(FailsafeConfig {
            autonomous_arm: true,
            ..FailsafeConfig::default()
        });
        f.last_host_us = None;
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, 10_000 * MS),
            FlightMode::Flying
        );
        // No host ever heard: none to lose.
        let mut later = all_fresh(12_000 * MS);
        later.last_host_us = None;
        assert_eq!(fs.update(&later, 12_000 * MS), FlightMode::Flying);
        // A host that was there and went silent is lost even so.
        f.last_host_us = Some(10_000 * MS);
        let late = 10_000 * MS + fs.config().host_timeout_us + 1;
        f.last_imu_us = Some(late);
        f.last_height_us = Some(late);
        f.last_valid_estimate_us = Some(late);
        assert_eq!(fs.update(&f, late), FlightMode::Landing);
    }

    #[test]
    fn a_cut_turns_the_motors_off_with_its_reason() {
        let mut fs = armed(0);
        fs.command(PilotCommand::Land, &all_fresh(MS), MS);
        assert_eq!(fs.reason(), Some(FailsafeReason::Command));
        fs.cut(FailsafeReason::LandTimeout, 2 * MS);
        assert_eq!(fs.mode(), FlightMode::Disarmed);
        assert_eq!(fs.reason(), Some(FailsafeReason::LandTimeout));
    }
}
