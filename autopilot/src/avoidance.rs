//! Avoidance: the stage that turns what the camera board sees ahead into guidance's velocity
//! and heading request.
//!
//! Takes: each Edge-FS [`Estimate`]'s obstacle reading ([`Avoidance::on_estimate`]), and at
//! each guidance step an [`AvoidanceInput`] (time, whether the drone flies normally and has
//! reached its flight height, its heading and the heading held so far). Gives: an
//! [`AvoidanceOutput`]: the forward velocity the avoidance FSM ([`crate::fsm`]) asks for plus
//! the wall force field's push back ([`crate::force_field`]), the heading setpoint, and whether
//! the FSM, finding no way to go, asks to land.
//!
//! * Readings: an estimate's obstacle distance and depth coverage are kept unless its image is
//!   unusable (too dark or too bright); its "nothing in range" only if its stereo part is usable
//!   (a frame without texture or stereo matches says nothing of free space, but an obstacle it
//!   reports stands). A reading older than the failsafe's estimate timeout is not used. The
//!   time to contact of the flow's divergence ([`protocol::Divergence`]) rides with it, taken
//!   at two standard errors towards "not approaching", together with the stereo distance's own
//!   time to contact (the distance over the closing speed of its range-rate track, also at two
//!   standard errors): the sooner of the two is the reading's. A frame without a stereo reading
//!   still gives a reading when that time is short enough to block the way.
//! * The FSM runs only in normal flight ([`FlightMode::Flying`](crate::FlightMode)): it starts
//!   in `Check` on the held heading once the drone is at its flight height and stops in any
//!   other mode; while it is stopped the request is zero velocity on the held heading.
//! * The force field acts whenever the motors run.

use crate::force_field::backward_velocity;
use crate::force_field::ForceFieldConfig;
use crate::fsm::{AvoidanceFsm, FsmConfig, FsmState, ObstacleReading};
use crate::range_rate::{Closing, RangeRate};
use protocol::{Estimate, EstimateFlags};
use timebase::{Duration, Instant};

/// Flags of a frame that says nothing about obstacles (the image itself is unusable).
const UNSEEN: EstimateFlags =
    EstimateFlags(EstimateFlags::TOO_DARK.0 | EstimateFlags::TOO_BRIGHT.0);

/// Flags of a frame whose stereo failed: an obstacle it reports stands (a surface nearer than
/// the stereo range leaves few matches), its "nothing in range" does not (the velocity may
/// still be invalid for flow reasons while the stereo part is fine).
const NO_DEPTH: EstimateFlags =
    EstimateFlags(EstimateFlags::NO_TEXTURE.0 | EstimateFlags::NO_STEREO_MATCH.0);

/// A time to contact counts at this many standard errors of the divergence towards "not
/// approaching": a short one is then certain.
const CONTACT_SIGMAS: f32 = 2.0;

/// The closing speed counts at this many standard errors below its estimate in the velocity
/// cross-check ([`Avoidance::cross_check`]).
pub const CLOSING_SIGMAS: f32 = 2.0;

/// The closing speed's standard error is taken as at least this, m/s: the nearest column's
/// depth errors are correlated from frame to frame, so the residuals understate it (measured
/// in flight: 0.11 m/s at 1 m for a single 0.5 s track).
pub const MIN_CLOSING_SIGMA_MPS: f32 = 0.05;

/// The closing speed must exceed the estimated speed by this much to overrule it, m/s.
pub const CLOSING_MARGIN_MPS: f32 = 0.15;

/// The closing speed overrules the estimate only once it has disagreed this long without a
/// break: a nearer surface sliding into the view's edge shrinks the nearest distance for a
/// few tenths of a second without any motion (in flight up to 0.36 s), while a wrong velocity
/// estimate persists (the suite's room 7 flew seconds at 0.3 m/s on a reading of 0.03).
pub const DISPUTE: Duration = Duration::from_millis(500);

/// The closing speed the track is sure of: [`CLOSING_SIGMAS`] standard errors (at least
/// [`MIN_CLOSING_SIGMA_MPS`] each) below its estimate, m/s.
fn sure_closing_mps(closing: Closing) -> f32 {
    closing.mps - CLOSING_SIGMAS * closing.sigma_mps.max(MIN_CLOSING_SIGMA_MPS)
}

