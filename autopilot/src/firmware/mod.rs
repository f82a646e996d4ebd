//! RTIC 2 application of the autopilot firmware (thumbv7em-none-eabihf only).
//!
//! A thin shell around [`autopilot::app::Autopilot`] on the board of [`autopilot::board`]; the
//! tasks mirror `autopilot::tasks::TASKS` (same names and relative priorities) and each body is
//! one call into the library. What differs between flavours is in one module each: [`real`]
//! (own sensors, board clock) and [`lockstep`] (`hil`, `qemu`: the host's IMU samples and world
//! time), selected as `flavour`; each fulfils the contract both boards share
//! ([`board_support::flavour::Flavour`]), as the camera board's do.
//!
//! | RTIC task | prio | trigger | body |
//! |---|---|---|---|
//! | `link_uart`, `telemetry_uart`, `rc_uart` | 6 | USART2, USART1, UART5 interrupts | receive bytes into lock-free queues (back-pressure: [`board_support::uart_rx`]; the telemetry port by DMA in the `hil` flavour, [`board_support::uart_dma`]); transmit queued frames ([`board_support::uart_tx`]); one [`board_support::uart_link`] each |
//! | `telemetry_dma` | 6 | DMA2 stream 2 (`hil` flavour; never enabled in the others) | half/full buffer: pends `telemetry_uart` |
//! | `control_loop` | 5 | TIM2 at 512 Hz (real) | reads the MPU-6000 on SPI2, checks the sample ([`autopilot::mpu6000`]; configures a reset sensor again), `Autopilot::on_imu`, motors; feeds the watchdog while `guidance` and `heartbeat` run |
//! | `imu_indi` | 5 | IMU sample from the host link (lockstep) | `Autopilot::on_imu`, motors (only once the host enabled them), releases the periodic tasks |
//! | `outputs_watch` | 5 | 100 Hz, board clock (lockstep) | the PWM outputs to 0 when the host's samples stopped or it never enabled them (`flavour::outputs_live`) |
//! | `stereo_rx` | 4 | woken by `link_uart` | `Autopilot::on_stereo_bytes` |
//! | `host_rx` | 4 | woken by `telemetry_uart` | position / command / parameter requests from the host (the camera board's passed on over the link; IMU samples: lockstep only) |
//! | `rc_rx` | 4 | woken by `rc_uart`, and every 20 ms (only with `board::RC_RECEIVER`) | [`autopilot::rc`]: SBUS frames -> commands and the RC kill latch |
//! | `guidance` | 3 | 50 Hz | `Autopilot::guidance_step`, `motor_safety`; its liveness stamp for the watchdog's feeder (real) |
//! | `gyro_tx` | 2 | 128 Hz | `Autopilot::gyro_attitude` to the camera board |
//! | `baro` | 2 | its conversions (real) | MS5611 on SPI2 -> `Autopilot::on_baro` |
//! | `telemetry` | 1 | 10 Hz | the supply voltage (real: ADC1 on PC4, `board::hw::BatteryInput`) -> `Autopilot::on_battery`; `Autopilot::telemetry` to the host |
//! | `heartbeat` | 1 | 1 Hz | heartbeats to both links, LED, watchdog (lockstep; real: its liveness stamp), status line |
//! | `idle` | 0 | nothing else to run | `WFI`: the core sleeps until the next interrupt (SysTick, TIM2, a UART); the watchdog, the timers and the UARTs run on in Sleep mode (RM0090 5.3.3) |
//!
//! No task ever waits for a UART: frames are queued whole or dropped and counted
//! (`tx_dropped` in the status line), and the UART's interrupt sends them. A lock on a transmit
//! queue is held for the copy of one frame.
//!
//! Parameters: at boot the configuration is the record saved in the parameter sector
//! ([`board_support::param_flash`], `Autopilot::from_store`), or the defaults when there is none
//! or it is bad (logged, and answered to `ParamOp::Storage`). A save (`ParamOp::Save`, only
//! with the motors off) erases and programs the sector in `host_rx` with the `ap` lock held:
//! the core stalls for the erase anyway (a second or two), so the watchdog is given
//! [`board_support::watchdog::SAVE`] for it ([`board_support::param_flash::WatchedSector`]). A link key provisioned over the
//! link is written the same way at once, beside the saved parameters
//! (`Autopilot::save_link_key`), and every save carries it; the boot loads it with the
//! parameters. The `qemu` flavour has no parameter storage.
//!
//! Watchdog (real flavour): [`autopilot::board::WATCHDOG`], at most 25 ms at the slowest LSI,
//! is fed by the 512 Hz control loop, and only while the guidance task and the heartbeat have
//! run recently (their [`board_support::watchdog::Liveness`] stamps): a hang anywhere starves
//! it (see [`autopilot::board::WATCHDOG_MS`]).
//!
//! Faults: the panic and HardFault handlers force the motor outputs off at the timer and GPIO
//! registers first ([`autopilot::board::hw::motors_off`]), then log, then wait for the
//! watchdog. After any reset the library starts disarmed and the PWM at 0.

