//! The battery on the unmodified `real` autopilot image: the bench puts a 1S LiPo's voltage on
//! the supply divider (PC4, ADC1 channel 14) and reads the result on the PWM outputs.
//!
//! * A battery ramped down in flight, sagging under the motors' current: the autopilot flies on
//!   while the compensated voltage is good, lands once it reads low, hurries the descent once
//!   it reads critical, and every motor duty is 0 at touchdown, never to run again.
//! * A flat battery on the ground: the `Arm` is refused, no motor ever runs.

use autopilot::AutopilotConfig;
use autopilot::battery::BatteryMonitor;
use protocol::{BatteryState, BoardToHost, Decoder, FlightMode, Message};
use virtual_board::bench::{At, Flow, Options, Setup, run};
use virtual_board::boards::autopilot::{Autopilot, BATTERY_V};
use virtual_board::firmware::Firmware;
use virtual_board::pilot::{CameraStandIn, GroundStation, MS};

const ARM_AT: u64 = 1_500 * MS;
/// The battery starts to fall, ns.
const RAMP_AT: u64 = 3_000 * MS;
/// How fast it falls, V/s: low (3.6 V) 1.5 s after the ramp starts, critical (3.4 V) 1 s later.
const RAMP_V_PER_S: f64 = 0.2;
/// The height the drone reports once armed, m.
const HOVER_M: f64 = 0.5;
/// The battery's internal resistance, Ω: the sag the motors' current puts on the reading.
const RESISTANCE_OHM: f64 = 0.12;
/// How long the motors must stay off after they stopped.
const STAY_OFF: u64 = 600 * MS;

struct Pilot {
    /// The resting voltage at `now`, V.
    resting_v: fn(u64) -> f64,
    ground: GroundStation,
    camera: CameraStandIn,
    telemetry: Decoder<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>,
    telemetry_read: usize,
    /// The battery verdict and flight mode of the last telemetry.
    state: Option<(BatteryState, FlightMode)>,
    /// When the telemetry first reported each verdict (low, critical) and when it first
    /// reported landing.
    low_at: Option<u64>,
    critical_at: Option<u64>,
    landing_at: Option<u64>,
    /// The verdict at the first report of a landing.
    landing_verdict: Option<BatteryState>,
    /// The lowest reading the firmware reported while flying normally, V.
    lowest_flying_reading: f64,
    last_ns: u64,
    running_before: bool,
    ran: bool,
    off_at: Option<u64>,
    came_back_at: Option<u64>,
}

impl Pilot {
    fn new(resting_v: fn(u64) -> f64) -> Self {
        Self {
            resting_v,
            ground: GroundStation::arming_at(ARM_AT, HOVER_M),
            camera: CameraStandIn::new(),
            telemetry: Decoder::new_mid_stream(),
            telemetry_read: 0,
            state: None,
            low_at: None,
            critical_at: None,
            landing_at: None,
            landing_verdict: None,
            lowest_flying_reading: f64::INFINITY,
            last_ns: 0,
            running_before: false,
            ran: false,
            off_at: None,
            came_back_at: None,
        }
    }

    fn read_telemetry(&mut self, now: u64, board: &Autopilot) {
        let sent = board.telemetry.tx.sent_bytes();
        for &byte in sent.get(self.telemetry_read..).unwrap_or(&[]) {
            if let Some(BoardToHost::Telemetry(t)) = self.telemetry.push(byte) {
                let Some(b) = t.battery else { continue };
                self.state = Some((b.state, t.flight_mode));
                if t.flight_mode == FlightMode::Flying {
                    self.lowest_flying_reading =
                        self.lowest_flying_reading.min(f64::from(b.voltage_v));
                }
                match b.state {
                    BatteryState::Low if self.low_at.is_none() => self.low_at = Some(now),
                    BatteryState::Critical if self.critical_at.is_none() => {
                        self.critical_at = Some(now);
                    }
                    _ => {}
                }
                if t.flight_mode == FlightMode::Landing && self.landing_at.is_none() {
                    self.landing_at = Some(now);
                    self.landing_verdict = Some(b.state);
                }
            }
        }
        self.telemetry_read = sent.len();
    }
}

impl virtual_board::bench::Probe<Autopilot> for Pilot {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let board = at.board();
        self.read_telemetry(now, board);
        // The world: hovering at HOVER_M once armed; landing, the height follows the descent
        // the autopilot flies (the land rate, the blind rate once the battery is critical).
        if let Some((verdict, FlightMode::Landing)) = self.state {
            let cfg = AutopilotConfig::default();
            let rate = if verdict == BatteryState::Critical {
                cfg.setpoints.blind_land_rate_mps
            } else {
                cfg.setpoints.land_rate_mps
            };
            let dt = (now - self.last_ns) as f64 / 1e9;
            let height = (self.ground.height_m() - f64::from(rate) * dt).max(0.0);
            self.ground.set_height(height);
        }
        self.camera.step(now, &board.link.rx);
        self.ground.step(now, &board.telemetry.rx);
        self.last_ns = now;