/// What avoidance needs to know at a guidance step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AvoidanceInput {
    /// Time.
    pub now: Instant,
    /// Normal flight: the FSM may run (in any other mode it stops).
    pub flying: bool,
    /// The drone is at its flight height: a stopped FSM starts.
    pub at_flight_height: bool,
    /// Heading, rad.
    pub yaw_rad: f32,
    /// Heading setpoint held so far, rad: where a starting FSM looks first, and the request
    /// while it is stopped.
    pub held_yaw_rad: f32,
    /// Estimated horizontal speed, m/s (`None`: no fresh velocity estimate).
    pub speed_mps: Option<f32>,
}

/// What avoidance asks of guidance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AvoidanceOutput {
    /// `[forward, sideways]` body velocity setpoint, m/s (the FSM's forward speed plus the
    /// force field's, which is negative near a wall).
    pub velocity_mps: [f32; 2],
    /// Heading setpoint, rad (not wrapped while the FSM is stopped).
    pub yaw_sp_rad: f32,
    /// The FSM found no way to go within its timeouts: land where it is.
    pub land: bool,
}

/// The avoidance FSM, whether it runs, and the latest obstacle reading.
#[derive(Debug, Clone)]
pub struct Avoidance {
    fsm: AvoidanceFsm,
    /// True while the FSM drives the request.
    active: bool,
    obstacle: Option<ObstacleReading>,
    /// The stereo distances' range rate.
    range_rate: RangeRate,
    /// Guidance steps at which the range rate overruled the velocity estimate.
    overruled: u32,
    /// The forward velocity the last cross-check put in the estimate's place, m/s (`None`: it
    /// let the estimate stand).
    overrule: Option<f32>,
    /// Since when the closing speed has disagreed with the estimate.
    disputed_since: Option<Instant>,
}

impl Avoidance {
    /// FSM stopped, no reading yet.
    pub fn new(cfg: FsmConfig) -> Self {
        Self {
            fsm: AvoidanceFsm::new(cfg, Instant::ZERO, 0.0),
            active: false,
            obstacle: None,
            range_rate: RangeRate::new(),
            overruled: 0,
            overrule: None,
            disputed_since: None,
        }
    }

    /// Takes a new FSM configuration, keeping the state.
    pub fn set_config(&mut self, cfg: FsmConfig) {
        self.fsm.set_config(cfg);
    }

    /// The obstacle reading of an estimate received at `now` at heading `yaw_rad`, if it has
    /// one (see the module documentation).
    pub fn on_estimate(&mut self, est: &Estimate, yaw_rad: f32, now: Instant) {
        if est.flags.0 & UNSEEN.0 != 0 {
            return;
        }
        let d = match est.obstacle_m {
            Some(d) if d.is_finite() && d >= 0.0 => Some(Some(d)),
            Some(_) => None, // garbage: no reading
            // A frame whose stereo failed says nothing of free space.
            None if est.flags.0 & NO_DEPTH.0 != 0 => None,
            None => Some(None),
        };
        let depth_fraction = if est.flags.0 & NO_DEPTH.0 == 0 {
            est.depth_fraction()
        } else {
            0.0
        };
        if let Some(distance_m) = d {
            self.range_rate.on_distance(distance_m, yaw_rad, now);
        }
        let flow_contact_s = est
            .divergence
            .and_then(|d| d.time_to_contact_within_s(-CONTACT_SIGMAS));
        let range_contact_s = d.flatten().and_then(|distance_m| {
            let closing = self.range_rate.closing(now)?;
            let sure = sure_closing_mps(closing);
            (sure > 0.0).then(|| distance_m / sure)
        });
        // The sooner of the two: the flow's divergence (which needs no range) and the stereo
        // distance over its closing speed (which needs no flow).
        let contact_s = match (flow_contact_s, range_contact_s) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        // Without a stereo reading a time to contact short enough to block still stands (it
        // needs no range); a longer one does not replace the last distance.
        let blocking = contact_s.filter(|t| *t < self.fsm.config().contact_time_s);
        let d = d.or_else(|| blocking.map(|_| None));
        if let Some(distance_m) = d {
            self.obstacle = Some(ObstacleReading {
                received: now,
                distance_m,
                depth_fraction,
                contact_s,
            });
        }
    }