mod clock;
#[cfg(any(feature = "qemu", feature = "hil"))]
#[path = "lockstep.rs"]
mod flavour;
#[cfg(not(any(feature = "qemu", feature = "hil")))]
#[path = "real.rs"]
mod flavour;
mod sensors;

use autopilot::app::Autopilot;
use autopilot::board::hw;
use core::mem::MaybeUninit;
use core::sync::atomic::AtomicU32;
use defmt_rtt as _;

// Panic and HardFault: motors off at the registers first, then log, then the watchdog.
board_support::fault_handlers!(hw::motors_off);

rtic_monotonics::systick_monotonic!(Mono, 1_000);

/// The autopilot state: CPU-only, so it lives in CCM. NOLOAD: `init` writes it first.
#[link_section = ".ccmram"]
static mut AP: MaybeUninit<Autopilot> = MaybeUninit::uninit();

/// Bytes of each receive queue between the RX interrupt and its decoding task.
const RX_QUEUE: usize = 2048;
/// Bytes of the SBUS receive queue (about five frames).
const RC_QUEUE: usize = 128;
/// Bytes of each transmit queue: the link's 128 Hz gyro messages and the host link's
/// telemetry each take a small part of it between two interrupts' worth of sending.
const TX_QUEUE: usize = 1024;

/// Received bytes lost since boot: a UART overrun, framing or noise error.
static RX_LOST: AtomicU32 = AtomicU32::new(0);
/// IMU samples rejected since boot (see [`autopilot::mpu6000`]; real flavour).
static IMU_INVALID: AtomicU32 = AtomicU32::new(0);
/// MPU-6000 re-configurations after a reset in flight ([`autopilot::mpu6000::Reconfigure`]).
static IMU_RECONFIGURED: AtomicU32 = AtomicU32::new(0);
/// Largest deviation of the control loop's start from its period, µs (real flavour).
static LOOP_JITTER_MAX_US: AtomicU32 = AtomicU32::new(0);
/// When the guidance task last completed a step (the watchdog's feeder checks it).
static GUIDANCE_ALIVE: board_support::watchdog::Liveness = board_support::watchdog::Liveness::new();
/// When the heartbeat, the lowest-priority task, last ran (the watchdog's feeder checks it).
static HEARTBEAT_ALIVE: board_support::watchdog::Liveness =
    board_support::watchdog::Liveness::new();

/// Encodes one message (outside any lock) and queues it on a UART's transmit queue: the lock
/// is held for the copy only, a full queue drops the frame and counts it.
fn send<M: protocol::Message, const N: usize>(
    tx: &mut impl rtic::Mutex<T = board_support::uart_tx::TxWriter>,
    msg: &M,
) {
    let mut buf = [0u8; N];
    if let Ok(n) = protocol::encode(msg, &mut buf) {
        let frame = buf.get(..n).unwrap_or(&[]);
        tx.lock(|tx| tx.send(frame));
    }
}

/// Period in SysTick ticks (1 ms, rounded down), at least 1.
const fn ticks(period: timebase::Duration) -> u32 {
    let t = period.as_millis() as u32;
    if t == 0 {
        1
    } else {
        t
    }
}

#[rtic::app(
    device = stm32f4xx_hal::pac,
    peripherals = true,
    dispatchers = [SPI3, UART4, TIM8_UP_TIM13, TIM8_BRK_TIM12, TIM8_TRG_COM_TIM14]
)]
mod app {
    use super::flavour::{self, Current as Flavour, Releases, Tick};
    use super::sensors::SensorBus;
    use super::{clock, send, ticks, Mono, AP, RC_QUEUE, RX_QUEUE, TX_QUEUE};
    use super::{GUIDANCE_ALIVE, HEARTBEAT_ALIVE, RX_LOST};
    use super::{IMU_INVALID, IMU_RECONFIGURED, LOOP_JITTER_MAX_US};
    use autopilot::app::Autopilot;
    use autopilot::board::{self, hw};
    use autopilot::mpu6000::{Reconfigure, SampleCheck};
    use autopilot::ms5611::{self, Calibration, Osr};
    use autopilot::tasks::HEARTBEAT_PERIOD;
    use autopilot::AutopilotConfig;
    use autopilot::HostOutcome;
    use board_support::flavour::{host_receiver, Flavour as _, HostRx, PARAM_STORAGE};
    use board_support::log;
    use board_support::param_flash::{FlashError, ParamSector, WatchedSector};
    use board_support::uart_link::{LinkInterrupt, LinkReader, ReceiveLink, RxInterrupt, UartLink};
    use board_support::uart_tx::TxWriter;
    use board_support::watchdog::Timeout;
    use core::sync::atomic::Ordering;
    use protocol::{
        AutopilotToStereo, BoardToHost, HostToBoard, HostToBoardDecoder, ImuSample, Message as _,
        Node, ParamOp, ParamReply,
    };
    use rtic_monotonics::Timebase as _;
    use stm32f4xx_hal::{prelude::*, serial::Rx, timer::CounterHz, watchdog::IndependentWatchdog};

