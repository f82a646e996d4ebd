//! RTIC 2 application of the autopilot firmware (thumbv7em-none-eabihf only).
//!
//! A thin shell around [`autopilot::app::Autopilot`]; the tasks mirror `autopilot::app::TASKS`
//! (same names and relative priorities) and each body is one call into the library.
//!
//! | RTIC task | prio | trigger | body |
//! |---|---|---|---|
//! | `usart1`, `usart1_dma`, `usart2` | 6 | USART1 IDLE + DMA2 stream 2 (QEMU: RXNE), USART2 RXNE | bytes into lock-free queues (never wait for a lock) |
//! | `imu_drdy` | 6 | EXTI4: MPU-6000 data ready, 500 Hz (real) | burst read over SPI1, spawns `imu_indi` |
//! | `imu_timer` | 6 | TIM2 at 512 Hz (real) | fallback: reads the IMU itself only while data-ready interrupts are missing |
//! | `imu_indi` | 5 | IMU sample (HIL/QEMU: from the host link) | `Autopilot::on_imu`, motors out (HIL/QEMU: releases the periodic tasks) |
//! | `stereo_rx` | 4 | woken by `usart1` | `Autopilot::on_stereo_bytes` |
//! | `host_rx` | 4 | woken by `usart2` | IMU / position / command from the host |
//! | `guidance` | 3 | 50 Hz | `Autopilot::guidance_step`, `motor_safety` |
//! | `gyro_tx` | 2 | 128 Hz | `Autopilot::gyro_attitude` to the camera board |
//! | `telemetry` | 1 | 10 Hz | `Autopilot::telemetry` to the host |
//! | `heartbeat` | 1 | 1 Hz | heartbeats to both links, LED, watchdog |
//! | `usart3` | 6 | USART3 RXNE (real) | SBUS bytes into a lock-free queue |
//! | `rc_rx` | 4 | woken by `usart3`, and every 20 ms | [`autopilot::rc`]: SBUS frames -> `Autopilot::on_command` (arm/land/kill; RC failsafe or silence => kill) |
//!
//! Motors: TIM3 PWM (see [`motors`]); in the HIL and QEMU flavours the commands also leave as
//! `BoardToHost::Motors` on the host link (the flight logic is the same code as on hardware).
//!
//! Time (see [`tick`]): on hardware the library clock is the board's SysTick and the periodic
//! tasks run on SysTick periods. In the `hil` and `qemu` flavours the board runs in lockstep
//! with the host's world simulation ([`autopilot::lockstep`]): the library clock is the world
//! time carried by the host's IMU samples, `imu_indi` releases `guidance`, `gyro_tx` and
//! `telemetry` when the world clock passes their periods, and the host sends the next sample
//! only after the `Motors` reply to the previous one. `heartbeat` (liveness, LED, watchdog)
//! stays on the board clock in every flavour.
//!
//! RC input (real flavour): an SBUS receiver on USART3 RX (PB11, 100,000 Bd 8E2, non-inverted
//! signal; see `docs/hardware.md`); in HIL and QEMU the host link's `PilotCommand` stands in.
//! Manual flight from the sticks is not wired: `Autopilot` has no manual mode yet.

mod board;
mod clock;
// Only the real flavour reads the IMU; the type is named in the RTIC resources of every flavour.
#[cfg_attr(any(feature = "qemu", feature = "hil"), allow(dead_code))]
mod imu;
use board_support::log;
mod motors;
mod tick;
#[cfg(not(feature = "qemu"))]
use board_support::uart_dma;

use autopilot::app::Autopilot;
use board_support::uart_rx::RxFlow;
use core::mem::MaybeUninit;
use defmt_rtt as _;
#[cfg(not(feature = "qemu"))]
use panic_probe as _;

rtic_monotonics::systick_monotonic!(Mono, 1_000);

/// The autopilot state: CPU-only, so it lives in CCM. NOLOAD: `init` writes it first.
#[link_section = ".ccmram"]
static mut AP: MaybeUninit<Autopilot> = MaybeUninit::uninit();

