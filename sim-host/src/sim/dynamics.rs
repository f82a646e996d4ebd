//! 6-DOF rigid-body dynamics of the 40 g pocket drone: four brushed motors with first-order
//! dynamics, thrust and drag-torque coefficients, rotor spin-up yaw torque, linear drag, a floor
//! contact, integrated with RK4.
//!
//! Frames: body x forward, y right, z down; world x north, y east, z down (height = -z), the
//! same as `protocol::ExternalPosition`. Motors are numbered as in `protocol::MotorCommand`:
//! 1 front-right, 2 rear-right, 3 rear-left, 4 front-left (array index 0..=3).

use super::math::{Quat, V3};

/// Standard gravity, m/s².
pub const GRAVITY: f64 = 9.81;

/// Physical parameters of the drone. Defaults: see [`DroneParams::pocket_drone`].
#[derive(Debug, Clone, PartialEq)]
pub struct DroneParams {
    /// Mass, kg.
    pub mass_kg: f64,
    /// Principal moments of inertia (x, y, z), kg m².
    pub inertia_kgm2: V3,
    /// Motor positions in the body frame (x forward, y right), m, motors 1..4.
    pub motor_xy_m: [[f64; 2]; 4],
    /// Spin direction of each rotor about body +z (down): +1 or -1. A rotor spinning about +z
    /// pushes the body about -z through its drag torque.
    pub spin_dir: [f64; 4],
    /// Rotor speed at full throttle, rad/s. Rotor speed is proportional to throttle (brushed
    /// DC motor, speed ~ voltage).
    pub rotor_max_radps: f64,
    /// Thrust coefficient, N/(rad/s)².
    pub k_thrust: f64,
    /// Rotor drag-torque coefficient, N m/(rad/s)².
    pub k_torque: f64,
    /// Rotor (propeller + motor armature) inertia about its axis, kg m²: the spin-up yaw torque.
    pub rotor_inertia_kgm2: f64,
    /// Motor time constant (first order), s.
    pub motor_tau_s: f64,
    /// Linear drag, body axes (x, y, z), N/(m/s).
    pub drag_nspm: V3,
    /// Rotational damping, N m/(rad/s).
    pub rot_damping: f64,
    /// Collision radius (rotor tips), m.
    pub radius_m: f64,
}

impl DroneParams {
    /// A 40 g pocket drone. Derivations:
    /// * mass 40 g, motor-to-motor diagonal 92 mm (Crazyflie-class frame, as the paper's
    ///   "pocket drone" is a 40 g Crazyflie-sized quad): arm 46 mm, so each motor sits at
    ///   ±32.5 mm in x and y of the X configuration.
    /// * inertia: Crazyflie 2 identification (Förster 2015: Ixx = Iyy = 1.66e-5, Izz = 2.93e-5
    ///   kg m² at 27 g) scaled by mass 40/27 at equal dimensions: 2.46e-5, 2.46e-5, 4.34e-5.
    /// * hover at 65 % throttle: per-motor hover thrust m g / 4 = 0.0981 N at 0.65 of the
    ///   maximum rotor speed, so thrust at full speed is 0.0981 / 0.65² = 0.232 N per motor
    ///   (thrust/weight 2.37). With a maximum speed of 2800 rad/s (7 mm coreless motor, 45 mm
    ///   prop, Crazyflie-class), k_thrust = 0.232 / 2800² = 2.96e-8 N/(rad/s)².
    /// * k_torque = 0.006 m x k_thrust: Crazyflie torque/thrust ratio (Förster: 0.005964 m).
    /// * rotor inertia: 45 mm two-blade prop of 0.2 g as a rod (m L²/12 = 3.4e-8) plus the
    ///   armature (~6e-9): 4e-8 kg m².
    /// * motor time constant 64 ms: the INDI actuator model (first-order filter
    ///   coefficient 0.03 at 512 Hz: tau = 1 / (512 ln(1/0.97)) = 0.064 s).
    /// * drag: Förster's rotor-induced drag (~9.2e-7 N s/m per rad/s of summed rotor speed at
    ///   ~7000 rad/s) gives ~6.5e-3 N/(m/s); scaled up for the heavier 40 g frame to 8e-3
    ///   horizontally and 1e-2 vertically.
    /// * spin directions: front-right and rear-left counter-clockwise seen from above (about
    ///   body -z, `-1`), rear-right and front-left clockwise (`+1`).
    pub fn pocket_drone() -> Self {
        let d = 0.046 / core::f64::consts::SQRT_2;
        let k_thrust = 0.040 * GRAVITY / 4.0 / (0.65 * 0.65) / (2800.0 * 2800.0);
        Self {
            mass_kg: 0.040,
            inertia_kgm2: V3::new(2.46e-5, 2.46e-5, 4.34e-5),
            motor_xy_m: [[d, d], [-d, d], [-d, -d], [d, -d]],
            spin_dir: [-1.0, 1.0, -1.0, 1.0],
            rotor_max_radps: 2800.0,
            k_thrust,
            k_torque: 0.006 * k_thrust,
            rotor_inertia_kgm2: 4e-8,
            motor_tau_s: 0.064,
            drag_nspm: V3::new(8e-3, 8e-3, 1e-2),
            rot_damping: 2e-6,
            radius_m: 0.046 + 0.0225,
        }
    }

