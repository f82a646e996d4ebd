//! Inputs the unit tests of several stages share.

use protocol::{Estimate, EstimateFlags, WireTime};

/// A valid estimate of `forward_mps` straight ahead, nothing in range over a view with depth
/// everywhere.
pub fn forward_estimate(forward_mps: f32) -> Estimate {
    Estimate {
        seq: 0,
        capture_us: WireTime(0),
        forward_mps,
        sideways_mps: 0.0,
        obstacle_m: None,
        quality: 200,
        flags: EstimateFlags::NONE,
        processing_us: 0,
        depth_coverage: 255,
        near_columns: 0,
    }
}