/// The IMU of the real flavour: MPU-6000 on SPI1 with chip select PA4.
type ImuDevice = imu::Mpu6000<
    stm32f4xx_hal::spi::Spi<stm32f4xx_hal::pac::SPI1>,
    stm32f4xx_hal::gpio::PA4<stm32f4xx_hal::gpio::Output>,
>;

/// Bytes of each receive queue between the RX interrupt and its decoding task.
const RX_QUEUE: usize = 2048;

/// Board time of the last IMU data-ready interrupt, µs (wrapping `u32`).
#[cfg(not(any(feature = "qemu", feature = "hil")))]
static LAST_DRDY_US: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// IMU reads done by the fallback timer because data-ready interrupts were missing.
static IMU_FALLBACK_READS: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// Bytes of the SBUS receive queue (about five frames).
const RC_QUEUE: usize = 128;

/// Received bytes lost since boot: queue full, or a UART overrun/framing/noise error.
static RX_LOST: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// Back-pressure of the host link's RXNE interrupt.
static HOST_FLOW: RxFlow = RxFlow::new(stm32f4xx_hal::pac::Interrupt::USART2);

/// Back-pressure of the SBUS receiver's RXNE interrupt (real flavour).
#[cfg(not(any(feature = "qemu", feature = "hil")))]
static RC_FLOW: RxFlow = RxFlow::new(stm32f4xx_hal::pac::Interrupt::USART3);

/// Blocking write of whole frames to a UART (a few dozen bytes per message at 921,600 Bd).
fn write_all<U: stm32f4xx_hal::serial::Instance>(
    tx: &mut stm32f4xx_hal::serial::Tx<U>,
    bytes: &[u8],
) {
    use embedded_io::Write as _;
    let _ = tx.write_all(bytes);
}

/// Encodes one message and writes it.
fn send<M: protocol::Message, U: stm32f4xx_hal::serial::Instance, const N: usize>(
    tx: &mut stm32f4xx_hal::serial::Tx<U>,
    msg: &M,
) {
    let mut buf = [0u8; N];
    if let Ok(n) = protocol::encode(msg, &mut buf) {
        write_all(tx, buf.get(..n).unwrap_or(&[]));
    }
}

/// Period in SysTick ticks (1 ms), at least 1.
const fn ticks(period_us: u32) -> u32 {
    let t = period_us / 1_000;
    if t == 0 {
        1
    } else {
        t
    }
}

/// The release channels of the lockstep flavours: (to `imu_indi`, to the periodic task).
#[cfg(any(feature = "qemu", feature = "hil"))]
type TickChannel = (
    rtic_sync::channel::Sender<'static, u64, 1>,
    rtic_sync::channel::Receiver<'static, u64, 1>,
);

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true, dispatchers = [SPI2, SPI3, UART4, UART5, TIM8_UP_TIM13])]
mod app {
    use super::motors::{Motors, PWM_HZ};
    use super::tick::Tick;
    use super::{board, clock, log, send, ticks, Mono, AP, RC_QUEUE, RX_QUEUE};
    use autopilot::app::{Autopilot, AutopilotConfig, HEARTBEAT_PERIOD_US};
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    use autopilot::app::{GUIDANCE_PERIOD_US, GYRO_TX_PERIOD_US, TELEMETRY_PERIOD_US};
    use board_support::uart_rx::{RxFlow, LINK_FLOW};
    use heapless::spsc::{Consumer, Producer, Queue};
    use protocol::{
        AutopilotToStereo, BoardToHost, Heartbeat, HostToBoard, HostToBoardDecoder, ImuSample,
        Message as _, Node,
    };
    use rtic_monotonics::Timebase as _;
    use rtic_sync::channel::{Receiver, Sender};
    use stm32f4xx_hal::{
        gpio::{Output, PC13},
        pac,
        prelude::*,
        serial::{self, Rx, Tx},
        watchdog::IndependentWatchdog,
    };

