//! Obstacle-avoidance state machine (paper, section "Autonomous Obstacle Avoidance"), flying
//! on evidence: a way counts as clear only when the camera saw free space, never because it saw
//! nothing.
//!
//! Each obstacle reading is one of three kinds of evidence ([`Evidence`]):
//!
//! * blocked: an obstacle nearer than the state's threshold, or a time to contact (from the
//!   flow's divergence, no range needed) confidently shorter than
//!   [`FsmConfig::contact_time_s`];
//! * clear: nothing nearer than the threshold over a view of which at least
//!   [`FsmConfig::min_clear_depth`] has a stereo depth;
//! * unknown: nothing nearer, but too little of the view has depth to say so (a plain wall, a
//!   dark room). Unknown is never taken for clear.
//!
//! Five states, each with a timeout that ends in a safe action:
//!
//! * [`FsmState::Check`]: wait for a fresh reading (one received after entering the state),
//!   holding zero velocity. Blocked within [`FsmConfig::obstacle_distance_m`] (1 m) ->
//!   `Hover`; clear -> `Forward`. No clear or blocked reading for
//!   [`FsmConfig::check_timeout`] -> `Turn` (look elsewhere); after
//!   [`FsmConfig::max_searches`] such searches in a row the FSM asks to land
//!   ([`FsmOutput::land`]).
//! * [`FsmState::Forward`]: fly forward at [`FsmConfig::forward_speed_mps`] (0.3 m/s), guided by
//!   the Edge-FS velocity. Blocked within 1 m in [`FsmConfig::block_confirm`] fresh readings in a
//!   row (one frame's stereo outlier does not stop the drone) -> `Brake`. Within
//!   [`FsmConfig::approach_distance_m`] of an obstacle the speed falls linearly towards
//!   [`FsmConfig::approach_speed_mps`] at the obstacle distance, so the drone arrives slowly
//!   and stops short; also `Brake` when no clear reading has
//!   arrived for [`FsmConfig::reading_timeout`] (flying blind is not clear), and after
//!   [`FsmConfig::forward_timeout`] in the state.
//! * [`FsmState::Brake`]: hold zero velocity until the estimated speed is at most
//!   [`FsmConfig::brake_speed_mps`] (or for [`FsmConfig::brake_timeout`]) -> `Hover`: the
//!   hover time is spent still, and the turn starts from a stop. With `brake_speed_mps = 0`
//!   `Forward` goes straight to `Hover`, as in the paper.
//! * [`FsmState::Hover`]: hold zero velocity for [`FsmConfig::hover_time`] (1 s) -> `Turn`.
//! * [`FsmState::Turn`]: depends on the [`FsmVariant`]:
//!   * [`FsmVariant::Paper`]: the yaw setpoint ramps by [`FsmConfig::turn_angle_rad`] (60 deg)
//!     at [`FsmConfig::turn_rate_radps`]; once the ramp is done and the heading is within
//!     [`FsmConfig::turn_tolerance_rad`] (or [`FsmConfig::turn_timeout`] after the ramp)
//!     -> `Check`.
//!   * [`FsmVariant::TurnUntilClear`] (the improvement the paper proposes: check and turn
//!     merged): the yaw setpoint keeps turning at the turn rate until
//!     [`FsmConfig::clear_confirm`] consecutive fresh readings are clear beyond
//!     [`FsmConfig::clear_distance_m`]; then the heading is held where it is -> `Forward`.
//!     No clear direction within [`FsmConfig::search_timeout`] (a full turn and more by
//!     default) -> the FSM asks to land.
//!
//! Once it has asked to land the FSM holds zero velocity and its heading until it is reset.
//! The numbering of the states (their `u8` value) is what telemetry carries.

use crate::attitude::wrap_pi;
use timebase::{Duration, Instant};

pub use protocol::FsmState;

/// Which avoidance logic to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FsmVariant {
    /// The paper's: hover, turn a fixed angle, check.
    Paper,
    /// Check and turn merged: keep turning until a clear path is seen.
    TurnUntilClear,
}

