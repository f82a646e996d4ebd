//! Wall force field: when the nearest obstacle is closer than a threshold, a backward velocity
//! reference that grows as the distance shrinks (it is added to the forward velocity setpoint).
//!
//! `v = -gain * (threshold - d)`, limited to `max_speed`; zero at and beyond the threshold, and
//! when nothing is in range (`None`) or the distance is not a finite non-negative number.

/// Force-field tunables.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceFieldConfig {
    /// Distance below which the field pushes back, m.
    pub threshold_m: f32,
    /// Backward speed per m inside the threshold, (m/s)/m.
    pub gain: f32,
    /// Largest backward speed, m/s.
    pub max_speed_mps: f32,
}

impl Default for ForceFieldConfig {
    fn default() -> Self {
        Self {
            threshold_m: 0.7,
            gain: 1.0,
            max_speed_mps: 0.4,
        }
    }
}

/// Forward velocity reference from the force field, m/s (≤ 0: backwards).
pub fn backward_velocity(cfg: &ForceFieldConfig, obstacle_m: Option<f32>) -> f32 {
    match obstacle_m {
        Some(d) if d.is_finite() && d >= 0.0 && d < cfg.threshold_m => {
            let v = cfg.gain * (cfg.threshold_m - d);
            if v.is_finite() {
                -v.clamp(0.0, cfg.max_speed_mps.max(0.0))
            } else {
                0.0
            }
        }
        _ => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_outside_and_growing_inside() {
        let c = ForceFieldConfig::default();
        assert_eq!(backward_velocity(&c, None), 0.0);
        assert_eq!(backward_velocity(&c, Some(2.0)), 0.0);
        assert_eq!(backward_velocity(&c, Some(0.7)), 0.0);
        let a = backward_velocity(&c, Some(0.6));
        let b = backward_velocity(&c, Some(0.4));
        assert!(a < 0.0 && b < a, "{a} {b}");
        assert!((b + 0.3).abs() < 1e-6);
        assert_eq!(backward_velocity(&c, Some(0.0)), -0.4);
        assert_eq!(backward_velocity(&c, Some(f32::NAN)), 0.0);
        assert_eq!(backward_velocity(&c, Some(-1.0)), 0.0);
    }
}