    type Duration = <Mono as rtic_monotonics::Timebase>::Duration;
    const A2S: usize = AutopilotToStereo::MAX_FRAME_BYTES;
    const B2H: usize = BoardToHost::MAX_FRAME_BYTES;

    #[shared]
    struct Shared {
        ap: &'static mut Autopilot,
        link_tx: Tx<pac::USART1>,
        host_tx: Tx<pac::USART2>,
        /// Messages decoded from the camera board since boot.
        stereo_msgs: u32,
        motors: Motors,
        link_in: Producer<'static, u8>,
        link_wake_tx: Sender<'static, (), 1>,
        /// The IMU, read by the data-ready interrupt and by the fallback timer (real flavour;
        /// `None` in HIL and QEMU, where the host sends the samples).
        imu: Option<super::ImuDevice>,
    }

    #[local]
    struct Local {
        led: PC13<Output>,
        iwdg: IndependentWatchdog,
        link_rx: Rx<pac::USART1>,
        link_out: Consumer<'static, u8>,
        link_wake_rx: Receiver<'static, (), 1>,
        host_rx: Rx<pac::USART2>,
        host_in: Producer<'static, u8>,
        host_out: Consumer<'static, u8>,
        host_wake_tx: Sender<'static, (), 1>,
        host_wake_rx: Receiver<'static, (), 1>,
        host_decoder: HostToBoardDecoder,
        guidance_tick: Tick,
        gyro_tick: Tick,
        telemetry_tick: Tick,
        /// The world clock from the host's IMU timestamps (used by the lockstep flavours).
        world: autopilot::lockstep::WorldClock,
        /// Releases of the periodic tasks on the world clock (a no-op on hardware).
        releases: super::tick::Releases,
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        rc_uart: Rx<pac::USART3>,
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        rc_in: Producer<'static, u8>,
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        rc_out: Consumer<'static, u8>,
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        rc_wake_tx: Sender<'static, (), 1>,
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        rc_wake_rx: Receiver<'static, (), 1>,
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        imu_int: stm32f4xx_hal::gpio::PC4<stm32f4xx_hal::gpio::Input>,
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        imu_timer: stm32f4xx_hal::timer::CounterHz<pac::TIM2>,
    }

    #[init(local = [
        link_q: Queue<u8, RX_QUEUE> = Queue::new(),
        host_q: Queue<u8, RX_QUEUE> = Queue::new(),
        rc_q: Queue<u8, RC_QUEUE> = Queue::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        // First: the status line's `stack_free` is the headroom left from here on.
        board_support::stack::paint();
        let mut rcc = cx.device.RCC.freeze(board::clocks());
        Mono::start(cx.core.SYST, board::SYSTICK_HZ);

        // SAFETY: `init` runs once, before any task; this is the only reference ever made to
        // AP, and it is handed to RTIC as a shared resource.
        #[allow(static_mut_refs)]
        let ap: &'static mut Autopilot =
            unsafe { AP.write(Autopilot::new(AutopilotConfig::default())) };

        let gpioa = cx.device.GPIOA.split(&mut rcc);
        let gpioc = cx.device.GPIOC.split(&mut rcc);
        let led = gpioc.pc13.into_push_pull_output();

        let config = serial::Config::default().baudrate(board::LINK_BAUD.bps());
        let (link_tx, link_rx) = cx
            .device
            .USART1
            .serial::<u8>((gpioa.pa9, gpioa.pa10), config, &mut rcc)
            .unwrap_or_else(|_| log::fatal("USART1 configuration"))
            .split();
        // The camera-board link: circular DMA + IDLE on hardware, RXNE in QEMU (no DMA model).
        #[cfg(feature = "qemu")]
        let link_rx = {
            let mut rx = link_rx;
            rx.listen();
            rx
        };
        #[cfg(not(feature = "qemu"))]
        super::uart_dma::start();
        let (host_tx, mut host_rx) = cx
            .device
            .USART2
            .serial::<u8>((gpioa.pa2, gpioa.pa3), config, &mut rcc)
            .unwrap_or_else(|_| log::fatal("USART2 configuration"))
            .split();
        host_rx.listen();
        let (link_in, link_out) = cx.local.link_q.split();
        let (host_in, host_out) = cx.local.host_q.split();
        let (link_wake_tx, link_wake_rx) = rtic_sync::make_channel!((), 1);
        let (host_wake_tx, host_wake_rx) = rtic_sync::make_channel!((), 1);