/// FSM tunables (defaults: the paper's values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FsmConfig {
    /// Which logic.
    pub variant: FsmVariant,
    /// An obstacle closer than this blocks the way, m (paper: 1 m).
    pub obstacle_distance_m: f32,
    /// Forward speed in `Forward`, m/s (paper: 0.3).
    pub forward_speed_mps: f32,
    /// Time in `Hover` (paper: 1 s).
    pub hover_time: Duration,
    /// Turn angle of the paper variant, rad (paper: 60 deg; positive: to the right).
    pub turn_angle_rad: f32,
    /// Yaw setpoint rate while turning, rad/s (sign ignored; the turn direction follows
    /// `turn_angle_rad`).
    pub turn_rate_radps: f32,
    /// Heading error that counts as "turned", rad.
    pub turn_tolerance_rad: f32,
    /// Leave `Turn` this long after the ramp ended even if the heading lags.
    pub turn_timeout: Duration,
    /// Turn-until-clear: a reading farther than this (or nothing in range) is clear, m.
    pub clear_distance_m: f32,
    /// Turn-until-clear: consecutive clear readings needed to stop turning.
    pub clear_confirm: u8,
    /// `Forward` stops (-> `Hover`) when the newest clear reading is older than this.
    pub reading_timeout: Duration,
    /// Smallest fraction of the view with a stereo depth (0..=1) for a reading without a near
    /// obstacle to count as clear; below it the reading is unknown.
    pub min_clear_depth: f32,
    /// `Check` without a clear or blocked reading for this long -> `Turn`.
    pub check_timeout: Duration,
    /// Consecutive `Check` timeouts (searches in new headings that found no evidence) after
    /// which the FSM asks to land.
    pub max_searches: u8,
    /// Longest time in `Forward` before a `Hover` (and a new look).
    pub forward_timeout: Duration,
    /// Consecutive blocked readings that stop `Forward` (1: the first, as in the paper).
    pub block_confirm: u8,
    /// `Forward` slows down when an obstacle is nearer than this, m (at most the obstacle
    /// distance: no slowing, as in the paper).
    pub approach_distance_m: f32,
    /// Forward speed with an obstacle at the obstacle distance, m/s (the approach's end).
    pub approach_speed_mps: f32,
    /// `Brake` ends once the estimated horizontal speed is at most this, m/s (0: no `Brake`,
    /// `Forward` ends in `Hover` as in the paper).
    pub brake_speed_mps: f32,
    /// Longest time in `Brake` (then `Hover`, however fast the estimate says).
    pub brake_timeout: Duration,
    /// Turn-until-clear: longest time turning without a confirmed clear direction before the
    /// FSM asks to land.
    pub search_timeout: Duration,
    /// A reading whose time to contact ([`ObstacleReading::contact_s`]) is below this blocks
    /// the way whatever its stereo distance, s (0: off). The second obstacle cue: it needs no
    /// stereo range, so it sees a surface nearer than the stereo search or one whose stereo
    /// failed, as long as the drone closes on it faster than it should.
    pub contact_time_s: f32,
}

impl Default for FsmConfig {
    fn default() -> Self {
        Self {
            variant: FsmVariant::Paper,
            obstacle_distance_m: 1.0,
            forward_speed_mps: 0.3,
            hover_time: Duration::from_secs(1),
            turn_angle_rad: 60.0_f32.to_radians(),
            turn_rate_radps: 1.5,
            turn_tolerance_rad: 8.0_f32.to_radians(),
            turn_timeout: Duration::from_secs(2),
            clear_distance_m: 1.5,
            clear_confirm: 3,
            reading_timeout: Duration::from_millis(300),
            min_clear_depth: 0.25,
            check_timeout: Duration::from_secs(2),
            max_searches: 6,
            forward_timeout: Duration::from_secs(60),
            block_confirm: 2,
            approach_distance_m: 2.0,
            approach_speed_mps: 0.1,
            brake_speed_mps: 0.05,
            brake_timeout: Duration::from_millis(1500),
            search_timeout: Duration::from_secs(6),
            contact_time_s: 1.5,
        }
    }
}

/// The latest obstacle reading from the camera board.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleReading {
    /// When the autopilot received it.
    pub received: Instant,
    /// Nearest obstacle, m; `None`: nothing within range where the view has depth.
    pub distance_m: Option<f32>,
    /// Fraction of the view with a stereo depth, 0..=1 (how much `distance_m == None` says).
    pub depth_fraction: f32,
    /// Time to contact with the scene ahead from the flow's divergence, at the long end of its
    /// uncertainty (so a short one is certain), s; `None`: not confidently approaching.
    pub contact_s: Option<f32>,
}

/// What one obstacle reading says about the way ahead, against a distance threshold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Evidence {
    /// An obstacle nearer than the threshold.
    Blocked,
    /// Nothing nearer than the threshold over a view with enough depth.
    Clear,
    /// Nothing nearer, but too little of the view has depth to tell.
    Unknown,
}

impl ObstacleReading {
    /// The evidence of this reading against `threshold_m`, counting it clear only when at
    /// least `min_depth` of the view has depth.
    pub fn evidence(&self, threshold_m: f32, min_depth: f32) -> Evidence {
        match self.distance_m {
            Some(d) if d.is_finite() && d < threshold_m => Evidence::Blocked,
            _ if self.depth_fraction >= min_depth => Evidence::Clear,
            _ => Evidence::Unknown,
        }
    }
}

/// What the FSM asks of guidance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FsmOutput {
    /// Forward body velocity setpoint, m/s (sideways is always 0).
    pub forward_mps: f32,
    /// Heading setpoint, rad (wrapped to (-pi, pi]).
    pub yaw_sp_rad: f32,
    /// The FSM found no way to go within its timeouts and asks to land.
    pub land: bool,
}

/// Avoidance state machine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AvoidanceFsm {
    cfg: FsmConfig,
    state: FsmState,
    entered: Instant,
    yaw_sp: f32,
    turn_start_yaw: f32,
    /// Time the yaw ramp of the paper variant finished.
    ramp_done: Option<Instant>,
    last_reading: Option<Instant>,
    /// When the newest clear reading (against the obstacle distance) arrived.
    last_clear: Option<Instant>,
    clear_count: u8,
    /// Blocked readings in a row in `Forward`.
    blocked_count: u8,
    /// `Check` timeouts in a row.
    searches: u8,
    /// Nearest obstacle of the latest reading, m (`None`: nothing in range or no reading).
    nearest_m: Option<f32>,
    land: bool,
    last_step: Instant,
    transitions: u32,
}

