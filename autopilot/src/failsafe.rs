//! Flight mode and failsafes.
//!
//! * A kill (RC or command) always wins: motors off at once, from any mode, until the next arm.
//! * Arming needs a fresh IMU sample and a fresh height measurement.
//! * No valid velocity estimate for [`FailsafeConfig::estimate_timeout`] (link lost, camera
//!   blind, quality low) -> [`FlightMode::HoverNoEstimate`]: level hover on the guidance trim at
//!   the current height setpoint. A valid estimate within
//!   [`FailsafeConfig::hover_before_land`] resumes the flight; otherwise -> `Landing`. A
//!   drone that has had no valid estimate at all since it was armed goes to `Landing` at once
//!   instead: waiting is for a camera that may come back, and every second of blind hover is
//!   drift nobody measures (a trim error of 0.6 deg is 0.1 m/s² of it).
//! * Height measurement stale for [`FailsafeConfig::height_timeout`] in flight -> `Landing`
//!   (the caller descends open-loop on reduced thrust).
//! * IMU stale for [`FailsafeConfig::imu_timeout`] while armed -> [`FlightMode::ImuFault`]:
//!   motors off (nothing can stabilise the drone without rates).
//! * No host heartbeat for [`FailsafeConfig::host_timeout`] while armed (the telemetry link,
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
use timebase::{Duration, Instant};

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
    /// No valid estimate for this long -> hover.
    pub estimate_timeout: Duration,
    /// Hover without estimate for this long -> land.
    pub hover_before_land: Duration,
    /// No IMU sample for this long while armed -> motors off.
    pub imu_timeout: Duration,
    /// No height measurement for this long in flight -> land.
    pub height_timeout: Duration,
    /// No host heartbeat for this long while armed -> [`FailsafeConfig::host_action`].
    pub host_timeout: Duration,
    /// What a lost host link does.
    pub host_action: HostLossAction,
    /// Arming is allowed without a host heartbeat (a drone that flies with no ground station).
    pub autonomous_arm: bool,
}

impl Default for FailsafeConfig {
    fn default() -> Self {
        Self {
            estimate_timeout: Duration::from_millis(500),
            hover_before_land: Duration::from_millis(1_500),
            imu_timeout: Duration::from_millis(20),
            height_timeout: Duration::from_millis(500),
            host_timeout: Duration::from_secs(3),
            host_action: HostLossAction::Land,
            autonomous_arm: false,
        }
    }
}

/// Freshness of the inputs at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Freshness {
    /// Time of the last valid velocity estimate.
    pub last_valid_estimate: Option<Instant>,
    /// Time of the last usable IMU sample.
    pub last_imu: Option<Instant>,
    /// Time of the last usable height measurement.
    pub last_height: Option<Instant>,
    /// Time of the last host heartbeat.
    pub last_host: Option<Instant>,
    /// The barometer is frozen (a stale height is then blamed on it).
    pub baro_frozen: bool,
}

fn fresh(t: Option<Instant>, now: Instant, timeout: Duration) -> bool {
    matches!(t, Some(t) if now.since(t) <= timeout)
}