    /// Throttle at which the four motors together carry the weight in steady state.
    pub fn hover_throttle(&self) -> f64 {
        (self.mass_kg * GRAVITY / 4.0 / self.k_thrust).sqrt() / self.rotor_max_radps
    }
}

impl Default for DroneParams {
    fn default() -> Self {
        Self::pocket_drone()
    }
}

/// Full dynamic state of the drone.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DroneState {
    /// Position in the world frame, m.
    pub pos: V3,
    /// Velocity in the world frame, m/s.
    pub vel: V3,
    /// Attitude, body to world.
    pub att: Quat,
    /// Body rates p, q, r, rad/s.
    pub rates: V3,
    /// Rotor speeds, rad/s (magnitude, direction from [`DroneParams::spin_dir`]).
    pub rotor_radps: [f64; 4],
}

/// Time derivative of [`DroneState`].
#[derive(Debug, Clone, Copy)]
struct Deriv {
    dpos: V3,
    dvel: V3,
    datt: Quat,
    drates: V3,
    drotor: [f64; 4],
}

/// The simulated airframe: parameters, state, and the floor contact.
#[derive(Debug, Clone)]
pub struct Drone {
    /// Parameters.
    pub params: DroneParams,
    /// Current state.
    pub state: DroneState,
    /// Specific force over the last step in the body frame, m/s² (what an ideal accelerometer
    /// measures: acceleration minus gravity).
    pub specific_force_body: V3,
    /// True while resting on the floor.
    pub on_ground: bool,
}

impl Drone {
    /// A drone at rest on the floor at `(x, y)` with heading `yaw` (rad).
    pub fn on_floor(params: DroneParams, x: f64, y: f64, yaw: f64) -> Self {
        Self {
            params,
            state: DroneState {
                pos: V3::new(x, y, 0.0),
                att: Quat::from_euler(0.0, 0.0, yaw),
                ..Default::default()
            },
            specific_force_body: V3::new(0.0, 0.0, -GRAVITY),
            on_ground: true,
        }
    }

    /// A drone hovering at the given pose with rotors at hover speed.
    pub fn hovering(params: DroneParams, pos: V3, yaw: f64) -> Self {
        let w = params.hover_throttle() * params.rotor_max_radps;
        Self {
            params,
            state: DroneState {
                pos,
                att: Quat::from_euler(0.0, 0.0, yaw),
                rotor_radps: [w; 4],
                ..Default::default()
            },
            specific_force_body: V3::new(0.0, 0.0, -GRAVITY),
            on_ground: false,
        }
    }

    /// Total thrust (N) and body torque (N m) for the given rotor speeds and accelerations.
    fn forces(&self, rotor: &[f64; 4], drotor: &[f64; 4]) -> (f64, V3) {
        let p = &self.params;
        let mut thrust = 0.0;
        let mut tau = V3::ZERO;
        for i in 0..4 {
            let t = p.k_thrust * rotor[i] * rotor[i];
            thrust += t;
            let [x, y] = p.motor_xy_m[i];
            // r x F with F = (0, 0, -t) at (x, y, 0).
            tau.x += -y * t;
            tau.y += x * t;
            // Reaction of the motor torque driving the rotor (drag + spin-up).
            tau.z -= p.spin_dir[i]
                * (p.k_torque * rotor[i] * rotor[i] + p.rotor_inertia_kgm2 * drotor[i]);
        }
        (thrust, tau)
    }