impl AvoidanceFsm {
    /// Takes a new configuration, keeping the state (used from the next step on).
    pub fn set_config(&mut self, cfg: FsmConfig) {
        self.cfg = cfg;
    }

    /// Starts in `Check` at `now`, holding heading `yaw_rad`.
    pub fn new(cfg: FsmConfig, now: Instant, yaw_rad: f32) -> Self {
        let yaw = wrap_pi(yaw_rad);
        Self {
            cfg,
            state: FsmState::Check,
            entered: now,
            yaw_sp: yaw,
            turn_start_yaw: yaw,
            ramp_done: None,
            last_reading: None,
            last_clear: None,
            clear_count: 0,
            blocked_count: 0,
            searches: 0,
            nearest_m: None,
            land: false,
            last_step: now,
            transitions: 0,
        }
    }

    /// Restarts in `Check` (e.g. after a failsafe), keeping the configuration.
    pub fn reset(&mut self, now: Instant, yaw_rad: f32) {
        let transitions = self.transitions;
        *self = Self::new(self.cfg, now, yaw_rad);
        self.transitions = transitions;
    }

    /// The configuration.
    pub fn config(&self) -> &FsmConfig {
        &self.cfg
    }

    /// Current state.
    pub fn state(&self) -> FsmState {
        self.state
    }

    /// When the current state was entered.
    pub fn entered(&self) -> Instant {
        self.entered
    }

    /// Number of state changes since creation.
    pub fn transitions(&self) -> u32 {
        self.transitions
    }

    /// True once the FSM has asked to land (until [`AvoidanceFsm::reset`]).
    pub fn wants_to_land(&self) -> bool {
        self.land
    }

    /// Current output without stepping.
    pub fn output(&self) -> FsmOutput {
        FsmOutput {
            forward_mps: if self.state == FsmState::Forward && !self.land {
                self.forward_speed()
            } else {
                0.0
            },
            yaw_sp_rad: self.yaw_sp,
            land: self.land,
        }
    }

    /// The forward speed, slowed within the approach distance of the nearest obstacle.
    fn forward_speed(&self) -> f32 {
        let full = self.cfg.forward_speed_mps;
        let (near, far) = (self.cfg.obstacle_distance_m, self.cfg.approach_distance_m);
        match self.nearest_m {
            Some(d) if far > near && d < far => {
                let slow = self.cfg.approach_speed_mps.min(full);
                let x = ((d - near) / (far - near)).clamp(0.0, 1.0);
                slow + (full - slow) * x
            }
            _ => full,
        }
    }

    fn enter(&mut self, s: FsmState, now: Instant) {
        self.state = s;
        self.entered = now;
        self.clear_count = 0;
        self.blocked_count = 0;
        self.ramp_done = None;
        self.transitions = self.transitions.wrapping_add(1);
    }

    fn evidence(&self, r: &ObstacleReading, threshold_m: f32) -> Evidence {
        if r.contact_s.is_some_and(|t| t < self.cfg.contact_time_s) {
            return Evidence::Blocked;
        }
        r.evidence(threshold_m, self.cfg.min_clear_depth)
    }

    fn start_turn(&mut self, now: Instant) {
        self.turn_start_yaw = self.yaw_sp;
        self.enter(FsmState::Turn, now);
    }