/// Mode logic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Failsafe {
    cfg: FailsafeConfig,
    mode: FlightMode,
    since: Instant,
    armed: Instant,
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
            since: Instant::ZERO,
            armed: Instant::ZERO,
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

    /// When the current mode began.
    pub fn since(&self) -> Instant {
        self.since
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
    pub fn land(&mut self, reason: FailsafeReason, now: Instant) -> FlightMode {
        if self.mode.motors_enabled() && self.mode != FlightMode::Landing {
            self.fail(FlightMode::Landing, reason, now);
        }
        self.mode
    }

    fn set(&mut self, m: FlightMode, now: Instant) {
        if m != self.mode {
            self.mode = m;
            self.since = now;
        }
    }

    /// Changes to `m` for `reason`; the reason is recorded when the mode changes.
    fn fail(&mut self, m: FlightMode, reason: FailsafeReason, now: Instant) {
        if m != self.mode {
            self.reason = Some(reason);
            self.set(m, now);
        }
    }

    /// True when the host's heartbeats have stopped: none for the host timeout, or none ever
    /// (unless autonomous arming allows flying without a host).
    pub fn host_lost(&self, f: &Freshness, now: Instant) -> bool {
        match f.last_host {
            None => !self.cfg.autonomous_arm,
            t => !fresh(t, now, self.cfg.host_timeout),
        }
    }

    /// Motors off at once for `reason` (from any armed mode), e.g. a landing that cannot
    /// end; the drone stays down until the next arm.
    pub fn cut(&mut self, reason: FailsafeReason, now: Instant) {
        if self.mode.motors_enabled() {
            self.fail(FlightMode::Disarmed, reason, now);
        }
    }

    /// True when the IMU is fresh at `now`.
    pub fn imu_fresh(&self, f: &Freshness, now: Instant) -> bool {
        fresh(f.last_imu, now, self.cfg.imu_timeout)
    }

    /// Applies a pilot command. Returns the new mode. `Arm` is refused (mode unchanged) unless
    /// disarmed/killed/faulted with a fresh IMU and height and a host heartbeat (see
    /// [`Failsafe::host_lost`]).
    pub fn command(&mut self, cmd: PilotCommand, f: &Freshness, now: Instant) -> FlightMode {
        match cmd {
            PilotCommand::Kill => self.fail(FlightMode::Killed, FailsafeReason::Command, now),
            PilotCommand::Land => {
                if self.mode.motors_enabled() {
                    self.fail(FlightMode::Landing, FailsafeReason::Command, now);
                }
            }
            PilotCommand::Arm => {
                let grounded = matches!(
                    self.mode,
                    FlightMode::Disarmed | FlightMode::Killed | FlightMode::ImuFault
                );
                if grounded
                    && self.imu_fresh(f, now)
                    && fresh(f.last_height, now, self.cfg.height_timeout)
                    && !self.host_lost(f, now)
                {
                    self.set(FlightMode::Flying, now);
                    self.armed = now;
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
    pub fn landed(&mut self, now: Instant) {
        if self.mode == FlightMode::Landing {
            self.set(FlightMode::Disarmed, now);
        }
    }

    /// Re-evaluates the timeouts at `now`. Returns the new mode.
    pub fn update(&mut self, f: &Freshness, now: Instant) -> FlightMode {
        if !self.mode.motors_enabled() {
            self.holding = false;
            return self.mode;
        }
        if !self.imu_fresh(f, now) {
            self.fail(FlightMode::ImuFault, FailsafeReason::ImuLost, now);
            return self.mode;
        }
        let host_lost = self.host_lost(f, now);
        self.holding = host_lost && self.cfg.host_action == HostLossAction::Hold;
        if host_lost {
            let lost = FailsafeReason::TelemetryLost;
            match self.cfg.host_action {
                HostLossAction::Kill => {
                    self.fail(FlightMode::Killed, lost, now);
                    return self.mode;
                }
                HostLossAction::Land => {
                    self.fail(FlightMode::Landing, lost, now);
                    return self.mode;
                }
                HostLossAction::Hold => {}
            }
        }
        if !fresh(f.last_height, now, self.cfg.height_timeout) {
            let reason = if f.baro_frozen {
                FailsafeReason::BaroFrozen
            } else {
                FailsafeReason::HeightLost
            };
            self.fail(FlightMode::Landing, reason, now);
            return self.mode;
        }
        // The estimate clock starts at arming: a drone armed without estimates gets the same
        // grace period as one that lost them.
        let last_est = match f.last_valid_estimate {
            Some(t) => t.max(self.armed),
            None => self.armed,
        };
        let est_ok = now.since(last_est) <= self.cfg.estimate_timeout;
        if matches!(f.last_valid_estimate, Some(t) if t > self.armed) {
            self.seen_estimate = true;
        }
        match self.mode {
            FlightMode::Flying if !est_ok && !self.seen_estimate => {
                self.fail(FlightMode::Landing, FailsafeReason::EstimateLost, now)
            }
            FlightMode::Flying if !est_ok => self.fail(
                FlightMode::HoverNoEstimate,
                FailsafeReason::EstimateLost,
                now,
            ),
            FlightMode::HoverNoEstimate => {
                if est_ok {
                    self.set(FlightMode::Flying, now);
                } else if now.since(self.since) >= self.cfg.hover_before_land {
                    self.fail(FlightMode::Landing, FailsafeReason::EstimateLost, now);
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
    use crate::test_support::at;

    const MS: u64 = 1_000;

    fn all_fresh(now: u64) -> Freshness {
        Freshness {
            last_valid_estimate: Some(at(now)),
            last_imu: Some(at(now)),
            last_height: Some(at(now)),
            last_host: Some(at(now)),
            baro_frozen: false,
        }
    }

    fn armed(now: u64) -> Failsafe {
        let mut fs = Failsafe::new(FailsafeConfig::default());
        assert_eq!(
            fs.command(PilotCommand::Arm, &all_fresh(now), at(now)),
            FlightMode::Flying
        );
        fs
    }

    #[test]
    fn arm_needs_fresh_imu_and_height() {
        let mut fs = Failsafe::new(FailsafeConfig::default());
        let mut f = all_fresh(1000 * MS);
        f.last_imu = None;
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, at(1000 * MS)),
            FlightMode::Disarmed
        );
        let mut f = all_fresh(1000 * MS);
        f.last_height = Some(at(0));
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, at(1000 * MS)),
            FlightMode::Disarmed
        );
        // Estimates are not needed to arm.
        let mut f = all_fresh(1000 * MS);
        f.last_valid_estimate = None;
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, at(1000 * MS)),
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
            fs.set(start, at(0));
            assert_eq!(
                fs.command(PilotCommand::Kill, &all_fresh(10 * MS), at(10 * MS)),
                FlightMode::Killed
            );
            assert!(!fs.mode().motors_enabled());
            // Land does not revive a killed drone; timeouts leave it alone.
            fs.command(PilotCommand::Land, &all_fresh(20 * MS), at(20 * MS));
            fs.update(&Freshness::default(), at(30 * MS));
            assert_eq!(fs.mode(), FlightMode::Killed);
        }
        let mut fs = Failsafe::new(FailsafeConfig::default());
        fs.command(PilotCommand::Kill, &all_fresh(0), at(0));
        assert_eq!(fs.mode(), FlightMode::Killed);
        // Re-arming after a kill is allowed.
        assert_eq!(
            fs.command(PilotCommand::Arm, &all_fresh(MS), at(MS)),
            FlightMode::Flying
        );
    }

    #[test]
    fn estimate_loss_hovers_then_lands_or_recovers() {
        let mut fs = armed(0);
        let mut f = all_fresh(0);
        f.last_valid_estimate = Some(at(100 * MS));
        let fresh_at = |t: u64, f: &Freshness| Freshness {
            last_imu: Some(at(t)),
            last_height: Some(at(t)),
            last_host: Some(at(t)),
            ..*f
        };
        // 500 ms after the last valid estimate: still flying; 1 µs later: hover.
        assert_eq!(
            fs.update(&fresh_at(600 * MS, &f), at(600 * MS)),
            FlightMode::Flying
        );
        assert_eq!(
            fs.update(&fresh_at(600 * MS + 1, &f), at(600 * MS + 1)),
            FlightMode::HoverNoEstimate
        );
        // An estimate comes back: flying again.
        f.last_valid_estimate = Some(at(1000 * MS));
        assert_eq!(
            fs.update(&fresh_at(1000 * MS, &f), at(1000 * MS)),
            FlightMode::Flying
        );
        // Lost again at 1.5 s: hover from 1.5 s, land 1.5 s later.
        fs.update(&fresh_at(1501 * MS, &f), at(1501 * MS));
        assert_eq!(fs.mode(), FlightMode::HoverNoEstimate);
        assert_eq!(
            fs.update(&fresh_at(3000 * MS, &f), at(3000 * MS)),
            FlightMode::HoverNoEstimate
        );
        assert_eq!(
            fs.update(&fresh_at(3001 * MS, &f), at(3001 * MS)),
            FlightMode::Landing
        );
        // Landing does not go back to flying on its own, and ends on touchdown.
        f.last_valid_estimate = Some(at(4600 * MS));
        assert_eq!(
            fs.update(&fresh_at(4600 * MS, &f), at(4600 * MS)),
            FlightMode::Landing
        );
        fs.landed(at(5000 * MS));
        assert_eq!(fs.mode(), FlightMode::Disarmed);
        assert_eq!(fs.reason(), Some(FailsafeReason::EstimateLost));
    }

    /// Armed without estimates: the estimate timeout's grace, then a landing at once (nothing
    /// was ever seen that could come back).
    #[test]
    fn armed_without_estimates_gets_the_grace_period_then_lands() {
        let mut fs = Failsafe::new(FailsafeConfig::default());
        let mut f = all_fresh(10 * 1000 * MS);
        f.last_valid_estimate = None;
        fs.command(PilotCommand::Arm, &f, at(10_000 * MS));
        let f2 = |t| Freshness {
            last_valid_estimate: None,
            last_imu: Some(at(t)),
            last_height: Some(at(t)),
            last_host: Some(at(t)),
            baro_frozen: false,
        };
        assert_eq!(
            fs.update(&f2(10_400 * MS), at(10_400 * MS)),
            FlightMode::Flying
        );
        assert_eq!(
            fs.update(&f2(10_501 * MS), at(10_501 * MS)),
            FlightMode::Landing
        );
        // An estimate from before the arming does not count as seen in this flight.
        let mut fs = Failsafe::new(FailsafeConfig::default());
        fs.command(PilotCommand::Arm, &f, at(10_000 * MS));
        let before = |t| Freshness {
            last_valid_estimate: Some(at(9_900 * MS)),
            ..f2(t)
        };
        assert_eq!(
            fs.update(&before(10_501 * MS), at(10_501 * MS)),
            FlightMode::Landing
        );
    }

    #[test]
    fn imu_stale_turns_motors_off() {
        let mut fs = armed(0);
        let mut f = all_fresh(0);
        f.last_imu = Some(at(100 * MS));
        f.last_height = Some(at(120 * MS));
        f.last_valid_estimate = Some(at(120 * MS));
        assert_eq!(fs.update(&f, at(120 * MS)), FlightMode::Flying);
        assert_eq!(fs.update(&f, at(120 * MS + 1)), FlightMode::ImuFault);
        assert!(!fs.mode().motors_enabled());
        // A fresh IMU does not restart the motors by itself.
        assert_eq!(
            fs.update(&all_fresh(200 * MS), at(200 * MS)),
            FlightMode::ImuFault
        );
    }

    #[test]
    fn height_stale_lands_and_land_command_lands() {
        let mut fs = armed(0);
        let mut f = all_fresh(600 * MS);
        f.last_height = Some(at(100 * MS));
        assert_eq!(fs.update(&f, at(600 * MS)), FlightMode::Flying);
        assert_eq!(fs.update(&f, at(600 * MS + 1)), FlightMode::Landing);
        assert_eq!(fs.reason(), Some(FailsafeReason::HeightLost));
        let mut fs = armed(0);
        assert_eq!(
            fs.command(PilotCommand::Land, &all_fresh(MS), at(MS)),
            FlightMode::Landing
        );
        // The first reason is kept; the next arming clears it.
        fs.land(FailsafeReason::BatteryLow, at(2 * MS));
        assert_eq!(fs.reason(), Some(FailsafeReason::Command));
        fs.command(PilotCommand::Kill, &all_fresh(3 * MS), at(3 * MS));
        fs.command(PilotCommand::Arm, &all_fresh(4 * MS), at(4 * MS));
        assert_eq!(fs.reason(), None);
        assert_eq!(
            fs.land(FailsafeReason::BatteryLow, at(5 * MS)),
            FlightMode::Landing
        );
        assert_eq!(fs.reason(), Some(FailsafeReason::BatteryLow));
        // Land while disarmed does nothing.
        let mut fs = Failsafe::new(FailsafeConfig::default());
        assert_eq!(
            fs.command(PilotCommand::Land, &all_fresh(MS), at(MS)),
            FlightMode::Disarmed
        );
    }

    fn host_silent_since(fs: &mut Failsafe, last_host: Instant, now: Instant) -> FlightMode {
        let f = Freshness {
            last_host: Some(last_host),
            ..all_fresh(now.as_micros())
        };
        fs.update(&f, now)
    }

    #[test]
    fn host_silence_lands_by_default_and_says_why() {
        let mut fs = armed(0);
        let timeout = fs.config().host_timeout.as_micros();
        assert_eq!(
            host_silent_since(&mut fs, at(100 * MS), at(100 * MS + timeout)),
            FlightMode::Flying
        );
        assert_eq!(fs.reason(), None);
        assert_eq!(
            host_silent_since(&mut fs, at(100 * MS), at(100 * MS + timeout + 1)),
            FlightMode::Landing
        );
        assert_eq!(fs.reason(), Some(FailsafeReason::TelemetryLost));
        // A heartbeat coming back does not stop the landing; touchdown disarms, the reason
        // stays for the flight summary until the next arming.
        assert_eq!(
            fs.update(&all_fresh(5000 * MS), at(5000 * MS)),
            FlightMode::Landing
        );
        fs.landed(at(6000 * MS));
        assert_eq!(fs.mode(), FlightMode::Disarmed);
        assert_eq!(fs.reason(), Some(FailsafeReason::TelemetryLost));
        fs.command(PilotCommand::Arm, &all_fresh(7000 * MS), at(7000 * MS));
        assert_eq!(fs.reason(), None);
    }

    #[test]
    fn host_silence_kills_or_holds_on_request() {
        let mut fs = armed(0);
        fs.set_config(FailsafeConfig {
            host_action: HostLossAction::Kill,
            ..FailsafeConfig::default()
        });
        let late = fs.config().host_timeout.as_micros() + 1;
        assert_eq!(
            host_silent_since(&mut fs, at(0), at(late)),
            FlightMode::Killed
        );
        assert_eq!(fs.reason(), Some(FailsafeReason::TelemetryLost));

        let mut fs = armed(0);
        fs.set_config(FailsafeConfig {
            host_action: HostLossAction::Hold,
            ..FailsafeConfig::default()
        });
        assert_eq!(
            host_silent_since(&mut fs, at(0), at(late)),
            FlightMode::Flying
        );
        assert!(fs.holding());
        // The other failsafes still act while holding.
        let mut f = all_fresh(late + 600 * MS);
        f.last_host = Some(at(0));
        f.last_height = Some(at(late));
        assert_eq!(fs.update(&f, at(late + 600 * MS)), FlightMode::Landing);
        // Heartbeats back: no longer holding.
        fs.update(&all_fresh(late + 700 * MS), at(late + 700 * MS));
        assert!(!fs.holding());
    }

    #[test]
    fn arming_needs_a_host_heartbeat_unless_autonomous_arming_is_allowed() {
        let mut fs = Failsafe::new(FailsafeConfig::default());
        let mut f = all_fresh(10_000 * MS);
        f.last_host = None;
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, at(10_000 * MS)),
            FlightMode::Disarmed
        );
        f.last_host = Some(at(5_000 * MS));
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, at(10_000 * MS)),
            FlightMode::Disarmed,
            "a heartbeat older than the host timeout does not count"
        );
        let mut fs = Failsafe::new(FailsafeConfig {
            autonomous_arm: true,
            ..FailsafeConfig::default()
        });
        f.last_host = None;
        assert_eq!(
            fs.command(PilotCommand::Arm, &f, at(10_000 * MS)),
            FlightMode::Flying
        );
        // No host ever heard: none to lose.
        let mut later = all_fresh(12_000 * MS);
        later.last_host = None;
        assert_eq!(fs.update(&later, at(12_000 * MS)), FlightMode::Flying);
        // A host that was there and went silent is lost even so.
        f.last_host = Some(at(10_000 * MS));
        let late = 10_000 * MS + fs.config().host_timeout.as_micros() + 1;
        f.last_imu = Some(at(late));
        f.last_height = Some(at(late));
        f.last_valid_estimate = Some(at(late));
        assert_eq!(fs.update(&f, at(late)), FlightMode::Landing);
    }

    #[test]
    fn a_cut_turns_the_motors_off_with_its_reason() {
        let mut fs = armed(0);
        fs.command(PilotCommand::Land, &all_fresh(MS), at(MS));
        assert_eq!(fs.reason(), Some(FailsafeReason::Command));
        fs.cut(FailsafeReason::LandTimeout, at(2 * MS));
        assert_eq!(fs.mode(), FlightMode::Disarmed);
        assert_eq!(fs.reason(), Some(FailsafeReason::LandTimeout));
    }
}