    type Duration = <Mono as rtic_monotonics::Timebase>::Duration;
    const A2S: usize = AutopilotToStereo::MAX_FRAME_BYTES;
    const B2H: usize = BoardToHost::MAX_FRAME_BYTES;

    #[shared]
    struct Shared {
        ap: &'static mut Autopilot,
        /// Transmit queue of the camera-board link.
        link_tx: TxWriter,
        /// Transmit queue of the telemetry port.
        host_tx: TxWriter,
        /// Messages decoded from the camera board since boot.
        stereo_msgs: u32,
        motors: hw::Motors,
        /// SPI2 with the IMU and the barometer (`None` in the lockstep flavours).
        sensors: Option<SensorBus>,
        iwdg: IndependentWatchdog,
    }

    #[local]
    struct Local {
        led: hw::Led,
        /// The camera-board link's interrupt end and its decoding task's.
        link: LinkInterrupt<hw::LinkUart, Rx<hw::LinkUart>>,
        link_reader: LinkReader,
        /// The telemetry port's interrupt end and its decoding task's.
        host: LinkInterrupt<hw::TelemetryUart, HostRx<hw::TelemetryUart>>,
        host_reader: LinkReader,
        host_decoder: HostToBoardDecoder,
        /// The parameter sector (`None` in the `qemu` flavour).
        param_sector: Option<ParamSector>,
        /// The RC receiver's interrupt end (its UART `None` without `board::RC_RECEIVER`) and
        /// its decoding task's.
        rc_link: RxInterrupt<Option<Rx<hw::RcUart>>>,
        rc_reader: LinkReader,
        loop_timer: CounterHz<hw::LoopTimer>,
        imu_check: SampleCheck,
        guidance_tick: Tick,
        gyro_tick: Tick,
        telemetry_tick: Tick,
        /// The supply-voltage input (`None` in the lockstep flavours).
        battery: Option<hw::BatteryInput>,
        world: autopilot::lockstep::WorldClock,
        releases: Releases,
    }

    #[init(local = [
        link_store: UartLink<RX_QUEUE, TX_QUEUE> = UartLink::new(),
        host_store: UartLink<RX_QUEUE, TX_QUEUE> = UartLink::new(),
        rc_store: ReceiveLink<RC_QUEUE> = ReceiveLink::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        // First: the status line's `stack_free` is the headroom left from here on.
        board_support::stack::paint();
        let reset_cause = board_support::fault::take_reset_cause();
        let mut b = hw::take(cx.device);
        Mono::start(cx.core.SYST, board_support::clocks::SYSTICK_HZ);

        // The saved parameters, or the defaults and why (QEMU models no flash interface).
        let param_sector = PARAM_STORAGE.then(|| ParamSector::new(b.flash));
        let autopilot = match &param_sector {
            Some(sector) => {
                let (autopilot, loaded) = Autopilot::from_store(sector);
                match loaded {
                    Ok(()) => defmt::info!("parameters: the saved record is in use"),
                    Err(why) => defmt::warn!("parameters: defaults ({})", why),
                }
                if autopilot.link_keyed() {
                    defmt::info!("link key: loaded, commands must be signed");
                }
                autopilot
            }
            None => Autopilot::new(AutopilotConfig::default()),
        };
        // SAFETY: `init` runs once, before any task; this is the only reference ever made to
        // AP, and it is handed to RTIC as a shared resource. The autopilot starts disarmed.
        #[allow(static_mut_refs)]
        let ap: &'static mut Autopilot = unsafe { AP.write(autopilot) };

        let (link_tx, mut link_rx) = b.link.split();
        link_rx.listen();
        let (host_tx, mut host_rx) = b.telemetry.split();

        let mut rc_uart = b.rc;
        let mut loop_timer = b.loop_timer;
        let sysclk = b.rcc.clocks.sysclk().raw();
        let sensors = if Flavour::OWN_SENSORS {
            let mut bus = SensorBus::new(b.spi, b.imu_cs, b.baro_cs);
            let busy_wait = |d: timebase::Duration| {
                cortex_m::asm::delay((d.as_millis() as u32).saturating_mul(sysclk / 1_000))
            };
            match bus.imu_init(busy_wait) {
                Ok(autopilot::mpu6000::WHO_AM_I_VALUE) => log::info!("MPU-6000 configured"),
                Ok(who) => defmt::error!("MPU-6000 not found: WHO_AM_I = {=u8:#x}", who),
                Err(_) => defmt::error!("MPU-6000: SPI transfer failed"),
            }
            if let Some(rc) = rc_uart.as_mut() {
                rc.listen();
            }
            loop_timer
                .start(board::LOOP_RATE_HZ.Hz())
                .unwrap_or_else(|_| panic!("TIM2 start"));
            loop_timer.listen(stm32f4xx_hal::timer::Event::Update);
            Some(bus)
        } else {
            None
        };
        let (guidance_tick, gyro_tick, telemetry_tick, releases) = Releases::new();
        let battery = Flavour::OWN_SENSORS.then(|| hw::BatteryInput::new(b.battery, &mut b.rcc));