    fn deriv(&self, s: &DroneState, cmd: &[f64; 4]) -> Deriv {
        let p = &self.params;
        let mut drotor = [0.0; 4];
        for i in 0..4 {
            let target = cmd[i].clamp(0.0, 1.0) * p.rotor_max_radps;
            drotor[i] = (target - s.rotor_radps[i]) / p.motor_tau_s;
        }
        let (thrust, tau) = self.forces(&s.rotor_radps, &drotor);
        let v_body = s.att.rotate_inv(s.vel);
        let f_body = V3::new(0.0, 0.0, -thrust) - p.drag_nspm.mul_elem(v_body);
        let acc = s.att.rotate(f_body) * (1.0 / p.mass_kg) + V3::new(0.0, 0.0, GRAVITY);
        let j = p.inertia_kgm2;
        let w = s.rates;
        let jw = j.mul_elem(w);
        let m = tau - w.cross(jw) - w * p.rot_damping;
        let drates = V3::new(m.x / j.x, m.y / j.y, m.z / j.z);
        Deriv {
            dpos: s.vel,
            dvel: acc,
            datt: s.att.derivative(w),
            drates,
            drotor,
        }
    }

    fn advance(s: &DroneState, d: &Deriv, h: f64) -> DroneState {
        let mut r = DroneState {
            pos: s.pos + d.dpos * h,
            vel: s.vel + d.dvel * h,
            att: s.att.add_scaled(d.datt, h),
            rates: s.rates + d.drates * h,
            rotor_radps: s.rotor_radps,
        };
        for i in 0..4 {
            r.rotor_radps[i] += d.drotor[i] * h;
        }
        r
    }

    /// Advances the state by `dt` seconds with throttles `cmd` (each clamped to 0..=1) held
    /// constant (classic RK4), then applies the floor contact.
    pub fn step(&mut self, cmd: &[f64; 4], dt: f64) {
        let s0 = self.state;
        let k1 = self.deriv(&s0, cmd);
        let k2 = self.deriv(&Self::advance(&s0, &k1, dt * 0.5), cmd);
        let k3 = self.deriv(&Self::advance(&s0, &k2, dt * 0.5), cmd);
        let k4 = self.deriv(&Self::advance(&s0, &k3, dt), cmd);
        let mut s = s0;
        s.pos += (k1.dpos + k2.dpos * 2.0 + k3.dpos * 2.0 + k4.dpos) * (dt / 6.0);
        s.vel += (k1.dvel + k2.dvel * 2.0 + k3.dvel * 2.0 + k4.dvel) * (dt / 6.0);
        let mut q = s0.att;
        for (k, wgt) in [
            (k1.datt, 1.0),
            (k2.datt, 2.0),
            (k3.datt, 2.0),
            (k4.datt, 1.0),
        ] {
            q = q.add_scaled(k, wgt * dt / 6.0);
        }
        s.att = q.normalized();
        s.rates += (k1.drates + k2.drates * 2.0 + k3.drates * 2.0 + k4.drates) * (dt / 6.0);
        for i in 0..4 {
            s.rotor_radps[i] +=
                (k1.drotor[i] + 2.0 * k2.drotor[i] + 2.0 * k3.drotor[i] + k4.drotor[i])
                    * (dt / 6.0);
            s.rotor_radps[i] = s.rotor_radps[i].max(0.0);
        }
        // Floor contact (z = 0, z down): the floor stops the fall, friction stops sliding and
        // the legs keep the airframe level while thrust is below weight.
        self.on_ground = false;
        if s.pos.z >= 0.0 {
            s.pos.z = 0.0;
            if s.vel.z > 0.0 {
                s.vel.z = 0.0;
            }
            let up = s.att.rotate(V3::new(0.0, 0.0, -1.0));
            let lift: f64 = s
                .rotor_radps
                .iter()
                .map(|w| self.params.k_thrust * w * w)
                .sum::<f64>()
                * -up.z;
            if lift < self.params.mass_kg * GRAVITY {
                self.on_ground = true;
                s.vel = V3::ZERO;
                let (_, _, yaw) = s.att.to_euler();
                s.att = Quat::from_euler(0.0, 0.0, yaw);
                s.rates = V3::ZERO;
            }
        }
        let acc = (s.vel - s0.vel) * (1.0 / dt) - V3::new(0.0, 0.0, GRAVITY);
        self.specific_force_body = s.att.rotate_inv(acc);
        self.state = s;
    }