    /// One guidance step: starts, steps or stops the FSM and adds the force field.
    pub fn step(
        &mut self,
        input: &AvoidanceInput,
        force_field: &ForceFieldConfig,
        estimate_timeout: Duration,
    ) -> AvoidanceOutput {
        let now = input.now;
        let obstacle = self
            .obstacle
            .filter(|o| now.since(o.received) <= estimate_timeout);
        let mut v_sp = [0.0f32; 2];
        let mut yaw_sp = input.held_yaw_rad;
        let mut land = false;
        if input.flying {
            if !self.active && input.at_flight_height {
                self.fsm.reset(now, yaw_sp);
                self.active = true;
            }
            if self.active {
                let out = self.fsm.step(now, input.yaw_rad, obstacle, input.speed_mps);
                v_sp[0] = out.forward_mps;
                yaw_sp = out.yaw_sp_rad;
                land = out.land;
            }
        } else {
            self.active = false;
        }
        v_sp[0] += backward_velocity(force_field, obstacle.and_then(|o| o.distance_m));
        AvoidanceOutput {
            velocity_mps: v_sp,
            yaw_sp_rad: yaw_sp,
            land,
        }
    }

    /// Stops the FSM (on the ground, at touchdown); it starts again in `Check`.
    pub fn stop(&mut self) {
        self.active = false;
        self.range_rate.reset();
    }

    /// The velocity estimate `[forward, sideways]` (m/s) checked against the obstacle's range
    /// rate at `now`: a static obstacle cannot close faster than the drone moves, so when
    /// the stereo distance shrinks faster ([`CLOSING_SIGMAS`] standard errors, at least
    /// [`MIN_CLOSING_SIGMA_MPS`] each, below its estimate) than the estimate's speed plus
    /// [`CLOSING_MARGIN_MPS`], the estimate is wrong, and once the disagreement has lasted
    /// [`DISPUTE`] its forward velocity is raised to that closing speed (the obstacle is in
    /// the camera's view, ahead). Guidance then brakes what the drone really does; the
    /// estimate itself is not changed.
    pub fn cross_check(&mut self, velocity: Option<[f32; 2]>, now: Instant) -> Option<[f32; 2]> {
        self.overrule = None;
        let (Some([forward, sideways]), Some(closing)) = (velocity, self.closing(now)) else {
            self.disputed_since = None;
            return velocity;
        };
        let sure = sure_closing_mps(closing);
        let speed = libm::sqrtf(forward * forward + sideways * sideways);
        if sure <= speed + CLOSING_MARGIN_MPS {
            self.disputed_since = None;
            return velocity;
        }
        let since = *self.disputed_since.get_or_insert(now);
        if now.since(since) < DISPUTE {
            return velocity;
        }
        let raised = forward.max(sure);
        self.overruled = self.overruled.wrapping_add(1);
        self.overrule = Some(raised);
        Some([raised, sideways])
    }

    /// The closing speed on the nearest obstacle at `now`, from the stereo distances.
    pub fn closing(&self, now: Instant) -> Option<Closing> {
        self.range_rate.closing(now)
    }

    /// Guidance steps at which the range rate overruled the velocity estimate
    /// ([`Self::cross_check`]).
    pub fn overruled(&self) -> u32 {
        self.overruled
    }

    /// The forward velocity the last cross-check put in the estimate's place, m/s (`None`:
    /// the estimate stood).
    pub fn overrule(&self) -> Option<f32> {
        self.overrule
    }

    /// True while the FSM drives the request.
    pub fn active(&self) -> bool {
        self.active
    }

    /// The FSM's state while it runs.
    pub fn state(&self) -> Option<FsmState> {
        self.active.then(|| self.fsm.state())
    }

    /// The avoidance FSM.
    pub fn fsm(&self) -> &AvoidanceFsm {
        &self.fsm
    }