        let mut iwdg = IndependentWatchdog::new(b.iwdg);
        board_support::watchdog::set(&mut iwdg, Flavour::WATCHDOG);
        let started = clock::now();
        GUIDANCE_ALIVE.ran(started);
        HEARTBEAT_ALIVE.ran(started);

        // Last, after the sensors' start-up waits: what the peers sent while the receivers
        // were not served yet is dropped here, not counted as lost in flight (`rx_lost`).
        let boot_bytes = board_support::uart_rx::discard_pending(&mut link_rx)
            + board_support::uart_rx::discard_pending(&mut host_rx)
            + rc_uart
                .as_mut()
                .map_or(0, board_support::uart_rx::discard_pending);
        let host_rx = host_receiver(host_rx, hw::TELEMETRY_RX_DMA);
        let (link_tx, link, link_reader) =
            cx.local
                .link_store
                .split(hw::LINK_IRQ, link_tx, link_rx, &RX_LOST);
        let (host_tx, host, host_reader) =
            cx.local
                .host_store
                .split(hw::TELEMETRY_IRQ, host_tx, host_rx, &RX_LOST);
        let (rc_link, rc_reader) = cx.local.rc_store.split(hw::RC_IRQ, rc_uart, &RX_LOST);
        log::info!(
            "autopilot up, sysclk {} Hz, reset cause {}, {} bytes received before the UARTs were served",
            sysclk,
            reset_cause as u8,
            boot_bytes
        );
        defmt::info!("reset cause: {}", reset_cause);
        stereo_rx::spawn().ok();
        host_rx::spawn().ok();
        guidance::spawn().ok();
        gyro_tx::spawn().ok();
        telemetry::spawn().ok();
        heartbeat::spawn().ok();
        if board::RC_RECEIVER {
            rc_rx::spawn().ok();
        }
        baro::spawn().ok();
        outputs_watch::spawn().ok();