        let gpiob = cx.device.GPIOB.split(&mut rcc);
        // SBUS receiver on USART3 RX (PB11): 100,000 Bd, 8 data bits + even parity (the 9-bit
        // word), 2 stop bits.
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let (rc_uart, rc_in, rc_out, rc_wake_tx, rc_wake_rx) = {
            let config = serial::Config::default()
                .baudrate(autopilot::rc::SBUS_BAUD.bps())
                .wordlength_9()
                .parity_even()
                .stopbits(serial::config::StopBits::STOP2);
            let mut rx: Rx<pac::USART3> = cx
                .device
                .USART3
                .rx(gpiob.pb11, config, &mut rcc)
                .unwrap_or_else(|_| log::fatal("USART3 configuration"));
            rx.listen();
            let (rc_in, rc_out) = cx.local.rc_q.split();
            let (tx, rx_wake) = rtic_sync::make_channel!((), 1);
            (rx, rc_in, rc_out, tx, rx_wake)
        };
        #[cfg(any(feature = "qemu", feature = "hil"))]
        let _ = cx.local.rc_q;
        let (_, (c1, c2, c3, c4)) = cx.device.TIM3.pwm_hz(PWM_HZ.Hz(), &mut rcc);
        let motors = Motors::new((
            // PB4 leaves its reset function (JTAG NJTRST) first.
            c1.with(gpiob.pb4.into_floating_input()),
            c2.with(gpiob.pb5),
            c3.with(gpiob.pb0),
            c4.with(gpiob.pb1),
        ));

        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let (imu, imu_timer, imu_int) = {
            use stm32f4xx_hal::spi::{Mode, Phase, Polarity};
            let mode = Mode {
                polarity: Polarity::IdleHigh,
                phase: Phase::CaptureOnSecondTransition,
            };
            let spi = cx.device.SPI1.spi(
                (Some(gpioa.pa5), Some(gpioa.pa6), Some(gpioa.pa7)),
                mode,
                1.MHz(),
                &mut rcc,
            );
            let cs = gpioa
                .pa4
                .into_push_pull_output_in_state(stm32f4xx_hal::gpio::PinState::High);
            let mut imu = super::imu::Mpu6000::new(spi, cs);
            let sysclk = rcc.clocks.sysclk().raw();
            match imu.init(|ms| cortex_m::asm::delay(ms.saturating_mul(sysclk / 1_000))) {
                Ok(()) => log::info!("IMU configured"),
                Err(_) => defmt::error!("MPU-6000 not found on SPI1"),
            }
            let mut timer = cx.device.TIM2.counter_hz(&mut rcc);
            timer
                .start(board::IMU_RATE_HZ.Hz())
                .unwrap_or_else(|_| log::fatal("TIM2 start"));
            timer.listen(stm32f4xx_hal::timer::Event::Update);
            // Data ready: MPU-6000 INT on PC4, rising edge, EXTI4.
            let mut syscfg = cx.device.SYSCFG.constrain(&mut rcc);
            let mut exti = cx.device.EXTI;
            let mut int = gpioc.pc4.into_pull_down_input();
            {
                use stm32f4xx_hal::gpio::{Edge, ExtiPin as _};
                int.make_interrupt_source(&mut syscfg);
                int.trigger_on_edge(&mut exti, Edge::Rising);
                int.enable_interrupt(&mut exti);
            }
            (Some(imu), timer, int)
        };
        #[cfg(any(feature = "qemu", feature = "hil"))]
        let imu: Option<super::ImuDevice> = None;

        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let (guidance_tick, gyro_tick, telemetry_tick, releases) = (
            Tick::every(GUIDANCE_PERIOD_US),
            Tick::every(GYRO_TX_PERIOD_US),
            Tick::every(TELEMETRY_PERIOD_US),
            super::tick::Releases,
        );
        #[cfg(any(feature = "qemu", feature = "hil"))]
        let (guidance_tick, gyro_tick, telemetry_tick, releases) = {
            let g: super::TickChannel = rtic_sync::make_channel!(u64, 1);
            let y: super::TickChannel = rtic_sync::make_channel!(u64, 1);
            let t: super::TickChannel = rtic_sync::make_channel!(u64, 1);
            (
                Tick(g.1),
                Tick(y.1),
                Tick(t.1),
                super::tick::Releases {
                    guidance: g.0,
                    gyro_tx: y.0,
                    telemetry: t.0,
                    timers: autopilot::lockstep::WorldTimers::new(),
                },
            )
        };

