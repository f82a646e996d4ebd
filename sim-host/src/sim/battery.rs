//! A 1S lithium-polymer flight battery: open-circuit voltage against state of charge, an
//! internal resistance, and the charge the motors draw.
//!
//! The brushed motors run on the battery through their FETs, so a rotor's speed follows the
//! duty times the terminal voltage: [`Battery::speed_factor`] scales the duty the drone model
//! sees by the terminal voltage over [`BatteryParams::reference_v`] (the voltage the drone's
//! thrust coefficients describe). As the battery discharges and sags, the same duty gives
//! less thrust, and the autopilot's height loop asks for more.
//!
//! Current: the propellers' shaft power grows with the cube of their speed and the battery
//! delivers it at its terminal voltage, so the motors draw [`BatteryParams::hover_current_a`]
//! times the mean of `(speed / hover speed)³` over the four rotors times
//! [`BatteryParams::reference_v`] over the terminal voltage; the electronics add
//! [`BatteryParams::avionics_current_a`].

use super::dynamics::DroneParams;

/// Open-circuit voltage of a 1S LiPo at rest against its state of charge, V, every 5 % from
/// empty (0) to full (1): a typical curve (steep above 90 % and below 10 %, flat around
/// 3.8 V in between).
pub const OCV_CURVE_V: [f64; 21] = [
    3.27, 3.61, 3.69, 3.71, 3.73, 3.75, 3.77, 3.79, 3.80, 3.82, 3.84, 3.85, 3.87, 3.91, 3.95, 3.98,
    4.02, 4.08, 4.11, 4.15, 4.20,
];

/// The battery's properties.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatteryParams {
    /// Capacity, mAh.
    pub capacity_mah: f64,
    /// Internal resistance with the leads, Ω.
    pub resistance_ohm: f64,
    /// State of charge at take-off, 0..=1.
    pub initial_charge: f64,
    /// Current of the four motors at the hover rotor speed from a supply at
    /// [`BatteryParams::reference_v`], A.
    pub hover_current_a: f64,
    /// Current of the boards (two Cortex-M4s, IMU, cameras, WiFi modem), A.
    pub avionics_current_a: f64,
    /// Terminal voltage at which the drone's rotor speed per duty is its nominal one, V.
    pub reference_v: f64,
}

impl BatteryParams {
    /// A charged 1S LiPo of `capacity_mah` for the 40 g pocket drone: 0.12 Ω (a 250-300 mAh
    /// cell with its JST lead), 3 A to hover (four 7 mm coreless motors; a Crazyflie-class
    /// quad hovers on about 2.5-3 A), 0.15 A for the electronics, thrust nominal at 3.9 V.
    pub fn lipo_1s(capacity_mah: f64) -> Self {
        Self {
            capacity_mah,
            resistance_ohm: 0.12,
            initial_charge: 1.0,
            hover_current_a: 3.0,
            avionics_current_a: 0.15,
            reference_v: 3.9,
        }
    }
}

/// The battery's state.
#[derive(Debug, Clone, PartialEq)]
pub struct Battery {
    /// Properties.
    pub params: BatteryParams,
    /// Charge left, C.
    charge_c: f64,
    /// Current drawn over the last step, A.
    current_a: f64,
}

/// Open-circuit voltage at state of charge `soc` (clamped to 0..=1), V: linear between the
/// points of [`OCV_CURVE_V`].
pub fn open_circuit_v(soc: f64) -> f64 {
    let x = soc.clamp(0.0, 1.0) * (OCV_CURVE_V.len() - 1) as f64;
    let i = (x.floor() as usize).min(OCV_CURVE_V.len() - 2);
    let f = x - i as f64;
    OCV_CURVE_V[i] + f * (OCV_CURVE_V[i + 1] - OCV_CURVE_V[i])
}

impl Battery {
    /// A battery at its initial charge.
    pub fn new(params: BatteryParams) -> Self {
        Self {
            charge_c: params.capacity_mah * 3.6 * params.initial_charge.clamp(0.0, 1.0),
            params,
            current_a: params.avionics_current_a,
        }
    }