        (
            Shared {
                ap,
                link_tx,
                host_tx,
                stereo_msgs: 0,
                motors: b.motors,
                sensors,
                iwdg,
            },
            Local {
                led: b.led,
                link,
                link_reader,
                host,
                host_reader,
                host_decoder: HostToBoardDecoder::new_mid_stream(),
                param_sector,
                rc_link,
                rc_reader,
                loop_timer,
                imu_check: SampleCheck::new(board::IMU_AXES, board::Mounting::default()),
                guidance_tick,
                gyro_tick,
                telemetry_tick,
                battery,
                world: autopilot::lockstep::WorldClock::new(),
                releases,
            },
        )
    }

    /// Nothing to run: sleep until an interrupt (Sleep mode: only the core's clock stops, so
    /// the 512 Hz timer, SysTick, the UARTs and the independent watchdog keep running, and a
    /// task that hangs still starves the watchdog's feeders). Waking costs a few cycles of the
    /// control loop's start latency.
    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// USART2, the camera-board link: transmit queued frames, receive bytes.
    #[task(binds = USART2, priority = 6, local = [link])]
    fn link_uart(cx: link_uart::Context) {
        cx.local.link.serve();
    }

    /// USART1, the telemetry port: transmit queued frames, receive bytes.
    #[task(binds = USART1, priority = 6, local = [host])]
    fn telemetry_uart(cx: telemetry_uart::Context) {
        cx.local.host.serve();
    }

    /// DMA2 stream 2 (`hil` flavour; never enabled in the others): the telemetry port's
    /// receive buffer is half or wholly full; `telemetry_uart` hands the bytes on.
    #[task(binds = DMA2_STREAM2, priority = 6)]
    fn telemetry_dma(_: telemetry_dma::Context) {
        hw::TELEMETRY_RX_DMA.acknowledge();
        rtic::pend(hw::TELEMETRY_IRQ);
    }

    /// UART5, the RC receiver (real flavour with `board::RC_RECEIVER` only; otherwise its
    /// interrupt is never enabled).
    #[task(binds = UART5, priority = 6, local = [rc_link])]
    fn rc_uart(cx: rc_uart::Context) {
        cx.local.rc_link.serve();
    }

    /// RC: SBUS frames to pilot commands and the RC kill latch; also wakes every 20 ms so that
    /// a receiver gone silent kills the motors (see [`autopilot::rc`]).
    #[task(priority = 4, shared = [ap], local = [
        rc_reader,
        sbus: autopilot::rc::SbusDecoder = autopilot::rc::SbusDecoder::new(),
        rc: autopilot::rc::RcCommands = autopilot::rc::RcCommands::new(autopilot::rc::RcConfig::DEFAULT),
    ])]
    async fn rc_rx(mut cx: rc_rx::Context) {
        loop {
            let _ = Mono::timeout_after(Duration::from_ticks(20), cx.local.rc_reader.woken()).await;
            let mut buf = [0u8; 32];
            loop {
                let n = cx.local.rc_reader.take(&mut buf);
                if n == 0 {
                    break;
                }
                let now = clock::now();
                let mut cmds = heapless::Vec::<protocol::PilotCommand, 4>::new();
                let rc = &mut *cx.local.rc;
                cx.local
                    .sbus
                    .feed(buf.get(..n).unwrap_or(&[]), now, |frame| {
                        if let Some(c) = rc.on_frame(&frame, now) {
                            // A kill must not be lost to a full list: it replaces the last.
                            if cmds.push(c).is_err() && c == protocol::PilotCommand::Kill {
                                if let Some(last) = cmds.last_mut() {
                                    *last = c;
                                }
                            }
                        }
                    });
                for c in cmds {
                    cx.shared.ap.lock(|ap| ap.on_command(c, now));
                }
            }
            let now = clock::now();
            let poll = cx.local.rc.poll(now);
            let engaged = cx.local.rc.kill_reason().is_some();
            cx.shared.ap.lock(|ap| {
                if let Some(c) = poll {
                    ap.on_command(c, now);
                }
                ap.set_rc_kill(engaged, now);
            });
        }
    }

    /// 512 Hz (real flavour): reads and checks the IMU, then attitude -> INDI -> motors. An
    /// invalid sample is not flown on: the IMU failsafe counts from the last valid one. A
    /// sensor found reset (asleep) is configured again ([`Reconfigure`]); its samples count
    /// again once it is awake, which it is only with its configuration read back right.
    #[task(binds = TIM2, priority = 5, shared = [ap, motors, sensors, iwdg], local = [
        loop_timer,
        imu_check,
        reconfigure: Reconfigure = Reconfigure::new(),
        last_start: Option<timebase::Instant> = None,
    ])]
    fn control_loop(mut cx: control_loop::Context) {
        cx.local
            .loop_timer
            .clear_flags(stm32f4xx_hal::timer::Flag::Update);
        let now = clock::now();
        if let Some(last) = cx.local.last_start.replace(now) {
            let period = timebase::Duration::from_hz(board::LOOP_RATE_HZ);
            let jitter = now.since(last).as_micros().abs_diff(period.as_micros()) as u32;
            LOOP_JITTER_MAX_US.fetch_max(jitter, Ordering::Relaxed);
        }
        let reads = cx
            .shared
            .sensors
            .lock(|bus| bus.as_mut().map(|bus| bus.imu_read()));
        let check = &mut *cx.local.imu_check;
        let sample = match reads {
            Some(Ok((who, pwr, data))) => {
                match check.check(who, pwr, &data, now.to_wire()) {
                    Ok(sample) => Some(sample),
                    Err(fault) => {
                        if cx.local.reconfigure.due(fault, now) {
                            let ok = cx
                                .shared
                                .sensors
                                .lock(|bus| bus.as_mut().map(|bus| bus.imu_configure()));
                            IMU_RECONFIGURED.store(cx.local.reconfigure.count(), Ordering::Relaxed);
                            // Rare (a sensor reset; the motors are off by then): worth a line.
                            defmt::warn!(
                                "MPU-6000 found reset (PWR_MGMT_1 = {=u8:#x}): configured again, read back right: {}",
                                pwr,
                                matches!(ok, Some(Ok(true)))
                            );
                        }
                        None
                    }
                }
            }
            Some(Err(_)) => {
                check.bus_error();
                None
            }
            None => None,
        };
        IMU_INVALID.store(check.faults().total(), Ordering::Relaxed);
        match sample {
            Some(imu) => {
                fly(&mut cx.shared.ap, &mut cx.shared.motors, &imu, now);
            }
            None => {
                if let Some(off) = cx.shared.ap.lock(|ap| ap.motor_safety(now)) {
                    cx.shared.motors.lock(|m| m.set(off));
                }
            }
        }
        if flavour::FEED_WATCHDOG_IN_LOOP
            && GUIDANCE_ALIVE.within(now, board::GUIDANCE_ALIVE)
            && HEARTBEAT_ALIVE.within(now, board::HEARTBEAT_ALIVE)
        {
            cx.shared.iwdg.lock(|w| w.feed());
        }
    }

    /// One control step on a valid sample: the library's 512 Hz loop, then the motors (held at
    /// 0 where the flavour's outputs are not live, see `flavour::outputs_live`). Returns the
    /// motor command.
    fn fly(
        ap: &mut impl rtic::Mutex<T = &'static mut Autopilot>,
        motors: &mut impl rtic::Mutex<T = hw::Motors>,
        imu: &ImuSample,
        now: timebase::Instant,
    ) -> [f32; 4] {
        let (throttle, enabled) = ap.lock(|ap| (ap.on_imu(imu, now), ap.hil_outputs()));
        let live = flavour::outputs_live(enabled, clock::now());
        motors.lock(|m| m.set(if live { throttle } else { [0.0; 4] }));
        throttle
    }

    /// Lockstep flavours: every `flavour::OUTPUTS_CHECK` of board time, the PWM outputs to
    /// 0 unless they are live (enabled by the host, and its samples still coming: world time,
    /// and with it every failsafe of the library, stops with them). Ends at once in the real
    /// flavour.
    #[task(priority = 5, shared = [ap, motors])]
    async fn outputs_watch(mut cx: outputs_watch::Context) {
        if flavour::OUTPUTS_CHECK == timebase::Duration::ZERO {
            return;
        }
        loop {
            Mono::delay(Duration::from_ticks(ticks(flavour::OUTPUTS_CHECK))).await;
            let enabled = cx.shared.ap.lock(|ap| ap.hil_outputs());
            if !flavour::outputs_live(enabled, clock::now()) {
                cx.shared.motors.lock(|m| m.set([0.0; 4]));
            }
        }
    }

    /// The lockstep flavours' control step: a host IMU sample (and its world time) ->
    /// attitude -> INDI -> motors, the command back to the host, then the periodic tasks due.
    #[task(priority = 5, shared = [ap, motors, host_tx], local = [releases])]
    async fn imu_indi(mut cx: imu_indi::Context, sample: (ImuSample, timebase::Instant)) {
        let (imu, now) = sample;
        let throttle = fly(&mut cx.shared.ap, &mut cx.shared.motors, &imu, now);
        motors_to_host(&mut cx.shared.host_tx, now, throttle);
        cx.local.releases.release(now);
    }

    /// The motor command to the host as well, in the flavours whose host flies on it.
    fn motors_to_host(
        host_tx: &mut impl rtic::Mutex<T = TxWriter>,
        now: timebase::Instant,
        throttle: [f32; 4],
    ) {
        if flavour::MOTORS_TO_HOST {
            let msg = BoardToHost::Motors(protocol::MotorCommand {
                timestamp_us: now.to_wire(),
                throttle,
            });
            send::<_, B2H>(host_tx, &msg);
        }
    }

    /// Camera-board bytes: estimates, status, heartbeats, config acks; a parameter answer is
    /// passed on to the host.
    #[task(priority = 4, shared = [ap, stereo_msgs, host_tx], local = [link_reader])]
    async fn stereo_rx(mut cx: stereo_rx::Context) {
        let mut buf = [0u8; 64];
        while cx.local.link_reader.woken().await {
            loop {
                let n = cx.local.link_reader.take(&mut buf);
                if n == 0 {
                    break;
                }
                let now = Flavour::lib_now();
                let bytes = buf.get(..n).unwrap_or(&[]);
                let (decoded, answer) = cx
                    .shared
                    .ap
                    .lock(|ap| (ap.on_stereo_bytes(bytes, now), ap.take_camera_param_reply()));
                cx.shared
                    .stereo_msgs
                    .lock(|c| *c = c.wrapping_add(decoded as u32));
                if let Some(answer) = answer {
                    send::<_, B2H>(&mut cx.shared.host_tx, &BoardToHost::Param(answer));
                }
            }
        }
    }

    /// Host bytes: external position (motion capture), pilot commands, parameter requests
    /// (answered on the telemetry port), and IMU samples (only the lockstep flavours take them;
    /// the real flavour refuses and counts them).
    #[task(priority = 4, shared = [ap, host_tx, link_tx, iwdg], local = [host_reader, host_decoder, world, param_sector])]
    async fn host_rx(mut cx: host_rx::Context) {
        let mut buf = [0u8; 64];
        while cx.local.host_reader.woken().await {
            loop {
                let n = cx.local.host_reader.take(&mut buf);
                if n == 0 {
                    break;
                }
                for &byte in buf.get(..n).unwrap_or(&[]) {
                    let Some(msg) = cx.local.host_decoder.push(byte) else {
                        continue;
                    };
                    let now = Flavour::lib_now();
                    // A save of this board's table (the camera board's is passed on): logged.
                    let saving = cx.local.param_sector.is_some()
                        && matches!(&msg, HostToBoard::Param(r)
                            if r.op == ParamOp::Save && r.board == Node::Autopilot);
                    let started = clock::now();
                    let iwdg = &mut cx.shared.iwdg;
                    let (outcome, new_key) = cx.shared.ap.lock(|ap| {
                        let outcome = match cx.local.param_sector.as_mut() {
                            Some(sector) => {
                                let mut store =
                                    WatchedSector::new(sector, Flavour::WATCHDOG, |t| {
                                        program_watchdog(iwdg, t)
                                    });
                                ap.on_host_message(msg, now, Some(&mut store))
                            }
                            None => ap.on_host_message(msg, now, None),
                        };
                        (outcome, ap.take_link_key_to_store().is_some())
                    });
                    if new_key {
                        // Into the parameter sector at once, beside the saved parameters
                        // (the motors are off: a key is only taken then).
                        let started = clock::now();
                        let saved = cx.local.param_sector.as_mut().map(|sector| {
                            let mut store = WatchedSector::new(sector, Flavour::WATCHDOG, |t| {
                                program_watchdog(&mut cx.shared.iwdg, t)
                            });
                            cx.shared.ap.lock(|ap| ap.save_link_key(&mut store))
                        });
                        let ms = clock::now().since(started).as_millis() as u32;
                        match saved {
                            Some(Ok(())) => {
                                defmt::info!("link key provisioned: saved in {=u32} ms", ms)
                            }
                            Some(Err(why)) => defmt::warn!(
                                "link key provisioned: not saved ({}), kept in RAM until the next parameter save",
                                why
                            ),
                            None => defmt::warn!("link key provisioned: no parameter storage, kept in RAM"),
                        }
                    }
                    if saving {
                        let ms = clock::now().since(started).as_millis() as u32;
                        let error = cx.local.param_sector.as_ref().and_then(|s| s.last_error());
                        log_save(&outcome, error, ms);
                    }
                    match outcome {
                        HostOutcome::Imu(sample) => {
                            if let Some(at) = flavour::host_imu(cx.local.world, &sample) {
                                // A sample arriving while the previous one is still being
                                // processed is skipped (the IMU failsafe watches the rate).
                                let _ = imu_indi::spawn((sample, at));
                            }
                        }
                        HostOutcome::Reply(reply) => send::<_, B2H>(&mut cx.shared.host_tx, &reply),
                        HostOutcome::ToCamera(msg) => send::<_, A2S>(&mut cx.shared.link_tx, &msg),
                        HostOutcome::Done => {}
                    }
                }
            }
        }
    }

    /// Programs the watchdog for a flash write ([`WatchedSector`]): the save's timeout before
    /// it; after it the board's own again, and the tasks its feeder watches counted alive from
    /// here (the write held every task).
    fn program_watchdog(iwdg: &mut impl rtic::Mutex<T = IndependentWatchdog>, timeout: Timeout) {
        iwdg.lock(|w| board_support::watchdog::set(w, timeout));
        if timeout != board_support::watchdog::SAVE {
            let now = clock::now();
            GUIDANCE_ALIVE.ran(now);
            HEARTBEAT_ALIVE.ran(now);
        }
    }

    /// The log line of a save: done, or why not, and how long the flash held it.
    fn log_save(outcome: &HostOutcome, flash: Option<FlashError>, ms: u32) {
        let HostOutcome::Reply(BoardToHost::Param(resp)) = outcome else {
            return;
        };
        match (&resp.reply, flash) {
            (ParamReply::Saved, _) => defmt::info!("parameters: saved in {=u32} ms", ms),
            (ParamReply::Error(e), Some(flash)) => defmt::warn!(
                "parameters: not saved ({}, the flash refused: {}) in {=u32} ms",
                e,
                flash,
                ms
            ),
            (ParamReply::Error(e), None) => {
                defmt::warn!("parameters: not saved ({}) in {=u32} ms", e, ms)
            }
            _ => {}
        }
    }

    /// 50 Hz: FSM, force field, velocity and height loops; motors off when they must be; then
    /// its liveness stamp (the watchdog's feeder checks it).
    #[task(priority = 3, shared = [ap, motors, host_tx], local = [guidance_tick])]
    async fn guidance(mut cx: guidance::Context) {
        loop {
            let now = cx.local.guidance_tick.wait().await;
            let off = cx.shared.ap.lock(|ap| {
                ap.guidance_step(now);
                ap.motor_safety(now)
            });
            if let Some(throttle) = off {
                cx.shared.motors.lock(|m| m.set(throttle));
                motors_to_host(&mut cx.shared.host_tx, now, throttle);
            }
            GUIDANCE_ALIVE.ran(clock::now());
        }
    }

    /// 128 Hz: gyro and attitude to the camera board for derotation.
    #[task(priority = 2, shared = [ap, link_tx], local = [gyro_tick])]
    async fn gyro_tx(mut cx: gyro_tx::Context) {
        loop {
            let now = cx.local.gyro_tick.wait().await;
            let msg =
                AutopilotToStereo::GyroAttitude(cx.shared.ap.lock(|ap| ap.gyro_attitude(now)));
            send::<_, A2S>(&mut cx.shared.link_tx, &msg);
        }
    }

    /// The MS5611 (real flavour): reset, PROM (CRC-checked; retried every second until it
    /// passes), then pressure and temperature conversions at OSR 4096, each waited for its
    /// datasheet maximum with the bus free, compensated and handed to the library.
    #[task(priority = 2, shared = [ap, sensors])]
    async fn baro(mut cx: baro::Context) {
        const OSR: Osr = Osr::X4096;
        let wait = Duration::from_ticks(OSR.conversion_time().as_micros().div_ceil(1_000) as u32);
        let cal = loop {
            let prom = cx.shared.sensors.lock(|bus| {
                let bus = bus.as_mut()?;
                bus.baro_command(ms5611::CMD_RESET).ok()?;
                Some(())
            });
            if prom.is_none() {
                return; // lockstep flavours: no bus
            }
            Mono::delay(Duration::from_ticks(
                ms5611::RESET_TIME.as_micros().div_ceil(1_000) as u32,
            ))
            .await;
            // One word per lock: the eight words in one go hold the bus (and so the 512 Hz
            // loop's start) for about 300 us.
            let mut words = [0u16; 8];
            let mut read = Some(());
            for (i, w) in words.iter_mut().enumerate() {
                let word = cx
                    .shared
                    .sensors
                    .lock(|bus| bus.as_mut().and_then(|b| b.baro_prom(i as u8).ok()));
                match word {
                    Some(word) => *w = word,
                    None => {
                        read = None;
                        break;
                    }
                }
            }
            match read.map(|()| Calibration::from_prom(&words)) {
                Some(Ok(cal)) => break cal,
                Some(Err(e)) => defmt::error!("MS5611 PROM refused: {}", defmt::Debug2Format(&e)),
                None => defmt::error!("MS5611: SPI transfer failed"),
            }
            Mono::delay(Duration::from_ticks(1_000)).await;
        };
        log::info!("MS5611 calibrated");
        loop {
            let mut d = [0u32; 2];
            for (cmd, out) in [
                ms5611::convert_d1_command(OSR),
                ms5611::convert_d2_command(OSR),
            ]
            .into_iter()
            .zip(d.iter_mut())
            {
                cx.shared.sensors.lock(|bus| {
                    if let Some(bus) = bus.as_mut() {
                        let _ = bus.baro_command(cmd);
                    }
                });
                Mono::delay(wait).await;
                *out = cx
                    .shared
                    .sensors
                    .lock(|bus| bus.as_mut().and_then(|b| b.baro_adc().ok()))
                    .unwrap_or(0);
            }
            // A result of 0 is a conversion the chip did not finish (or a read too early).
            if d[0] != 0 && d[1] != 0 {
                let reading = cal.compensate(d[0], d[1]);
                let now = Flavour::lib_now();
                cx.shared.ap.lock(|ap| ap.on_baro(&reading, now));
            }
        }
    }

    /// 10 Hz: the supply voltage (a conversion that does not end is passed on as NaN, which
    /// the autopilot counts as rejected), then telemetry to the host.
    #[task(priority = 1, shared = [ap, host_tx], local = [telemetry_tick, battery])]
    async fn telemetry(mut cx: telemetry::Context) {
        loop {
            let now = cx.local.telemetry_tick.wait().await;
            let volts = cx
                .local
                .battery
                .as_mut()
                .map(|b| b.read_volts().unwrap_or(f32::NAN));
            let msg = BoardToHost::Telemetry(cx.shared.ap.lock(|ap| ap.telemetry_task(volts, now)));
            send::<_, B2H>(&mut cx.shared.host_tx, &msg);
        }
    }

    /// 1 Hz: heartbeats to both links, LED, watchdog (lockstep flavours; real: the liveness
    /// stamp its feeder checks), a status log line.
    #[task(priority = 1, shared = [ap, link_tx, host_tx, stereo_msgs, iwdg], local = [led])]
    async fn heartbeat(mut cx: heartbeat::Context) {
        loop {
            let now = clock::now();
            let hb = Autopilot::heartbeat(now);
            send::<_, A2S>(&mut cx.shared.link_tx, &AutopilotToStereo::Heartbeat(hb));
            send::<_, B2H>(&mut cx.shared.host_tx, &BoardToHost::Heartbeat(hb));
            cx.local.led.toggle();
            HEARTBEAT_ALIVE.ran(now);
            if !flavour::FEED_WATCHDOG_IN_LOOP {
                cx.shared.iwdg.lock(|w| w.feed());
            }
            let msgs = cx.shared.stereo_msgs.lock(|c| *c);
            let tx_dropped = cx.shared.link_tx.lock(|t| t.dropped_frames())
                + cx.shared.host_tx.lock(|t| t.dropped_frames());
            let (errors, estimates, peer, refused, blocked, fixes_refused) =
                cx.shared.ap.lock(|ap| {
                    (
                        ap.link_errors(),
                        ap.estimates_received(),
                        ap.stereo_heartbeat().map(|(_, h)| h.uptime_ms),
                        ap.arm_refused(),
                        ap.arm_blocker().is_some(),
                        ap.fixes_refused(),
                    )
                });
            log::info!(
                "status uptime_ms={} stereo_rx_ok={} link_errors={} version_mismatch={} estimates={} stereo_uptime_ms={} imu_invalid={} imu_reconfigured={} rx_lost={} tx_dropped={} host_sensor_rejected={} arm_refused={} arm_blocked={} fixes_refused={} loop_jitter_max_us={} stack_free={}",
                hb.uptime_ms,
                msgs,
                errors.total(),
                errors.version_mismatch,
                estimates,
                peer.unwrap_or(u32::MAX),
                IMU_INVALID.load(Ordering::Relaxed),
                IMU_RECONFIGURED.load(Ordering::Relaxed),
                RX_LOST.load(Ordering::Relaxed),
                tx_dropped,
                flavour::HOST_SENSOR_REJECTED.load(Ordering::Relaxed),
                refused,
                blocked as u8,
                fixes_refused,
                LOOP_JITTER_MAX_US.load(Ordering::Relaxed),
                board_support::stack::free_bytes()
            );
            Mono::delay(Duration::from_ticks(ticks(HEARTBEAT_PERIOD))).await;
        }
    }
}