    /// Kinetic + potential energy (rigid body only), J.
    pub fn energy(&self) -> f64 {
        let s = &self.state;
        let j = self.params.inertia_kgm2;
        0.5 * self.params.mass_kg * s.vel.dot(s.vel) + 0.5 * j.mul_elem(s.rates).dot(s.rates)
            - self.params.mass_kg * GRAVITY * s.pos.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hover_equilibrium_near_65_percent() {
        let p = DroneParams::pocket_drone();
        let u = p.hover_throttle();
        assert!((u - 0.65).abs() < 1e-9, "hover throttle {u}");
        let mut d = Drone::hovering(p, V3::new(2.0, 2.0, -1.0), 0.3);
        for _ in 0..2000 {
            d.step(&[u; 4], 0.0005);
        }
        let s = d.state;
        assert!((s.pos.z + 1.0).abs() < 1e-6, "z {}", s.pos.z);
        assert!(s.vel.norm() < 1e-6 && s.rates.norm() < 1e-9);
        assert!((d.specific_force_body.z + GRAVITY).abs() < 1e-6);
    }

    #[test]
    fn free_fall_matches_gravity() {
        let p = DroneParams {
            drag_nspm: V3::ZERO,
            ..DroneParams::pocket_drone()
        };
        let mut d = Drone::hovering(p, V3::new(0.0, 0.0, -10.0), 0.0);
        d.state.rotor_radps = [0.0; 4];
        for _ in 0..1000 {
            d.step(&[0.0; 4], 0.001);
        }
        let z = d.state.pos.z;
        assert!((z - (-10.0 + 0.5 * GRAVITY)).abs() < 1e-9, "z {z}");
        assert!(d.specific_force_body.norm() < 1e-6, "weightless");
    }

    #[test]
    fn torque_free_spin_conserves_energy_and_norm() {
        let p = DroneParams {
            drag_nspm: V3::ZERO,
            rot_damping: 0.0,
            ..DroneParams::pocket_drone()
        };
        let mut d = Drone::hovering(p, V3::new(0.0, 0.0, -100.0), 0.0);
        d.state.rotor_radps = [0.0; 4];
        d.state.rates = V3::new(3.0, -2.0, 5.0);
        let rot_e = |d: &Drone| {
            0.5 * d
                .params
                .inertia_kgm2
                .mul_elem(d.state.rates)
                .dot(d.state.rates)
        };
        let e0 = rot_e(&d);
        for _ in 0..2000 {
            d.step(&[0.0; 4], 0.0005);
        }
        assert!((rot_e(&d) - e0).abs() / e0 < 1e-6);
        let q = d.state.att;
        let n = q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z;
        assert!((n - 1.0).abs() < 1e-12);
    }

    #[test]
    fn differential_thrust_signs() {
        let p = DroneParams::pocket_drone();
        let u = p.hover_throttle();
        // More thrust on the left motors (3, 4) rolls right (positive roll).
        let mut d = Drone::hovering(p.clone(), V3::new(0.0, 0.0, -1.0), 0.0);
        for _ in 0..100 {
            d.step(&[u, u, u + 0.05, u + 0.05], 0.001);
        }
        assert!(d.state.rates.x > 0.0);
        // More on the front motors pitches nose up (positive pitch).
        let mut d = Drone::hovering(p.clone(), V3::new(0.0, 0.0, -1.0), 0.0);
        for _ in 0..100 {
            d.step(&[u + 0.05, u, u, u + 0.05], 0.001);
        }
        assert!(d.state.rates.y > 0.0);
        // Speeding up the counter-clockwise rotors (1, 3) yaws the body clockwise (positive r),
        // at first mostly through the spin-up torque.
        let mut d = Drone::hovering(p, V3::new(0.0, 0.0, -1.0), 0.0);
        d.step(&[u + 0.1, u, u + 0.1, u], 0.001);
        let r_early = d.state.rates.z;
        assert!(r_early > 0.0);
    }

    #[test]
    fn rests_on_floor_below_hover_throttle() {
        let p = DroneParams::pocket_drone();
        let mut d = Drone::on_floor(p, 1.0, 1.0, 0.0);
        for _ in 0..1000 {
            d.step(&[0.5; 4], 0.001);
        }
        assert!(d.on_ground && d.state.pos.z == 0.0);
        for _ in 0..1000 {
            d.step(&[0.8; 4], 0.001);
        }
        assert!(!d.on_ground && d.state.pos.z < -0.05);
    }
}
