//! What a HIL run measured ([`HilResult`]): the counts of the lockstep, the camera and the
//! links, the flight's heights and drift, the autopilot's last telemetry and the 50 Hz log
//! rows ([`HilRow`]), with the one-fact-per-line summary `sim-host hil` prints.

use protocol::{FlightMode, LinkErrorCounts, Telemetry};

/// One row of the HIL log (every 20 ms of world time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HilRow {
    /// World time, s.
    pub t_s: f64,
    /// True position x, y (m) and height (m).
    pub pos: [f32; 3],
    /// True horizontal velocity in the world frame, m/s.
    pub vel: [f32; 2],
    /// Motor commands applied, 0..=1.
    pub motors: [f32; 4],
    /// The autopilot's flight mode in its latest telemetry (`None`: none yet).
    pub mode: Option<FlightMode>,
}

/// What a HIL run measured.
#[derive(Debug, Clone, Default)]
pub struct HilResult {
    /// World time flown, s.
    pub sim_s: f64,
    /// Wall time, s.
    pub wall_s: f64,
    /// IMU samples sent.
    pub imu_samples: u64,
    /// `Motors` replies matched to their sample.
    pub motor_replies: u64,
    /// IMU samples whose reply did not come within the timeout.
    pub reply_timeouts: u64,
    /// Frames streamed to the camera board.
    pub frames_sent: u64,
    /// Estimates mirrored back by the camera board.
    pub estimates: u64,
    /// Of those, valid ones (usable for control).
    pub valid_estimates: u64,
    /// How often each `EstimateFlags` bit (0..=7) was set in the estimates.
    pub flag_counts: [u64; 8],
    /// Frames whose estimate did not come within the timeout.
    pub frame_timeouts: u64,
    /// Wall time spent waiting for the autopilot's `Motors` replies, s.
    pub imu_wait_s: f64,
    /// Wall time the world was held for a frame's estimate, s.
    pub frame_wait_s: f64,
    /// Time with the drone airborne (above 2 cm), s.
    pub airborne_s: f64,
    /// Highest height reached, m.
    pub max_height_m: f64,
    /// Height at the end, m.
    pub final_height_m: f64,
    /// Largest horizontal distance from the start position, m.
    pub max_drift_m: f64,
    /// Wall and obstacle contacts.
    pub collisions: u32,
    /// Largest absolute motor command seen (0: the motors never ran).
    pub max_motor: f32,
    /// Decoding errors on the autopilot's host link (host side).
    pub autopilot_link_errors: LinkErrorCounts,
    /// Decoding errors on the camera board's host link (host side).
    pub stereo_link_errors: LinkErrorCounts,
    /// Decoding errors on the relayed board-to-board link (both directions), if relayed.
    pub relay_errors: LinkErrorCounts,
    /// Messages relayed camera board -> autopilot and autopilot -> camera board.
    pub relayed_messages: [u64; 2],
    /// The autopilot's last telemetry (its own count of camera-link errors included).
    pub last_telemetry: Option<Telemetry>,
    /// The log (50 Hz of world time).
    pub log: Vec<HilRow>,
    /// Why the MCAP flight log stopped being written, if it did.
    pub log_error: Option<String>,
    /// Why the flight ended before its duration (interrupted, a board's link closed), if it
    /// did: the result and its log cover the world time flown until then.
    pub ended_early: Option<String>,
}

impl HilResult {
    /// Sum of every decoding error seen on every link.
    pub fn total_link_errors(&self) -> u32 {
        self.autopilot_link_errors.total()
            + self.stereo_link_errors.total()
            + self.relay_errors.total()
            + self.last_telemetry.map_or(0, |t| t.link_errors.total())
    }

    /// A summary like `fly`'s, one fact per line.
    pub fn summary(&self) -> String {
        let mode = self
            .last_telemetry
            .map_or("none (no telemetry)", |t| t.flight_mode.name());
        format!(
            "world time        {:.2} s in {:.1} s wall ({:.3}x real time)\n\
             airborne          {:.2} s, max height {:.2} m, final height {:.2} m\n\
             max drift         {:.2} m (horizontal, from the start)\n\
             collisions        {}\n\
             imu lockstep      {} samples, {} motor replies, {} timeouts, {:.1} s waiting\n\
             camera            {} frames, {} estimates ({} valid; flag bits set {:?}), {} timeouts, world held {:.1} s\n\
             link errors       autopilot host {}, camera host {}, board-to-board relay {}, autopilot's own {}\n\
             relayed messages  camera->autopilot {}, autopilot->camera {}\n\
             final mode        {}{}",
            self.sim_s,
            self.wall_s,
            if self.wall_s > 0.0 { self.sim_s / self.wall_s } else { 0.0 },
            self.airborne_s,
            self.max_height_m,
            self.final_height_m,
            self.max_drift_m,
            self.collisions,
            self.imu_samples,
            self.motor_replies,
            self.reply_timeouts,
            self.imu_wait_s,
            self.frames_sent,
            self.estimates,
            self.valid_estimates,
            self.flag_counts,
            self.frame_timeouts,
            self.frame_wait_s,
            self.autopilot_link_errors.total(),
            self.stereo_link_errors.total(),
            self.relay_errors.total(),
            self.last_telemetry.map_or(0, |t| t.link_errors.total()),
            self.relayed_messages[0],
            self.relayed_messages[1],
            mode,
            self.ended_early
                .as_ref()
                .map_or(String::new(), |why| format!("\nended early       {why}")),
        )
    }
}