        let mut iwdg = IndependentWatchdog::new(cx.device.IWDG);
        iwdg.start(board::WATCHDOG_MS.millis());

        log::info!("autopilot up, sysclk {} Hz", rcc.clocks.sysclk().raw());
        stereo_rx::spawn().ok();
        host_rx::spawn().ok();
        guidance::spawn().ok();
        gyro_tx::spawn().ok();
        telemetry::spawn().ok();
        heartbeat::spawn().ok();
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        rc_rx::spawn().ok();

        (
            Shared {
                ap,
                link_tx,
                host_tx,
                stereo_msgs: 0,
                motors,
                link_in,
                link_wake_tx,
                imu,
            },
            Local {
                led,
                iwdg,
                link_rx,
                link_out,
                link_wake_rx,
                host_rx,
                host_in,
                host_out,
                host_wake_tx,
                host_wake_rx,
                host_decoder: HostToBoardDecoder::new_mid_stream(),
                guidance_tick,
                gyro_tick,
                telemetry_tick,
                world: autopilot::lockstep::WorldClock::new(),
                releases,
                #[cfg(not(any(feature = "qemu", feature = "hil")))]
                rc_uart,
                #[cfg(not(any(feature = "qemu", feature = "hil")))]
                rc_in,
                #[cfg(not(any(feature = "qemu", feature = "hil")))]
                rc_out,
                #[cfg(not(any(feature = "qemu", feature = "hil")))]
                rc_wake_tx,
                #[cfg(not(any(feature = "qemu", feature = "hil")))]
                rc_wake_rx,
                #[cfg(not(any(feature = "qemu", feature = "hil")))]
                imu_int,
                #[cfg(not(any(feature = "qemu", feature = "hil")))]
                imu_timer,
            },
        )
    }

    /// Moves the pending bytes of an RXNE-driven UART into its queue (pausing the interrupt
    /// at a full queue) and wakes the decoding task.
    fn drain_uart<U: serial::Instance>(
        rx: &mut Rx<U>,
        queue: &mut Producer<'static, u8>,
        flow: &RxFlow,
        wake: &mut Sender<'static, (), 1>,
    ) {
        board_support::uart_rx::drain(rx, queue, flow, &super::RX_LOST);
        let _ = wake.try_send(());
    }

    /// USART1 (camera board) receive interrupt: RXNE in QEMU, IDLE line with DMA otherwise.
    #[task(binds = USART1, priority = 6, shared = [link_in, link_wake_tx], local = [link_rx])]
    fn usart1(cx: usart1::Context) {
        let rx = cx.local.link_rx;
        (cx.shared.link_in, cx.shared.link_wake_tx).lock(|queue, wake| {
            #[cfg(feature = "qemu")]
            drain_uart(rx, queue, &LINK_FLOW, wake);
            #[cfg(not(feature = "qemu"))]
            {
                let _ = rx;
                let lost = super::uart_dma::on_interrupt(queue);
                super::RX_LOST.fetch_add(lost, core::sync::atomic::Ordering::Relaxed);
                let _ = wake.try_send(());
            }
        });
    }

    /// DMA2 stream 2 (USART1 RX) half/full transfer: hand on what arrived so far.
    #[cfg(not(feature = "qemu"))]
    #[task(binds = DMA2_STREAM2, priority = 6, shared = [link_in, link_wake_tx])]
    fn usart1_dma(cx: usart1_dma::Context) {
        (cx.shared.link_in, cx.shared.link_wake_tx).lock(|queue, wake| {
            let lost = super::uart_dma::on_interrupt(queue);
            super::RX_LOST.fetch_add(lost, core::sync::atomic::Ordering::Relaxed);
            let _ = wake.try_send(());
        });
    }

    /// USART2 (host) receive interrupt.
    #[task(binds = USART2, priority = 6, local = [host_rx, host_in, host_wake_tx])]
    fn usart2(cx: usart2::Context) {
        drain_uart(
            cx.local.host_rx,
            cx.local.host_in,
            &super::HOST_FLOW,
            cx.local.host_wake_tx,
        );
    }

    /// USART3 (SBUS receiver) receive interrupt (real flavour).
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    #[task(binds = USART3, priority = 6, local = [rc_uart, rc_in, rc_wake_tx])]
    fn usart3(cx: usart3::Context) {
        drain_uart(
            cx.local.rc_uart,
            cx.local.rc_in,
            &super::RC_FLOW,
            cx.local.rc_wake_tx,
        );
    }

    /// RC (real flavour): SBUS frames to pilot commands; also wakes every 20 ms so that a
    /// receiver gone silent kills the motors (see [`autopilot::rc`]).
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    #[task(priority = 4, shared = [ap], local = [
        rc_out,
        rc_wake_rx,
        sbus: autopilot::rc::SbusDecoder = autopilot::rc::SbusDecoder::new(),
        rc: autopilot::rc::RcCommands = autopilot::rc::RcCommands::new(autopilot::rc::RcConfig::DEFAULT),
    ])]
    async fn rc_rx(mut cx: rc_rx::Context) {
        loop {
            let _ = Mono::timeout_after(Duration::from_ticks(20), cx.local.rc_wake_rx.recv()).await;
            let mut buf = [0u8; 32];
            loop {
                let n = super::RC_FLOW.take(cx.local.rc_out, &mut buf);
                if n == 0 {
                    break;
                }
                let now = clock::now_us();
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
            let now = clock::now_us();
            if let Some(c) = cx.local.rc.poll(now) {
                cx.shared.ap.lock(|ap| ap.on_command(c, now));
            }
        }
    }

    /// MPU-6000 data ready (real flavour, 500 Hz): reads the sample and hands it to
    /// `imu_indi`.
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    #[task(binds = EXTI4, priority = 6, shared = [imu], local = [imu_int])]
    fn imu_drdy(mut cx: imu_drdy::Context) {
        use stm32f4xx_hal::gpio::ExtiPin as _;
        cx.local.imu_int.clear_interrupt_pending_bit();
        let now = clock::now_us();
        super::LAST_DRDY_US.store(now as u32, core::sync::atomic::Ordering::Relaxed);
        if let Some(Ok(sample)) = cx
            .shared
            .imu
            .lock(|imu| imu.as_mut().map(|imu| imu.read(now as u32)))
        {
            // Still busy with the previous sample: skip this one.
            let _ = imu_indi::spawn((sample, now));
        }
    }

    /// 512 Hz timer (real flavour): the fallback when the data-ready interrupt stops (a broken
    /// INT wire, a sensor reset that lost its interrupt set-up). While data-ready pulses come it
    /// does nothing; after `board::IMU_DRDY_TIMEOUT_US` without one it reads the IMU itself
    /// (counted in the status line's `imu_fallback`). If the IMU itself stops answering, the
    /// library's IMU-stale failsafe turns the motors off.
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    #[task(binds = TIM2, priority = 6, shared = [imu], local = [imu_timer])]
    fn imu_timer(mut cx: imu_timer::Context) {
        cx.local
            .imu_timer
            .clear_flags(stm32f4xx_hal::timer::Flag::Update);
        let now = clock::now_us();
        let last = super::LAST_DRDY_US.load(core::sync::atomic::Ordering::Relaxed);
        if (now as u32).wrapping_sub(last) <= board::IMU_DRDY_TIMEOUT_US {
            return;
        }
        super::IMU_FALLBACK_READS.fetch_add(1, core::sync::atomic::Ordering::Relaxed);
        if let Some(Ok(sample)) = cx
            .shared
            .imu
            .lock(|imu| imu.as_mut().map(|imu| imu.read(now as u32)))
        {
            let _ = imu_indi::spawn((sample, now));
        }
    }

    /// 512 Hz: IMU sample (and its library time, µs) -> attitude -> INDI -> motors. In the
    /// lockstep flavours it then releases the periodic tasks due at the sample's world time.
    #[task(priority = 5, shared = [ap, motors, host_tx], local = [releases])]
    async fn imu_indi(mut cx: imu_indi::Context, sample: (ImuSample, u64)) {
        let (imu, now) = sample;
        let throttle = cx.shared.ap.lock(|ap| ap.on_imu(&imu, now));
        motors_out(&mut cx.shared.motors, &mut cx.shared.host_tx, now, throttle);
        cx.local.releases.release(now);
    }

    /// Motor command out: PWM, and the host link in HIL/QEMU.
    fn motors_out(
        motors: &mut impl rtic::Mutex<T = Motors>,
        host_tx: &mut impl rtic::Mutex<T = Tx<pac::USART2>>,
        now: u64,
        throttle: [f32; 4],
    ) {
        motors.lock(|m| m.set(throttle));
        #[cfg(any(feature = "qemu", feature = "hil"))]
        {
            let msg = BoardToHost::Motors(protocol::MotorCommand {
                timestamp_us: now as u32,
                throttle,
            });
            host_tx.lock(|tx| send::<_, _, B2H>(tx, &msg));
        }
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let _ = (host_tx, now);
    }

    /// Camera-board bytes: estimates, status, heartbeats, config acks.
    #[task(priority = 4, shared = [ap, stereo_msgs], local = [link_out, link_wake_rx])]
    async fn stereo_rx(mut cx: stereo_rx::Context) {
        let mut buf = [0u8; 64];
        while cx.local.link_wake_rx.recv().await.is_ok() {
            loop {
                let n = LINK_FLOW.take(cx.local.link_out, &mut buf);
                if n == 0 {
                    break;
                }
                let now = clock::lib_now_us();
                let bytes = buf.get(..n).unwrap_or(&[]);
                let decoded = cx.shared.ap.lock(|ap| ap.on_stereo_bytes(bytes, now));
                cx.shared
                    .stereo_msgs
                    .lock(|c| *c = c.wrapping_add(decoded as u32));
            }
        }
    }

    /// Host bytes: IMU samples (HIL), external position, pilot commands.
    #[task(priority = 4, shared = [ap], local = [host_out, host_wake_rx, host_decoder, world])]
    async fn host_rx(mut cx: host_rx::Context) {
        let mut buf = [0u8; 64];
        while cx.local.host_wake_rx.recv().await.is_ok() {
            loop {
                let n = super::HOST_FLOW.take(cx.local.host_out, &mut buf);
                if n == 0 {
                    break;
                }
                for &byte in buf.get(..n).unwrap_or(&[]) {
                    let Some(msg) = cx.local.host_decoder.push(byte) else {
                        continue;
                    };
                    match msg {
                        HostToBoard::Imu(sample) => {
                            // Lockstep flavours: the sample's timestamp is the world time.
                            #[cfg(any(feature = "qemu", feature = "hil"))]
                            let at = {
                                let at = cx.local.world.observe(sample.timestamp_us);
                                clock::set_world_us(cx.local.world.now_us());
                                at
                            };
                            #[cfg(not(any(feature = "qemu", feature = "hil")))]
                            let at = clock::now_us();
                            // A sample arriving while the previous one is still being
                            // processed is skipped (the IMU failsafe watches the rate).
                            let _ = imu_indi::spawn((sample, at));
                        }
                        HostToBoard::ExternalPosition(pos) => {
                            let now = clock::lib_now_us();
                            cx.shared.ap.lock(|ap| ap.on_external_position(&pos, now))
                        }
                        HostToBoard::Command(cmd) => {
                            let now = clock::lib_now_us();
                            cx.shared.ap.lock(|ap| ap.on_command(cmd, now))
                        }
                        HostToBoard::Heartbeat(_) | HostToBoard::FrameChunk(_) => {}
                    }
                }
            }
        }
    }

    /// 50 Hz: FSM, force field, velocity and height loops; motors off when they must be.
    #[task(priority = 3, shared = [ap, motors, host_tx], local = [guidance_tick])]
    async fn guidance(mut cx: guidance::Context) {
        loop {
            let now = cx.local.guidance_tick.wait().await;
            let off = cx.shared.ap.lock(|ap| {
                ap.guidance_step(now);
                ap.motor_safety(now)
            });
            if let Some(throttle) = off {
                motors_out(&mut cx.shared.motors, &mut cx.shared.host_tx, now, throttle);
            }
        }
    }

    /// 128 Hz: gyro and attitude to the camera board for derotation.
    #[task(priority = 2, shared = [ap, link_tx], local = [gyro_tick])]
    async fn gyro_tx(mut cx: gyro_tx::Context) {
        loop {
            let now = cx.local.gyro_tick.wait().await;
            let msg =
                AutopilotToStereo::GyroAttitude(cx.shared.ap.lock(|ap| ap.gyro_attitude(now)));
            cx.shared.link_tx.lock(|tx| send::<_, _, A2S>(tx, &msg));
        }
    }

    /// 10 Hz: telemetry to the host.
    #[task(priority = 1, shared = [ap, host_tx], local = [telemetry_tick])]
    async fn telemetry(mut cx: telemetry::Context) {
        loop {
            let now = cx.local.telemetry_tick.wait().await;
            let msg = BoardToHost::Telemetry(cx.shared.ap.lock(|ap| ap.telemetry(now)));
            cx.shared.host_tx.lock(|tx| send::<_, _, B2H>(tx, &msg));
        }
    }

    /// 1 Hz: heartbeats to both links, LED, watchdog, a status log line.
    #[task(priority = 1, shared = [ap, link_tx, host_tx, stereo_msgs], local = [led, iwdg])]
    async fn heartbeat(mut cx: heartbeat::Context) {
        loop {
            let now = clock::now_us();
            let uptime_ms = (now / 1_000) as u32;
            let hb = Heartbeat::new(Node::Autopilot, uptime_ms);
            cx.shared
                .link_tx
                .lock(|tx| send::<_, _, A2S>(tx, &AutopilotToStereo::Heartbeat(hb)));
            cx.shared
                .host_tx
                .lock(|tx| send::<_, _, B2H>(tx, &BoardToHost::Heartbeat(hb)));
            cx.local.led.toggle();
            cx.local.iwdg.feed();
            let msgs = cx.shared.stereo_msgs.lock(|c| *c);
            let (errors, estimates, peer) = cx.shared.ap.lock(|ap| {
                (
                    ap.link_errors().total(),
                    ap.estimates_received(),
                    ap.stereo_heartbeat().map(|(_, h)| h.uptime_ms),
                )
            });
            log::info!(
                "status uptime_ms={} stereo_rx_ok={} link_errors={} estimates={} stereo_uptime_ms={} imu_fallback={} rx_lost={} stack_free={}",
                uptime_ms,
                msgs,
                errors,
                estimates,
                peer.unwrap_or(u32::MAX),
                super::IMU_FALLBACK_READS.load(core::sync::atomic::Ordering::Relaxed),
                super::RX_LOST.load(core::sync::atomic::Ordering::Relaxed),
                board_support::stack::free_bytes()
            );
            Mono::delay(Duration::from_ticks(ticks(HEARTBEAT_PERIOD_US))).await;
        }
    }
}