        // The battery sags under the current the motors draw.
        let duties = board.motors().map(|m| m.duty);
        let model = BatteryMonitor::new(AutopilotConfig::default().battery);
        let resting = (self.resting_v)(now);
        let current = f64::from(model.current_a(&duties.map(|d| d as f32), resting as f32));
        board.set_battery_v(resting - RESISTANCE_OHM * current);

        let all_off = duties.iter().all(|&d| d == 0.0);
        self.ran |= !all_off;
        if (RAMP_AT - 100 * MS..RAMP_AT).contains(&now) && duties.iter().all(|&d| d > 0.0) {
            self.running_before = true;
        }
        if now > RAMP_AT {
            match (self.off_at, all_off) {
                (None, true) => self.off_at = Some(now),
                (Some(_), false) if self.came_back_at.is_none() => self.came_back_at = Some(now),
                _ => {}
            }
        }
        match self.off_at {
            Some(off) if now > off + STAY_OFF => Flow::Stop,
            _ => Flow::Continue,
        }
    }
}

fn ramp(now: u64) -> f64 {
    let falling_s = now.saturating_sub(RAMP_AT) as f64 / 1e9;
    BATTERY_V - RAMP_V_PER_S * falling_s
}

#[test]
fn a_battery_ramped_down_in_flight_lands_then_hurries_and_stops_the_motors() {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let outcome = run(
        Setup {
            board: Autopilot::new(21).expect("the board"),
            firmware,
            probe: Pilot::new(ramp),
        },
        Options::seconds(9.0),
    )
    .expect("the run");
    let report = outcome.report();
    let p = &outcome.probe;
    assert!(p.running_before, "not flying before the ramp\n{report}");
    // Under hover thrust the reading sags below the landing threshold: the compensation kept
    // the flight going.
    let cfg = AutopilotConfig::default().battery;
    assert!(
        p.lowest_flying_reading < f64::from(cfg.low_v) + 0.05,
        "the reading never sagged: {} V\n{report}",
        p.lowest_flying_reading
    );
    let low = p.low_at.unwrap_or_else(|| panic!("never low\n{report}"));
    let critical = p
        .critical_at
        .unwrap_or_else(|| panic!("never critical\n{report}"));
    let landing = p
        .landing_at
        .unwrap_or_else(|| panic!("never landed\n{report}"));
    assert_eq!(p.landing_verdict, Some(BatteryState::Low), "{report}");
    assert!(
        low < critical,
        "low at {low}, critical at {critical}\n{report}"
    );
    // Low: 3.6 V is 1.5 s into the ramp, and the 1 s filter lags it.
    let ms = |t: u64| t as f64 / 1e6;
    println!(
        "battery low {:.0} ms, landing {:.0} ms, critical {:.0} ms after the ramp began",
        ms(low - RAMP_AT),
        ms(landing - RAMP_AT),
        ms(critical - RAMP_AT)
    );
    assert!(
        (1_500 * MS..=3_000 * MS).contains(&(low - RAMP_AT)),
        "low {:.0} ms into the ramp\n{report}",
        ms(low - RAMP_AT)
    );
    let off = p
        .off_at
        .unwrap_or_else(|| panic!("the motors never all stopped\n{report}"));
    // Landing from HOVER_M at the land rate at worst, then the touchdown confirmation, one
    // guidance period and the telemetry's period of slack.
    let ap = AutopilotConfig::default();
    let bound_ns = (HOVER_M / f64::from(ap.setpoints.land_rate_mps) * 1e9) as u64
        + ap.setpoints.landed_time.as_micros() * 1_000
        + 400 * MS;
    println!(
        "every motor at 0 {:.0} ms after the landing began (bound {:.0} ms)",
        ms(off - landing),
        ms(bound_ns)
    );
    assert!(
        off > landing && off - landing <= bound_ns,
        "motors off {:.0} ms after the landing began\n{report}",
        ms(off.saturating_sub(landing))
    );
    assert_eq!(p.came_back_at, None, "a motor ran again\n{report}");
    outcome.assert_clean();
}

#[test]
fn a_flat_battery_refuses_the_arm() {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let outcome = run(
        Setup {
            board: Autopilot::new(22).expect("the board"),
            firmware,
            probe: Pilot::new(|_| 3.6),
        },
        Options::seconds(3.0),
    )
    .expect("the run");
    let report = outcome.report();
    let p = &outcome.probe;
    assert!(!p.ran, "a motor ran on a flat battery\n{report}");
    assert_eq!(
        p.state,
        Some((BatteryState::Ok, FlightMode::Disarmed)),
        "{report}"
    );
    let arm_refused = outcome
        .log
        .lines()
        .iter()
        .rev()
        .find_map(|l| {
            let at = l.text.find("arm_refused=")?;
            l.text[at + "arm_refused=".len()..]
                .split(' ')
                .next()?
                .parse::<u32>()
                .ok()
        })
        .unwrap_or_else(|| panic!("no status line\n{report}"));
    assert_eq!(arm_refused, 1, "{report}");
}