    /// State of charge, 0..=1.
    pub fn charge(&self) -> f64 {
        let full = self.params.capacity_mah * 3.6;
        if full > 0.0 {
            (self.charge_c / full).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }

    /// Open-circuit (resting) voltage now, V.
    pub fn open_circuit_v(&self) -> f64 {
        open_circuit_v(self.charge())
    }

    /// Current drawn over the last step, A.
    pub fn current_a(&self) -> f64 {
        self.current_a
    }

    /// Terminal voltage under the last step's current, V (never below 0).
    pub fn terminal_v(&self) -> f64 {
        (self.open_circuit_v() - self.params.resistance_ohm * self.current_a).max(0.0)
    }

    /// Rotor speed per duty relative to the nominal one: the terminal voltage over
    /// [`BatteryParams::reference_v`].
    pub fn speed_factor(&self) -> f64 {
        self.terminal_v() / self.params.reference_v
    }

    /// Discharges over `dt` s with the rotors at `rotor_radps` on a drone with `drone`'s
    /// parameters (the current of the rotor speeds, see the module docs).
    pub fn step(&mut self, rotor_radps: &[f64; 4], drone: &DroneParams, dt: f64) {
        let hover = drone.hover_throttle() * drone.rotor_max_radps;
        let mean_cube = rotor_radps
            .iter()
            .map(|w| (w.max(0.0) / hover).powi(3))
            .sum::<f64>()
            / 4.0;
        // The power at the voltage of the last step (a tenth of a volt at least: a dead cell
        // delivers nothing rather than infinite current).
        let supply = self.params.reference_v / self.terminal_v().max(0.1);
        self.current_a =
            self.params.avionics_current_a + self.params.hover_current_a * mean_cube * supply;
        self.charge_c = (self.charge_c - self.current_a * dt).max(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_discharge_curve_runs_from_4_2_v_full_to_3_27_v_empty() {
        assert_eq!(open_circuit_v(1.0), 4.20);
        assert_eq!(open_circuit_v(0.0), 3.27);
        assert!((open_circuit_v(0.5) - 3.84).abs() < 1e-9);
        assert!((open_circuit_v(0.525) - 3.845).abs() < 1e-9);
        for k in 0..100 {
            let (a, b) = (k as f64 / 100.0, (k + 1) as f64 / 100.0);
            assert!(open_circuit_v(a) < open_circuit_v(b), "monotonic at {a}");
        }
    }

    #[test]
    fn hover_draws_its_current_and_empties_the_capacity_in_time() {
        let drone = DroneParams::pocket_drone();
        let hover = drone.hover_throttle() * drone.rotor_max_radps;
        let params = BatteryParams::lipo_1s(250.0);
        let mut b = Battery::new(params);
        assert_eq!(b.charge(), 1.0);
        // Fresh, at rest: the terminal voltage is the open-circuit one less the electronics'.
        let v0 = b.terminal_v();
        b.step(&[hover; 4], &drone, 1.0);
        let i = params.avionics_current_a + params.hover_current_a * params.reference_v / v0;
        assert!((b.current_a() - i).abs() < 1e-9);
        assert!((b.terminal_v() - (b.open_circuit_v() - 0.12 * i)).abs() < 1e-9);
        // 250 mAh at about 3 A: about 5 minutes to empty, the current rising as the voltage
        // falls.
        let mut t = 1.0;
        let mut charge_c = 250.0 * 3.6 - b.current_a();
        while b.charge() > 0.0 {
            let before = b.current_a();
            b.step(&[hover; 4], &drone, 1.0);
            assert!(b.current_a() >= before - 0.05, "at {t} s");
            charge_c -= b.current_a();
            t += 1.0;
        }
        assert!(
            charge_c <= 0.0 && charge_c > -b.current_a(),
            "{charge_c} C left"
        );
        assert!((250.0..330.0).contains(&t), "{t} s");
        // Sagging and flat: the same duty spins the rotors slower.
        assert!(b.speed_factor() < 0.8);
    }
}