    /// One step at `now` with the current heading `yaw_rad`, the latest obstacle reading and
    /// the estimated horizontal speed (m/s; `None`: no fresh estimate, and `Brake` lasts its
    /// timeout).
    pub fn step(
        &mut self,
        now: Instant,
        yaw_rad: f32,
        reading: Option<ObstacleReading>,
        speed_mps: Option<f32>,
    ) -> FsmOutput {
        let dt = now.since(self.last_step).as_secs_f32();
        let dt = dt.min(0.5);
        self.last_step = now;
        let yaw = if yaw_rad.is_finite() {
            wrap_pi(yaw_rad)
        } else {
            self.yaw_sp
        };
        // A reading counts as fresh once, and only if it arrived after the current state began.
        let fresh = match reading {
            Some(r) if Some(r.received) != self.last_reading => {
                self.last_reading = Some(r.received);
                if r.received >= self.entered {
                    Some(r)
                } else {
                    None
                }
            }
            _ => None,
        };
        self.nearest_m = reading.and_then(|r| r.distance_m).filter(|d| d.is_finite());
        if self.land {
            return self.output();
        }
        let obstacle_m = self.cfg.obstacle_distance_m;
        let fresh_evidence = fresh.map(|r| self.evidence(&r, obstacle_m));
        if let (Some(r), Some(Evidence::Clear)) = (fresh, fresh_evidence) {
            self.last_clear = Some(r.received);
        }
        let in_state = now.since(self.entered);
        let rate = self.cfg.turn_rate_radps.abs();
        match self.state {
            FsmState::Check => match fresh_evidence {
                Some(Evidence::Blocked) => {
                    self.searches = 0;
                    self.enter(FsmState::Hover, now);
                }
                Some(Evidence::Clear) => {
                    self.searches = 0;
                    self.enter(FsmState::Forward, now);
                }
                _ if in_state >= self.cfg.check_timeout => {
                    // Nothing known this way: look elsewhere, or give up after a full search.
                    self.searches = self.searches.saturating_add(1);
                    if self.searches >= self.cfg.max_searches.max(1) {
                        self.land = true;
                    } else {
                        self.start_turn(now);
                    }
                }
                _ => {}
            },
            FsmState::Forward => {
                // No reading at all is stale at once; otherwise the newest clear one counts
                // (entering the state on a clear reading counts as one).
                let clear_since = self
                    .last_clear
                    .map_or(self.entered, |t| t.max(self.entered));
                let stale = reading.is_none() || now.since(clear_since) > self.cfg.reading_timeout;
                match fresh_evidence {
                    Some(Evidence::Blocked) => {
                        self.blocked_count = self.blocked_count.saturating_add(1)
                    }
                    Some(_) => self.blocked_count = 0,
                    None => {}
                }
                let blocked = self.blocked_count >= self.cfg.block_confirm.max(1);
                if blocked || stale || in_state >= self.cfg.forward_timeout {
                    let stop = if self.cfg.brake_speed_mps > 0.0 {
                        FsmState::Brake
                    } else {
                        FsmState::Hover
                    };
                    self.enter(stop, now);
                }
            }
            FsmState::Brake => {
                let still = speed_mps.is_some_and(|v| v.abs() <= self.cfg.brake_speed_mps);
                if still || in_state >= self.cfg.brake_timeout {
                    self.enter(FsmState::Hover, now);
                }
            }
            FsmState::Hover => {
                if in_state >= self.cfg.hover_time {
                    self.start_turn(now);
                }
            }
            FsmState::Turn => match self.cfg.variant {
                FsmVariant::Paper => {
                    let angle = self.cfg.turn_angle_rad;
                    let target = wrap_pi(self.turn_start_yaw + angle);
                    let elapsed = in_state.as_secs_f32();
                    let turned = (rate * elapsed).min(angle.abs());
                    self.yaw_sp = wrap_pi(self.turn_start_yaw + turned * angle.signum());
                    if turned >= angle.abs() {
                        let done = *self.ramp_done.get_or_insert(now);
                        let on_heading = wrap_pi(target - yaw).abs() <= self.cfg.turn_tolerance_rad;
                        if on_heading || now.since(done) >= self.cfg.turn_timeout {
                            self.yaw_sp = target;
                            self.enter(FsmState::Check, now);
                        }
                    }
                }
                FsmVariant::TurnUntilClear => {
                    let dir = if self.cfg.turn_angle_rad < 0.0 {
                        -1.0
                    } else {
                        1.0
                    };
                    // Lead the heading by a bounded amount so the setpoint does not run away
                    // from a drone that turns slower than asked.
                    let lead = wrap_pi(self.yaw_sp + dir * rate * dt - yaw);
                    if lead.abs() <= 0.5 {
                        self.yaw_sp = wrap_pi(self.yaw_sp + dir * rate * dt);
                    }
                    if let Some(r) = fresh {
                        if self.evidence(&r, self.cfg.clear_distance_m) == Evidence::Clear {
                            self.clear_count = self.clear_count.saturating_add(1);
                        } else {
                            self.clear_count = 0;
                        }
                        if self.clear_count >= self.cfg.clear_confirm.max(1) {
                            self.yaw_sp = yaw;
                            self.last_clear = Some(r.received);
                            self.enter(FsmState::Forward, now);
                            return self.output();
                        }
                    }
                    if in_state >= self.cfg.search_timeout {
                        // A full turn without a clear direction: hold the heading, land.
                        self.yaw_sp = yaw;
                        self.land = true;
                    }
                }
            },
        }
        self.output()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;

    const S: u64 = 1_000_000;
    const STEP: u64 = 20_000;

    /// A reading over a view that has depth everywhere.
    fn reading(t: u64, d: Option<f32>) -> Option<ObstacleReading> {
        Some(ObstacleReading {
            received: at(t),
            distance_m: d,
            depth_fraction: 1.0,
            contact_s: None,
        })
    }

    /// A reading with nothing in range over a view with little depth (a plain wall).
    fn unknown(t: u64) -> Option<ObstacleReading> {
        Some(ObstacleReading {
            received: at(t),
            distance_m: None,
            depth_fraction: 0.05,
            contact_s: None,
        })
    }

    /// The paper's FSM: the first blocked reading stops it, no slowing on approach.
    fn paper() -> AvoidanceFsm {
        let cfg = FsmConfig {
            block_confirm: 1,
            approach_distance_m: 0.0,
            brake_speed_mps: 0.0,
            ..FsmConfig::default()
        };
        AvoidanceFsm::new(cfg, at(0), 0.0)
    }

    #[test]
    fn forward_slows_on_approach_and_stops_on_a_confirmed_obstacle() {
        let cfg = FsmConfig::default();
        let mut f = AvoidanceFsm::new(cfg, at(0), 0.0);
        let out = f.step(at(STEP), 0.0, reading(STEP, None), None);
        assert_eq!((f.state(), out.forward_mps), (FsmState::Forward, 0.3));
        // Beyond the approach distance: full speed; half way in: half way down.
        let out = f.step(at(2 * STEP), 0.0, reading(2 * STEP, Some(2.5)), None);
        assert_eq!(out.forward_mps, 0.3);
        let mid = 0.5 * (cfg.obstacle_distance_m + cfg.approach_distance_m);
        let out = f.step(at(3 * STEP), 0.0, reading(3 * STEP, Some(mid)), None);
        let half = 0.5 * (cfg.forward_speed_mps + cfg.approach_speed_mps);
        assert!((out.forward_mps - half).abs() < 1e-5, "{out:?}");
        // One blocked reading is an outlier; the speed is the approach's end meanwhile.
        let out = f.step(at(4 * STEP), 0.0, reading(4 * STEP, Some(0.6)), None);
        assert_eq!((f.state(), out.forward_mps), (FsmState::Forward, 0.1));
        let out = f.step(at(5 * STEP), 0.0, reading(5 * STEP, Some(1.2)), None);
        assert_eq!(f.state(), FsmState::Forward);
        assert!(out.forward_mps > 0.1 && out.forward_mps < 0.3, "{out:?}");
        // Two in a row stop it.
        f.step(at(6 * STEP), 0.0, reading(6 * STEP, Some(0.9)), None);
        assert_eq!(f.state(), FsmState::Forward);
        let out = f.step(at(7 * STEP), 0.0, reading(7 * STEP, Some(0.9)), None);
        assert_eq!((f.state(), out.forward_mps), (FsmState::Brake, 0.0));
    }

    #[test]
    fn brake_ends_when_the_drone_is_still_or_at_its_timeout() {
        let cfg = FsmConfig {
            block_confirm: 1,
            ..FsmConfig::default()
        };
        let blocked = |t: u64| reading(t, Some(0.8));
        let mut f = AvoidanceFsm::new(cfg, at(0), 0.0);
        f.step(at(STEP), 0.0, reading(STEP, None), Some(0.0));
        f.step(at(2 * STEP), 0.0, blocked(2 * STEP), Some(0.3));
        assert_eq!(f.state(), FsmState::Brake);
        // Still moving (or a NaN or missing speed): braking, zero velocity asked.
        for (k, v) in [
            (3, Some(0.2)),
            (4, Some(f32::NAN)),
            (5, None),
            (6, Some(-0.06)),
        ] {
            let out = f.step(at(k * STEP), 0.0, blocked(k * STEP), v);
            assert_eq!((f.state(), out.forward_mps), (FsmState::Brake, 0.0), "{k}");
        }
        // Still -> Hover, which then lasts its full time.
        f.step(at(7 * STEP), 0.0, blocked(7 * STEP), Some(-0.04));
        assert_eq!(
            (f.state(), f.entered().as_micros()),
            (FsmState::Hover, 7 * STEP)
        );
        f.step(
            at(7 * STEP + cfg.hover_time.as_micros() - 1),
            0.0,
            None,
            Some(0.0),
        );
        assert_eq!(f.state(), FsmState::Hover);
        f.step(
            at(7 * STEP + cfg.hover_time.as_micros()),
            0.0,
            None,
            Some(0.0),
        );
        assert_eq!(f.state(), FsmState::Turn);

        // A speed that never falls: Hover at the timeout.
        let mut f = AvoidanceFsm::new(cfg, at(0), 0.0);
        f.step(at(STEP), 0.0, reading(STEP, None), Some(0.0));
        f.step(at(2 * STEP), 0.0, blocked(2 * STEP), Some(0.3));
        f.step(
            at(2 * STEP + cfg.brake_timeout.as_micros() - 1),
            0.0,
            None,
            Some(0.3),
        );
        assert_eq!(f.state(), FsmState::Brake);
        f.step(
            at(2 * STEP + cfg.brake_timeout.as_micros()),
            0.0,
            None,
            Some(0.3),
        );
        assert_eq!(f.state(), FsmState::Hover);
    }

    #[test]
    fn check_waits_for_a_fresh_reading_then_goes_forward_when_clear() {
        let mut f = paper();
        // A reading from before the state began does not count.
        let mut f2 = AvoidanceFsm::new(FsmConfig::default(), at(5 * S), 0.0);
        f2.step(at(5 * S + STEP), 0.0, reading(4 * S, None), None);
        assert_eq!(f2.state(), FsmState::Check);
        // No reading: stays, zero speed.
        let out = f.step(at(STEP), 0.0, None, None);
        assert_eq!((f.state(), out.forward_mps), (FsmState::Check, 0.0));
        // Clear (nothing in range) at t = 40 ms -> Forward at 40 ms, 0.3 m/s.
        let out = f.step(at(2 * STEP), 0.0, reading(2 * STEP, None), None);
        assert_eq!(f.state(), FsmState::Forward);
        assert_eq!(f.entered().as_micros(), 2 * STEP);
        assert_eq!(out.forward_mps, 0.3);
        // Also clear: an obstacle beyond 1 m.
        let mut f = paper();
        f.step(at(STEP), 0.0, reading(STEP, Some(1.2)), None);
        assert_eq!(f.state(), FsmState::Forward);
    }

    #[test]
    fn check_goes_to_hover_when_blocked() {
        let mut f = paper();
        f.step(at(STEP), 0.0, reading(STEP, Some(0.8)), None);
        assert_eq!(f.state(), FsmState::Hover);
        assert_eq!(f.output().forward_mps, 0.0);
    }

    #[test]
    fn forward_to_hover_to_turn_to_check_with_times() {
        let mut f = paper();
        f.step(at(STEP), 0.0, reading(STEP, None), None);
        assert_eq!(f.state(), FsmState::Forward);
        // The same reading again is not fresh; a far obstacle keeps going.
        f.step(at(2 * STEP), 0.0, reading(STEP, Some(0.5)), None);
        f.step(at(3 * STEP), 0.0, reading(3 * STEP, Some(1.5)), None);
        assert_eq!(f.state(), FsmState::Forward);
        // Readings keep coming while clear.
        let mut t = 3 * STEP;
        while t < 2 * S - 100_000 {
            t += 100_000;
            f.step(at(t), 0.0, reading(t, None), None);
            assert_eq!(f.state(), FsmState::Forward);
        }
        // Obstacle at 0.95 m at t = 2 s -> Hover at 2 s.
        f.step(at(2 * S), 0.0, reading(2 * S, Some(0.95)), None);
        assert_eq!(
            (f.state(), f.entered().as_micros()),
            (FsmState::Hover, 2 * S)
        );
        // Hover lasts exactly 1 s.
        f.step(at(3 * S - 1), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Hover);
        f.step(at(3 * S), 0.0, None, None);
        assert_eq!(
            (f.state(), f.entered().as_micros()),
            (FsmState::Turn, 3 * S)
        );
        // The yaw setpoint ramps at 1.5 rad/s towards +60 deg.
        let out = f.step(at(3 * S + 200_000), 0.0, None, None);
        assert!((out.yaw_sp_rad - 0.3).abs() < 1e-4, "{}", out.yaw_sp_rad);
        assert_eq!(out.forward_mps, 0.0);
        // Ramp done at 3.698 s; the heading follows -> Check.
        let target = 60.0_f32.to_radians();
        let t_ramp = 3 * S + (target / 1.5 * 1e6) as u64 + 1;
        f.step(at(t_ramp), target - 0.5, None, None);
        assert_eq!(f.state(), FsmState::Turn, "heading not there yet");
        f.step(at(t_ramp + STEP), target - 0.05, None, None);
        assert_eq!(
            (f.state(), f.entered().as_micros()),
            (FsmState::Check, t_ramp + STEP)
        );
        assert!((f.output().yaw_sp_rad - target).abs() < 1e-5);
        // And the cycle goes on from Check.
        f.step(
            at(t_ramp + 2 * STEP),
            target,
            reading(t_ramp + 2 * STEP, None),
            None,
        );
        assert_eq!(f.state(), FsmState::Forward);
        assert_eq!(f.transitions(), 5);
    }

    #[test]
    fn forward_stops_when_readings_stop() {
        let mut f = paper();
        f.step(at(STEP), 0.0, reading(STEP, None), None);
        assert_eq!(f.state(), FsmState::Forward);
        // The last reading is 300 ms old: still going; 1 µs later: stop.
        f.step(at(STEP + 300_000), 0.0, reading(STEP, None), None);
        assert_eq!(f.state(), FsmState::Forward);
        f.step(at(STEP + 300_001), 0.0, reading(STEP, None), None);
        assert_eq!(
            (f.state(), f.entered().as_micros()),
            (FsmState::Hover, STEP + 300_001)
        );
        // No reading at all is stale too.
        let mut f = paper();
        f.step(at(STEP), 0.0, reading(STEP, None), None);
        f.step(at(2 * STEP), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Hover);
    }

    #[test]
    fn turn_times_out_when_the_heading_lags() {
        let mut f = paper();
        f.step(at(STEP), 0.0, reading(STEP, Some(0.3)), None);
        f.step(at(STEP + S), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Turn);
        let ramp_end = STEP + S + 700_000; // 60 deg at 1.5 rad/s = 0.698 s
        f.step(at(ramp_end), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Turn);
        f.step(at(ramp_end + 2 * S - 1), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Turn);
        f.step(at(ramp_end + 2 * S), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Check);
    }

    #[test]
    fn heading_wraps_through_pi() {
        let mut f = AvoidanceFsm::new(FsmConfig::default(), at(0), 3.0);
        f.step(at(STEP), 3.0, reading(STEP, Some(0.3)), None);
        f.step(at(STEP + S), 3.0, None, None);
        let out = f.step(at(STEP + S + 800_000), 3.0, None, None);
        let expect = wrap_pi(3.0 + 60.0_f32.to_radians());
        assert!((out.yaw_sp_rad - expect).abs() < 1e-4);
        f.step(at(STEP + S + 820_000), expect, None, None);
        assert_eq!(f.state(), FsmState::Check);
    }

    #[test]
    fn turn_until_clear_keeps_turning_until_confirmed_clear() {
        let cfg = FsmConfig {
            variant: FsmVariant::TurnUntilClear,
            ..FsmConfig::default()
        };
        let mut f = AvoidanceFsm::new(cfg, at(0), 0.0);
        f.step(at(STEP), 0.0, reading(STEP, Some(0.6)), None);
        f.step(at(STEP + S), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Turn);
        // The drone follows the setpoint; readings are blocked (1.2 m < 1.5 m clear distance),
        // far beyond a 60 deg turn.
        let mut t = STEP + S;
        let mut yaw = 0.0;
        for _ in 0..50 {
            t += STEP;
            let out = f.step(at(t), yaw, reading(t, Some(1.2)), None);
            yaw = out.yaw_sp_rad;
        }
        assert_eq!(f.state(), FsmState::Turn);
        assert!((yaw - 1.5).abs() < 0.01, "turned 1 s at 1.5 rad/s: {yaw}");
        // Two clear readings, then a blocked one: the count restarts.
        for d in [None, Some(2.0), Some(0.9)] {
            t += STEP;
            f.step(at(t), yaw, reading(t, d), None);
        }
        assert_eq!(f.state(), FsmState::Turn);
        for _ in 0..2 {
            t += STEP;
            f.step(at(t), yaw, reading(t, None), None);
            assert_eq!(f.state(), FsmState::Turn);
        }
        t += STEP;
        let out = f.step(at(t), 1.55, reading(t, Some(3.0)), None);
        assert_eq!((f.state(), f.entered().as_micros()), (FsmState::Forward, t));
        // Heading held where the drone is.
        assert_eq!(out.yaw_sp_rad, 1.55);
        assert_eq!(out.forward_mps, 0.3);
    }

    #[test]
    fn turn_until_clear_setpoint_waits_for_a_slow_drone() {
        let cfg = FsmConfig {
            variant: FsmVariant::TurnUntilClear,
            ..FsmConfig::default()
        };
        let mut f = AvoidanceFsm::new(cfg, at(0), 0.0);
        f.step(at(STEP), 0.0, reading(STEP, Some(0.6)), None);
        f.step(at(STEP + S), 0.0, None, None);
        let mut t = STEP + S;
        for _ in 0..200 {
            t += STEP;
            f.step(at(t), 0.0, None, None);
        }
        assert!(f.output().yaw_sp_rad <= 0.5 + 1e-4);
    }

    /// A surface nearer than the stereo search (no distance, little depth) that the drone
    /// closes on: the time to contact stops `Forward`, confirmed like a distance; a long one
    /// does not, and turn-until-clear does not take a short one for clear.
    #[test]
    fn a_short_time_to_contact_blocks_without_a_distance() {
        let contact = |t: u64, contact_s: f32| {
            Some(ObstacleReading {
                contact_s: Some(contact_s),
                ..unknown(t).unwrap()
            })
        };
        let mut f = AvoidanceFsm::new(FsmConfig::default(), at(0), 0.0);
        f.step(at(STEP), 0.0, reading(STEP, None), None);
        assert_eq!(f.state(), FsmState::Forward);
        for k in 2..10 {
            f.step(at(k * STEP), 0.0, contact(k * STEP, 4.0), None);
        }
        assert_eq!(f.state(), FsmState::Forward, "a long time to contact");
        f.step(at(10 * STEP), 0.0, contact(10 * STEP, 0.9), None);
        assert_eq!(
            f.state(),
            FsmState::Forward,
            "one short reading is an outlier"
        );
        f.step(at(11 * STEP), 0.0, contact(11 * STEP, 0.8), None);
        assert_eq!(f.state(), FsmState::Brake);

        let off = FsmConfig {
            contact_time_s: 0.0,
            ..FsmConfig::default()
        };
        let mut f = AvoidanceFsm::new(off, at(0), 0.0);
        f.step(at(STEP), 0.0, reading(STEP, None), None);
        for k in 2..10 {
            f.step(at(k * STEP), 0.0, contact(k * STEP, 0.5), None);
        }
        assert_eq!(f.state(), FsmState::Forward, "the cue switched off");

        let turn = FsmConfig {
            variant: FsmVariant::TurnUntilClear,
            ..FsmConfig::default()
        };
        let clear_but_closing = |t: u64| {
            Some(ObstacleReading {
                contact_s: Some(0.5),
                ..reading(t, None).unwrap()
            })
        };
        let mut f = AvoidanceFsm::new(turn, at(0), 0.0);
        f.step(at(STEP), 0.0, reading(STEP, Some(0.5)), None);
        f.step(at(STEP + S + STEP), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Turn);
        let mut t = STEP + S + STEP;
        for _ in 0..10 {
            t += STEP;
            f.step(at(t), 0.0, clear_but_closing(t), None);
        }
        assert_eq!(f.state(), FsmState::Turn, "closing fast is not clear");
    }

    #[test]
    fn evidence_needs_depth_to_be_clear() {
        let r = |d, depth| ObstacleReading {
            received: at(0),
            distance_m: d,
            depth_fraction: depth,
            contact_s: None,
        };
        assert_eq!(r(Some(0.5), 0.0).evidence(1.0, 0.25), Evidence::Blocked);
        assert_eq!(r(Some(1.5), 0.3).evidence(1.0, 0.25), Evidence::Clear);
        assert_eq!(r(None, 0.25).evidence(1.0, 0.25), Evidence::Clear);
        assert_eq!(r(None, 0.2).evidence(1.0, 0.25), Evidence::Unknown);
        assert_eq!(r(Some(f32::NAN), 1.0).evidence(1.0, 0.25), Evidence::Clear);
        assert_eq!(r(Some(3.0), 0.0).evidence(1.0, 0.25), Evidence::Unknown);
    }

    #[test]
    fn check_does_not_take_silence_for_clear_and_searches_then_lands() {
        let cfg = FsmConfig::default();
        let mut f = paper();
        // Unknown readings at 25 Hz: Check holds, zero speed, until its timeout.
        let mut t = 0;
        while t + 40_000 < cfg.check_timeout.as_micros() {
            t += 40_000;
            let out = f.step(at(t), f.output().yaw_sp_rad, unknown(t), None);
            assert_eq!(
                (f.state(), out.forward_mps, out.land),
                (FsmState::Check, 0.0, false)
            );
        }
        // Timed out: turn to look elsewhere; each search in a new heading times out too.
        let mut searches = 0;
        let mut turns = 0;
        for _ in 0..20_000 {
            t += 40_000;
            let before = f.state();
            let out = f.step(at(t), f.output().yaw_sp_rad, unknown(t), None);
            assert_eq!(out.forward_mps, 0.0, "never forward on unknown readings");
            if before == FsmState::Check && f.state() == FsmState::Turn {
                turns += 1;
            }
            if before == FsmState::Check && (f.state() != FsmState::Check || out.land) {
                searches += 1;
            }
            if out.land {
                break;
            }
        }
        assert!(f.wants_to_land());
        assert_eq!(searches, usize::from(cfg.max_searches));
        assert_eq!(turns, usize::from(cfg.max_searches) - 1);
        // Bounded: each search is the check timeout plus a 60 deg turn.
        let turn_us = (cfg.turn_angle_rad / cfg.turn_rate_radps * 1e6) as u64 + 40_000;
        assert!(
            t <= u64::from(cfg.max_searches) * (cfg.check_timeout.as_micros() + turn_us) + 80_000
        );
        // Landing is kept (zero speed) whatever comes, until a reset.
        let out = f.step(at(t + 40_000), 0.0, reading(t + 40_000, None), None);
        assert!(out.land && out.forward_mps == 0.0);
        f.reset(at(t + 80_000), 0.0);
        assert!(!f.wants_to_land());
        assert_eq!(f.state(), FsmState::Check);
    }

    #[test]
    fn a_clear_reading_during_the_search_goes_forward_and_restarts_the_count() {
        let cfg = FsmConfig::default();
        let mut f = paper();
        f.step(
            at(cfg.check_timeout.as_micros()),
            0.0,
            unknown(cfg.check_timeout.as_micros()),
            None,
        );
        assert_eq!(f.state(), FsmState::Turn);
        let mut t = cfg.check_timeout.as_micros();
        while f.state() != FsmState::Check {
            t += STEP;
            f.step(at(t), f.output().yaw_sp_rad, None, None);
        }
        t += STEP;
        f.step(at(t), f.output().yaw_sp_rad, reading(t, None), None);
        assert_eq!(f.state(), FsmState::Forward);
        assert_eq!(f.searches, 0);
    }

    #[test]
    fn forward_stops_when_clear_evidence_stops() {
        let mut f = paper();
        f.step(at(STEP), 0.0, reading(STEP, None), None);
        assert_eq!(f.state(), FsmState::Forward);
        // Readings keep coming, but over a plain view: 300 ms after the last clear one, stop.
        let mut t = STEP;
        while t < STEP + 300_000 {
            t += STEP;
            f.step(at(t), 0.0, unknown(t), None);
            assert_eq!(f.state(), FsmState::Forward, "at {t}");
        }
        t += STEP;
        f.step(at(t), 0.0, unknown(t), None);
        assert_eq!((f.state(), f.entered().as_micros()), (FsmState::Hover, t));
    }

    #[test]
    fn forward_times_out_into_hover() {
        let cfg = FsmConfig::default();
        let mut f = paper();
        f.step(at(STEP), 0.0, reading(STEP, None), None);
        let end = STEP + cfg.forward_timeout.as_micros();
        let mut t = STEP;
        while t + 100_000 < end {
            t += 100_000;
            f.step(at(t), 0.0, reading(t, None), None);
            assert_eq!(f.state(), FsmState::Forward);
        }
        f.step(at(end), 0.0, reading(end, None), None);
        assert_eq!((f.state(), f.entered().as_micros()), (FsmState::Hover, end));
    }

    #[test]
    fn turn_until_clear_needs_clear_evidence_and_lands_after_its_timeout() {
        let cfg = FsmConfig {
            variant: FsmVariant::TurnUntilClear,
            ..FsmConfig::default()
        };
        let mut f = AvoidanceFsm::new(cfg, at(0), 0.0);
        f.step(at(STEP), 0.0, reading(STEP, Some(0.6)), None);
        f.step(at(STEP + S), 0.0, None, None);
        assert_eq!(f.state(), FsmState::Turn);
        let start = STEP + S;
        let mut t = start;
        // Unknown readings all the way round: no Forward, and a landing at the timeout.
        while t < start + cfg.search_timeout.as_micros() - STEP {
            t += STEP;
            let out = f.step(at(t), f.output().yaw_sp_rad, unknown(t), None);
            assert_eq!(
                (f.state(), out.forward_mps, out.land),
                (FsmState::Turn, 0.0, false)
            );
        }
        t += STEP;
        let yaw = f.output().yaw_sp_rad;
        let out = f.step(at(t), yaw, unknown(t), None);
        assert!(out.land);
        assert_eq!(out.forward_mps, 0.0);
        assert_eq!(out.yaw_sp_rad, yaw, "holds the heading it has");
        // The timeout covers more than a full turn.
        assert!(
            cfg.search_timeout.as_micros() as f32 * 1e-6 * cfg.turn_rate_radps
                > 2.0 * core::f32::consts::PI
        );
    }
}