    /// The latest obstacle reading, however old.
    pub fn obstacle(&self) -> Option<ObstacleReading> {
        self.obstacle
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;
    use crate::test_support::forward_estimate;
    use crate::AutopilotConfig;

    fn input(now_us: u64, flying: bool, at_flight_height: bool) -> AvoidanceInput {
        AvoidanceInput {
            now: at(now_us),
            flying,
            at_flight_height,
            yaw_rad: 0.2,
            held_yaw_rad: 0.2,
            speed_mps: Some(0.0),
        }
    }

    fn sees(obstacle_m: Option<f32>) -> Estimate {
        Estimate {
            obstacle_m,
            ..forward_estimate(0.0)
        }
    }

    #[test]
    fn a_frame_whose_stereo_failed_reports_obstacles_but_not_free_space() {
        let mut a = Avoidance::new(FsmConfig::default());
        let distance = |a: &Avoidance| a.obstacle().and_then(|o| o.distance_m);
        let est = |obstacle_m, flags| Estimate {
            flags,
            ..sees(obstacle_m)
        };
        a.on_estimate(&est(Some(2.0), EstimateFlags::NONE), 0.0, at(40_000));
        assert_eq!(distance(&a), Some(2.0));
        // A plain view: its "nothing in range" does not clear the last reading.
        a.on_estimate(&est(None, EstimateFlags::NO_STEREO_MATCH), 0.0, at(80_000));
        a.on_estimate(&est(None, EstimateFlags::NO_TEXTURE), 0.0, at(120_000));
        assert_eq!(distance(&a), Some(2.0));
        // A surface nearer than the stereo range, reported from a frame with few matches: kept,
        // with no depth to speak of.
        a.on_estimate(
            &est(Some(0.53), EstimateFlags::NO_STEREO_MATCH),
            0.0,
            at(160_000),
        );
        assert_eq!(distance(&a), Some(0.53));
        assert_eq!(a.obstacle().unwrap().depth_fraction, 0.0);
        // A dark frame says nothing at all, nor does a garbage distance.
        a.on_estimate(&est(Some(0.2), EstimateFlags::TOO_DARK), 0.0, at(200_000));
        a.on_estimate(&est(Some(f32::NAN), EstimateFlags::NONE), 0.0, at(210_000));
        assert_eq!(distance(&a), Some(0.53));
        // A usable view with nothing in range clears it.
        a.on_estimate(&est(None, EstimateFlags::NONE), 0.0, at(240_000));
        assert_eq!(distance(&a), None);
        assert_eq!(a.obstacle().unwrap().received, at(240_000));
    }

    /// The suite's room 7 (seed 9001): the drone closes on an obstacle at 0.3 m/s while the
    /// velocity estimate reads 0.03. The stereo distance shrinks at the true rate: after half a
    /// second of disagreement guidance flies on the closing speed, which it brakes; an estimate
    /// that agrees, or a distance that holds, is left alone.
    #[test]
    fn a_closing_speed_the_estimate_misses_overrules_it() {
        let run = |closing_mps: f32, estimate: [f32; 2]| {
            let mut a = Avoidance::new(FsmConfig::default());
            let mut out = [None; 60];
            for (k, o) in (0..60u64).zip(out.iter_mut()) {
                let t = k * 20_000;
                if k % 2 == 0 {
                    let d = 1.5 - closing_mps * t as f32 * 1e-6;
                    a.on_estimate(&sees(Some(d)), 0.0, at(t));
                }
                *o = a.cross_check(Some(estimate), at(t));
            }
            (out, a.overruled())
        };
        let (out, overruled) = run(0.3, [0.03, 0.0]);
        // The track needs 0.4 s, the disagreement 0.5 s more.
        assert!(out[..45].iter().all(|v| *v == Some([0.03, 0.0])), "{out:?}");
        let last = out.last().unwrap().unwrap();
        assert!(
            (0.2..=0.31).contains(&last[0]) && last[1] == 0.0,
            "{last:?}"
        );
        assert!(overruled > 0);
        for (closing, estimate) in [(0.3, [0.28, 0.05]), (0.0, [0.03, 0.0]), (0.3, [0.0, 0.3])] {
            let (out, overruled) = run(closing, estimate);
            assert_eq!(overruled, 0, "{closing} {estimate:?}");
            assert!(out.iter().all(|v| *v == Some(estimate)));
        }
        // No estimate: nothing to check.
        let mut a = Avoidance::new(FsmConfig::default());
        assert_eq!(a.cross_check(None, at(0)), None);
    }

    /// The stereo distance closing fast on an obstacle blocks the way before the distance
    /// does: at 0.9 m/s from 2.5 m, with no divergence, the reading's time to contact drops
    /// below `contact_time_s` (1.5 s) while the obstacle is still beyond
    /// `obstacle_distance_m` (1 m); a distance that holds gives no time to contact.
    #[test]
    fn a_fast_closing_distance_is_a_time_to_contact() {
        let cfg = FsmConfig::default();
        let contact = |closing_mps: f32| {
            let mut a = Avoidance::new(cfg);
            let mut first_blocking = None;
            for k in 0..40u64 {
                let t = k * 40_000;
                let d = 2.5 - closing_mps * t as f32 * 1e-6;
                a.on_estimate(&sees(Some(d)), 0.0, at(t));
                let reading = a.obstacle().unwrap();
                if first_blocking.is_none()
                    && reading.contact_s.is_some_and(|c| c < cfg.contact_time_s)
                {
                    first_blocking = reading.distance_m;
                }
            }
            first_blocking
        };
        let d = contact(0.9).expect("a fast closing blocks");
        assert!(d > cfg.obstacle_distance_m, "blocked only at {d} m");
        assert_eq!(contact(0.0), None);
        assert_eq!(contact(0.3), None, "the forward speed closes without alarm");
    }

    #[test]
    fn the_fsm_starts_at_flight_height_and_stops_outside_normal_flight() {
        let cfg = AutopilotConfig::default();
        let mut a = Avoidance::new(cfg.fsm);
        // Climbing: held heading, no FSM.
        let out = a.step(
            &input(0, true, false),
            &cfg.force_field,
            cfg.failsafe.estimate_timeout,
        );
        assert_eq!(
            out,
            AvoidanceOutput {
                velocity_mps: [0.0; 2],
                yaw_sp_rad: 0.2,
                land: false
            }
        );
        assert_eq!(a.state(), None);
        // At height: Check on the held heading; a clear view then sends it forward.
        a.step(
            &input(20_000, true, true),
            &cfg.force_field,
            cfg.failsafe.estimate_timeout,
        );
        assert_eq!(a.state(), Some(FsmState::Check));
        a.on_estimate(&sees(None), 0.0, at(30_000));
        let out = a.step(
            &input(40_000, true, true),
            &cfg.force_field,
            cfg.failsafe.estimate_timeout,
        );
        assert_eq!(a.state(), Some(FsmState::Forward));
        a.step(
            &input(60_000, true, true),
            &cfg.force_field,
            cfg.failsafe.estimate_timeout,
        );
        let out2 = a.step(
            &input(80_000, true, true),
            &cfg.force_field,
            cfg.failsafe.estimate_timeout,
        );
        assert_eq!(out.yaw_sp_rad, 0.2);
        assert_eq!(out2.velocity_mps, [cfg.fsm.forward_speed_mps, 0.0]);
        // Any other mode stops it; back in normal flight it starts again in Check.
        let out = a.step(
            &input(100_000, false, true),
            &cfg.force_field,
            cfg.failsafe.estimate_timeout,
        );
        assert_eq!(out.velocity_mps, [0.0; 2]);
        assert!(!a.active());
        a.step(
            &input(120_000, true, true),
            &cfg.force_field,
            cfg.failsafe.estimate_timeout,
        );
        assert_eq!(a.state(), Some(FsmState::Check));
        a.stop();
        assert_eq!(a.state(), None);
    }

    #[test]
    fn the_force_field_pushes_back_in_any_mode_until_the_reading_is_stale() {
        let cfg = AutopilotConfig::default();
        let mut a = Avoidance::new(cfg.fsm);
        a.on_estimate(&sees(Some(0.4)), 0.0, at(1_000_000));
        let push = backward_velocity(&cfg.force_field, Some(0.4));
        assert!(push < 0.0);
        for flying in [true, false] {
            let out = a.step(
                &input(1_000_000, flying, false),
                &cfg.force_field,
                cfg.failsafe.estimate_timeout,
            );
            assert_eq!(out.velocity_mps, [push, 0.0]);
        }
        let stale = 1_000_000 + cfg.failsafe.estimate_timeout.as_micros() + 1;
        assert_eq!(
            a.step(
                &input(stale, false, false),
                &cfg.force_field,
                cfg.failsafe.estimate_timeout
            )
            .velocity_mps,
            [0.0; 2]
        );
    }

    #[test]
    fn an_fsm_without_a_way_to_go_asks_to_land() {
        let cfg = AutopilotConfig::default();
        let mut a = Avoidance::new(cfg.fsm);
        let mut t = 0;
        let mut land = false;
        // Never a reading: every Check times out into a turn until the searches run out.
        while !land && t < 120_000_000 {
            t += 20_000;
            land = a
                .step(
                    &input(t, true, true),
                    &cfg.force_field,
                    cfg.failsafe.estimate_timeout,
                )
                .land;
        }
        assert!(land, "asked to land within {t} us");
        assert!(a.fsm().wants_to_land());
    }
}
