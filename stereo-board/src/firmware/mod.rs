//! RTIC 2 application of the stereo-board firmware (thumbv7em-none-eabihf only).
//!
//! A thin shell around [`stereo_board::app`]: the tasks below mirror `app::TASKS` and each body
//! is one call into [`StereoBoardApp`]. Pins, peripherals, clocks and rates come from the board
//! definition, [`stereo_board::board`].
//!
//! | RTIC task | prio | binds / trigger | body |
//! |---|---|---|---|
//! | `link_irq` | 4 | link UART (UART4; USART1 in QEMU): RXNE, TXE | bytes into a lock-free queue (a full queue pauses the interrupt, see [`board_support::uart_rx`]); queued frames out ([`board_support::uart_tx`]) |
//! | `uart_rx` | 3 | woken by `link_irq` | [`StereoBoardApp::on_rx_bytes`] (with the parameter sector on the real board) |
//! | `host_irq` / `host_rx` | 4 / 3 | USART2 RXNE (qemu) or IDLE (hil: received by DMA, [`board_support::uart_dma`]), TXE | [`StereoBoardApp::on_host_bytes`]; queued frames out |
//! | `host_dma` | 4 | DMA1 stream 5 (hil) | half/full buffer: pends `host_irq` |
//! | `dcmi_irq` | 4 | DCMI frame end, VSYNC, overrun, sync error (real) | checks the frame ([`stereo_board::camera::CaptureMonitor`]), hands a whole one on, re-arms after a torn one |
//! | `dma_irq` | 4 | DMA2 stream 1 transfer / direct-mode error (real) | counts, re-arms |
//! | `frame` | 2 | spawned per frame | [`StereoBoardApp::process_frame`] + `send_estimate` (or `discard_processed_frame` when the buffer was refilled meanwhile) |
//! | `status` | 1 | every `app::STATUS_PERIOD_US` | capture state in, [`StereoBoardApp::status_tick`], host heartbeat, LED, watchdog |
//! | `idle` | 0 | nothing else to run | `WFI` (sleep until an interrupt) |
//!
//! Edge-FS runs inside a lock of the board state, whose ceiling is the receive tasks'
//! priority 3: while a frame is processed, received bytes wait in the queues filled at
//! priority 4 and are decoded right after. The gyro sample used for a frame is the latest one
//! when processing starts. Frames go out through [`board_support::uart_tx`]: a task copies a
//! whole frame into the UART's transmit queue (never waiting for the line; a full queue drops
//! the frame and counts it) and the UART's interrupt moves the bytes out, one per TXE.
//!
//! Time: on hardware the library sees the board clock. In the `hil` and `qemu` flavours it
//! sees the world time of the host's simulation ([`clock::lib_now_us`]): frames carry their
//! exposure time in world time and the autopilot, which runs in lockstep with the host, stamps
//! its gyro samples with world time, so gyro ages and processing times are measured on one
//! clock however slowly the link lets the world run. `status` stays on the board clock.
//!
//! Parameters: at boot the Edge-FS parameters are the record saved in the parameter sector
//! ([`board_support::param_flash`], [`StereoBoardApp::load_params`]), or the defaults when there
//! is none or it is bad (logged, and answered to `ParamOp::Storage`). A save, passed on by the
//! autopilot only while its motors are off, erases and programs the sector in `uart_rx` with
//! the board lock held: the core stalls for the erase anyway (a second or two; no frame is
//! processed meanwhile), and the watchdog is given [`board_support::watchdog::SAVE`] for it
//! ([`board_support::param_flash::WatchedSector`]). The `qemu` flavour has no parameter
//! storage.
//!
//! Memory: the board state (Edge-FS history, decoders) is CPU-only and lives in CCM
//! ([`APP`]); camera frame buffers are DMA targets in SRAM. `cargo xtask size` prints the
//! static use.
//!
//! Flavours: `real` (the original board: camera on the DCMI, link on UART4), `hil` (the same
//! board, frames from a host on USART2) and `qemu` (`-M netduinoplus2`: no camera, link on
//! USART1 and host on USART2, the first two `-serial` ports).

mod board;
mod clock;
#[cfg(not(any(feature = "qemu", feature = "hil")))]
mod dcmi;
mod pins;
#[cfg(not(any(feature = "qemu", feature = "hil")))]
mod sccb;
use board_support::log;

use core::mem::MaybeUninit;
use core::sync::atomic::AtomicU32;
use defmt_rtt as _;

// Panic and HardFault: log, then wait for the watchdog (the camera board drives no actuator).
board_support::fault_handlers!(no_actuators);

/// The camera board's actuator stop for the fault path: it has none.
fn no_actuators() {}
use stereo_board::app::StereoBoardApp;

rtic_monotonics::systick_monotonic!(Mono, 1_000);

/// The board state: CPU-only, so it lives in CCM. The section is NOLOAD (not initialised by
/// the start-up code); `init` writes it before anything reads it.
#[link_section = ".ccmram"]
static mut APP: MaybeUninit<StereoBoardApp> = MaybeUninit::uninit();

/// Received bytes lost since boot: queue full, or a UART overrun/framing/noise error.
static RX_LOST: AtomicU32 = AtomicU32::new(0);

/// Frames lost since the frame task last looked (a frame ended while the task was busy).
static FRAMES_LOST: AtomicU32 = AtomicU32::new(0);

/// Bytes of each receive queue between the RX interrupt and its decoding task.
const RX_QUEUE: usize = 4096;

/// Bytes of the host link's receive and transmit queues: the host link exists in the qemu and
/// hil flavours only (the real board's queues are token ones).
#[cfg(any(feature = "qemu", feature = "hil"))]
const HOST_QUEUE: (usize, usize) = (RX_QUEUE, TX_QUEUE);
/// Bytes of the host link's receive and transmit queues (see the lockstep flavours').
#[cfg(not(any(feature = "qemu", feature = "hil")))]
const HOST_QUEUE: (usize, usize) = (2, 2);

/// Bytes of each transmit queue: an estimate (25 Hz) and the status and heartbeat (1 Hz) are a
/// few dozen bytes each; at 115,200 Bd the line drains about 11 bytes per ms, so the queue
/// holds well over a second's worth of what the board sends.
const TX_QUEUE: usize = 1024;

/// Queues whole frames on a UART's transmit queue (see [`board_support::uart_tx`]).
fn queue_frame(tx: &mut board_support::uart_tx::TxWriter, frame: &[u8]) {
    // A full queue drops the frame and counts it (`TxWriter::dropped_frames`, in the log).
    let _ = tx.send(frame);
}

/// The link UART: UART4 on the camera board ([`stereo_board::board::LINK_UART`]); USART1 on
/// QEMU's netduinoplus2 (its first `-serial` port).
#[cfg(not(feature = "qemu"))]
type LinkUart = stm32f4xx_hal::pac::UART4;
/// The link UART (see the hardware flavours').
#[cfg(feature = "qemu")]
type LinkUart = stm32f4xx_hal::pac::USART1;
/// The link UART's interrupt.
#[cfg(not(feature = "qemu"))]
const LINK_IRQ: stm32f4xx_hal::pac::Interrupt = stm32f4xx_hal::pac::Interrupt::UART4;
/// The link UART's interrupt.
#[cfg(feature = "qemu")]
const LINK_IRQ: stm32f4xx_hal::pac::Interrupt = stm32f4xx_hal::pac::Interrupt::USART1;

/// Back-pressure of the link's RXNE interrupt.
static LINK_FLOW: board_support::uart_rx::RxFlow = board_support::uart_rx::RxFlow::new(LINK_IRQ);

/// Back-pressure of the host link's RXNE interrupt (qemu, hil flavours).
#[cfg(any(feature = "qemu", feature = "hil"))]
static HOST_FLOW: board_support::uart_rx::RxFlow =
    board_support::uart_rx::RxFlow::new(stm32f4xx_hal::pac::Interrupt::USART2);

/// The host link's receiver: its RXNE interrupt (qemu; the real board has no host link), or a
/// circular DMA (hil: 921,600 Bd, a byte lasts less than logging holds the interrupts off, see
/// [`board_support::uart_dma`]).
#[cfg(not(all(feature = "hil", not(feature = "qemu"))))]
type HostRx = stm32f4xx_hal::serial::Rx<stm32f4xx_hal::pac::USART2>;
/// The host link's receiver (see the qemu flavour's).
#[cfg(all(feature = "hil", not(feature = "qemu")))]
type HostRx = board_support::uart_dma::DmaRx;

/// Takes over the host link's receive side: its RXNE interrupt on.
#[cfg(feature = "qemu")]
fn host_receiver(mut rx: stm32f4xx_hal::serial::Rx<stm32f4xx_hal::pac::USART2>) -> HostRx {
    use stm32f4xx_hal::serial::RxListen as _;
    rx.listen();
    rx
}

/// Takes over the host link's receive side (the HAL's `rx`, consumed): circular DMA into a
/// buffer in SRAM.
#[cfg(all(feature = "hil", not(feature = "qemu")))]
fn host_receiver(_rx: stm32f4xx_hal::serial::Rx<stm32f4xx_hal::pac::USART2>) -> HostRx {
    let buf = cortex_m::singleton!(: [u8; 1024] = [0; 1024])
        .unwrap_or_else(|| log::fatal("the host link's DMA buffer is taken once"));
    // SAFETY: USART2's receive side is handed over here (its HAL `Rx` is consumed); DMA1
    // stream 5 serves only it; the buffer is a static in SRAM, which DMA1 reaches.
    unsafe {
        board_support::uart_dma::DmaRx::start(
            stm32f4xx_hal::pac::USART2::ptr(),
            board::HOST_RX_DMA,
            buf,
        )
    }
}

#[cfg(any(feature = "qemu", feature = "hil"))]
/// A frame handed from the host-link task to the frame task (qemu, hil flavours): the
/// buffer and its exposure time (`None`: empty).
pub struct FrameSlot {
    buf: [u8; protocol::STEREO_FRAME_BYTES],
    capture_us: Option<u64>,
}

#[cfg(any(feature = "qemu", feature = "hil"))]
impl FrameSlot {
    const fn new() -> Self {
        Self {
            buf: [0; protocol::STEREO_FRAME_BYTES],
            capture_us: None,
        }
    }
}

/// The HIL frame slot (SRAM).
#[cfg(any(feature = "qemu", feature = "hil"))]
static mut SLOT: FrameSlot = FrameSlot::new();

/// The HIL frame assembler (SRAM).
#[cfg(any(feature = "qemu", feature = "hil"))]
static mut ASSEMBLER: stereo_board::app::FrameAssembler = stereo_board::app::FrameAssembler::new();

/// The camera's double buffer (real flavour; the buffers themselves live in [`dcmi`]).
#[cfg(not(any(feature = "qemu", feature = "hil")))]
pub struct Camera;

/// Where the frame task finds its frame.
#[cfg(any(feature = "qemu", feature = "hil"))]
type Frames = &'static mut FrameSlot;
/// Where the frame task finds its frame.
#[cfg(not(any(feature = "qemu", feature = "hil")))]
type Frames = Camera;

/// What the frame task is spawned with.
#[cfg(any(feature = "qemu", feature = "hil"))]
type FrameReady = ();
/// What the frame task is spawned with: the delivered DMA buffer.
#[cfg(not(any(feature = "qemu", feature = "hil")))]
type FrameReady = dcmi::Delivered;

/// The frame task's view of its frame source.
trait FrameSource {
    /// The frame and its exposure time, µs.
    fn take(&mut self, ready: &FrameReady) -> Option<(&[u8; protocol::STEREO_FRAME_BYTES], u64)>;
    /// True if the frame was not touched while it was being processed.
    fn intact(&self, ready: &FrameReady) -> bool;
    /// Done with the frame.
    fn release(&mut self, ready: &FrameReady);
}

#[cfg(any(feature = "qemu", feature = "hil"))]
impl FrameSource for &'static mut FrameSlot {
    fn take(&mut self, _: &()) -> Option<(&[u8; protocol::STEREO_FRAME_BYTES], u64)> {
        let capture = self.capture_us.take()?;
        Some((&self.buf, capture))
    }
    // The slot is written only by `host_rx`, under the same lock as the frame task's.
    fn intact(&self, _: &()) -> bool {
        true
    }
    fn release(&mut self, _: &()) {}
}

#[cfg(not(any(feature = "qemu", feature = "hil")))]
impl FrameSource for Camera {
    fn take(&mut self, ready: &FrameReady) -> Option<(&[u8; protocol::STEREO_FRAME_BYTES], u64)> {
        dcmi::frame(ready).map(|f| (f, ready.capture_us))
    }
    fn intact(&self, ready: &FrameReady) -> bool {
        dcmi::intact(ready)
    }
    fn release(&mut self, ready: &FrameReady) {
        dcmi::release(ready);
    }
}

/// Busy-waits `us` microseconds on the core clock (start-up only).
#[cfg(not(any(feature = "qemu", feature = "hil")))]
fn delay_us(us: u32) {
    cortex_m::asm::delay(us.saturating_mul(stereo_board::board::SYSCLK_HZ / 1_000_000));
}

/// Brings the cameras up as the original board does: CPLD mode and reset are already set by
/// the pin table (reset held low); clock on, reset released after
/// [`stereo_board::board::CAMERA_RESET_LOW_US`], registers written after
/// [`stereo_board::board::CAMERA_RESET_RECOVERY_US`] and each read back. Returns the first
/// register that failed, if any.
#[cfg(not(any(feature = "qemu", feature = "hil")))]
fn bring_up_cameras(i2c: stm32f4xx_hal::pac::I2C2) -> Result<(), (u8, sccb::SccbError)> {
    use stereo_board::board;
    use stereo_board::camera::tcm8230;
    dcmi::start_camera_clock();
    delay_us(board::CAMERA_RESET_LOW_US);
    pins::set(&board::CAMERA_RESET, true);
    delay_us(board::CAMERA_RESET_RECOVERY_US);
    let mut bus = sccb::Sccb::new(i2c);
    for &(reg, value) in &tcm8230::SETUP {
        bus.write(reg, value).map_err(|e| (reg, e))?;
        match bus.read(reg) {
            Ok(v) if v == value => {}
            Ok(_) => return Err((reg, sccb::SccbError::Bus)),
            Err(e) => return Err((reg, e)),
        }
    }
    Ok(())
}

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true, dispatchers = [SPI2, SPI3, UART5])]
mod app {
    use super::{board, clock, log, queue_frame, FrameSource as _, Mono, APP, LINK_FLOW};
    use super::{HOST_QUEUE, RX_QUEUE, TX_QUEUE};
    use board_support::uart_tx::{TxPump, TxQueue, TxWriter};
    use core::sync::atomic::Ordering;
    use heapless::spsc::{Consumer, Producer, Queue};
    use rtic_monotonics::Timebase as _;
    use rtic_sync::channel::{Receiver, Sender};
    use stereo_board::app::{StereoBoardApp, STATUS_PERIOD_US};
    use stereo_board::edge_fs::EdgeFsParams;
    use stm32f4xx_hal::{
        pac,
        prelude::*,
        serial::{self, Rx},
        watchdog::IndependentWatchdog,
    };

    use super::{FrameReady, Frames, LinkUart};
    use board_support::param_flash::{ParamSector, WatchedSector};
    use board_support::watchdog::HEARTBEAT_FED;
    use protocol::BoardToHost;
    use rtic::mutex::prelude::*;
    use stereo_board::app::send_to_host;
    use stereo_board::camera::CaptureMonitor;

    type Duration = <Mono as rtic_monotonics::Timebase>::Duration;
    type Wake = ();

    #[shared]
    struct Shared {
        board: &'static mut StereoBoardApp,
        /// The link's transmit queue (tasks' side).
        link_tx: TxWriter,
        /// The host link's transmit queue (qemu, hil flavours; the real board leaves its
        /// USART2 unused).
        host_tx: Option<TxWriter>,
        frames: Frames,
        /// The capture path's state (real flavour; idle in the others).
        capture: CaptureMonitor,
        // The link interrupt's resources (shared only because the flavours bind different
        // interrupts; one task uses them).
        link_rx: Rx<LinkUart>,
        link_in: Producer<'static, u8>,
        link_wake_tx: Sender<'static, Wake, 1>,
        link_pump: TxPump<LinkUart>,
        /// The watchdog: fed by `status`, given the save's timeout by `uart_rx` for a save.
        iwdg: IndependentWatchdog,
    }

    #[local]
    struct Local {
        /// The parameter sector (`None` in the `qemu` flavour).
        param_sector: Option<ParamSector>,
        link_out: Consumer<'static, u8>,
        link_wake_rx: Receiver<'static, Wake, 1>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_rx: super::HostRx,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_pump: TxPump<pac::USART2>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_in: Producer<'static, u8>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_out: Consumer<'static, u8>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_wake_tx: Sender<'static, Wake, 1>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_wake_rx: Receiver<'static, Wake, 1>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        assembler: &'static mut stereo_board::app::FrameAssembler,
    }

    #[init(local = [
        link_q: Queue<u8, RX_QUEUE> = Queue::new(),
        host_q: Queue<u8, { HOST_QUEUE.0 }> = Queue::new(),
        link_txq: TxQueue<TX_QUEUE> = TxQueue::new(),
        host_txq: TxQueue<{ HOST_QUEUE.1 }> = TxQueue::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        // First: the status line's `stack_free` is the headroom left from here on.
        board_support::stack::paint();
        let mut rcc = cx.device.RCC.freeze(board::clocks());
        Mono::start(cx.core.SYST, board::SYSTICK_HZ);

        // SAFETY: `init` runs once, before any task; this is the only reference ever made to
        // APP, and it is handed to RTIC as a shared resource.
        #[allow(static_mut_refs)]
        let board_state: &'static mut StereoBoardApp =
            unsafe { APP.write(StereoBoardApp::new(EdgeFsParams::default_config())) };
        // The saved parameters, or the defaults and why (QEMU models no flash interface).
        let param_sector = (!cfg!(feature = "qemu")).then(|| ParamSector::new(cx.device.FLASH));
        if let Some(sector) = &param_sector {
            match board_state.load_params(sector) {
                Ok(()) => log::info!("parameters: the saved record is in use"),
                Err(why) => defmt::warn!("parameters: defaults ({})", why),
            }
        }

        // The HAL's port split resets the port: split before the pin table is applied.
        let gpioa = cx.device.GPIOA.split(&mut rcc);
        let link_config = serial::Config::default().baudrate(stereo_board::board::LINK_BAUD.bps());
        #[cfg(not(feature = "qemu"))]
        let link = cx
            .device
            .UART4
            .serial::<u8>((gpioa.pa0, gpioa.pa1), link_config, &mut rcc)
            .unwrap_or_else(|_| log::fatal("UART4 configuration"));
        #[cfg(feature = "qemu")]
        let link = cx
            .device
            .USART1
            .serial::<u8>((gpioa.pa9, gpioa.pa10), link_config, &mut rcc)
            .unwrap_or_else(|_| log::fatal("USART1 configuration"));
        let (link_tx, mut link_rx) = link.split();
        link_rx.listen();
        let (link_tx, link_pump) = cx.local.link_txq.split(link_tx, super::LINK_IRQ);
        let (link_in, link_out) = cx.local.link_q.split();
        let (link_wake_tx, link_wake_rx) = rtic_sync::make_channel!(Wake, 1);

        // The host link: HIL frames in, estimates mirrored out (qemu, hil flavours).
        #[cfg(any(feature = "qemu", feature = "hil"))]
        let (host_tx, host_pump, host_rx, host_in, host_out, host_wake_tx, host_wake_rx) = {
            let (tx, rx) = cx
                .device
                .USART2
                .serial::<u8>(
                    (gpioa.pa2, gpioa.pa3),
                    serial::Config::default().baudrate(board::HOST_BAUD.bps()),
                    &mut rcc,
                )
                .unwrap_or_else(|_| log::fatal("USART2 configuration"))
                .split();
            let rx = super::host_receiver(rx);
            let (tx, pump) = cx.local.host_txq.split(tx, pac::Interrupt::USART2);
            let (q_in, q_out) = cx.local.host_q.split();
            let (wake_tx, wake_rx) = rtic_sync::make_channel!(Wake, 1);
            (tx, pump, rx, q_in, q_out, wake_tx, wake_rx)
        };
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let (host_tx, _, _) = (None, cx.local.host_q, cx.local.host_txq);
        #[cfg(any(feature = "qemu", feature = "hil"))]
        let host_tx = Some(host_tx);
        #[cfg(any(feature = "qemu", feature = "hil"))]
        let capture = CaptureMonitor::new();
        #[cfg(any(feature = "qemu", feature = "hil"))]
        // SAFETY: `init` runs once; these are the only references to the two statics.
        #[allow(static_mut_refs)]
        let (frames, assembler): (Frames, &'static mut stereo_board::app::FrameAssembler) = unsafe {
            (
                &mut *core::ptr::addr_of_mut!(super::SLOT),
                &mut *core::ptr::addr_of_mut!(super::ASSEMBLER),
            )
        };

        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let (frames, capture) = {
            // Every pin of the board table: CPLD in pixel-mux mode, cameras held in reset,
            // clock, DCMI and SCCB pins, the link's pull-ups, the LED.
            super::pins::configure_all();
            match super::bring_up_cameras(cx.device.I2C2) {
                Ok(()) => log::info!("cameras configured"),
                Err((reg, e)) => {
                    defmt::error!("camera set-up failed at register {=u8:#x}: {}", reg, e)
                }
            }
            let mut capture = CaptureMonitor::new();
            super::dcmi::configure();
            super::dcmi::start(&mut capture, clock::now_us());
            (super::Camera, capture)
        };
        // The hil flavour: the board's link and host UART pins as the table gives them (the
        // HAL leaves the pull-ups off), the cameras held in reset, the LED.
        #[cfg(all(feature = "hil", not(feature = "qemu")))]
        super::pins::configure(&stereo_board::board::HIL_PINS);
        #[cfg(feature = "qemu")]
        super::pins::configure(&[stereo_board::board::LED]);

        let mut iwdg = IndependentWatchdog::new(cx.device.IWDG);
        board_support::watchdog::set(&mut iwdg, HEARTBEAT_FED);

        log::info!("stereo-board up, sysclk {} Hz", rcc.clocks.sysclk().raw());
        status::spawn().ok();
        uart_rx::spawn().ok();
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_rx::spawn().ok();

        (
            Shared {
                board: board_state,
                link_tx,
                host_tx,
                frames,
                capture,
                link_rx,
                link_in,
                link_wake_tx,
                link_pump,
                iwdg,
            },
            Local {
                param_sector,
                link_out,
                link_wake_rx,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_rx,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_pump,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_in,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_out,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_wake_tx,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_wake_rx,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                assembler,
            },
        )
    }

    /// Nothing to do: sleep until the next interrupt (RM0090 5.3.3, Sleep mode: the core
    /// stops, the peripherals, DMA and their interrupts run on). Without it the core spins, and
    /// an emulator has to execute every cycle instead of skipping to the next event.
    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// The link UART's interrupt (UART4; USART1 in QEMU): queued frames out, received bytes
    /// into the queue.
    #[cfg(not(feature = "qemu"))]
    #[task(binds = UART4, priority = 4, shared = [link_rx, link_in, link_wake_tx, link_pump])]
    fn link_irq(cx: link_irq::Context) {
        (
            cx.shared.link_rx,
            cx.shared.link_in,
            cx.shared.link_wake_tx,
            cx.shared.link_pump,
        )
            .lock(super::link_interrupt);
    }

    /// The link UART's interrupt (see the hardware flavours').
    #[cfg(feature = "qemu")]
    #[task(binds = USART1, priority = 4, shared = [link_rx, link_in, link_wake_tx, link_pump])]
    fn link_irq_qemu(cx: link_irq_qemu::Context) {
        (
            cx.shared.link_rx,
            cx.shared.link_in,
            cx.shared.link_wake_tx,
            cx.shared.link_pump,
        )
            .lock(super::link_interrupt);
    }

    /// Decodes the autopilot's bytes (gyro/attitude, config, parameter requests, heartbeat);
    /// a parameter save writes the parameter sector under the save's watchdog timeout.
    #[task(priority = 3, shared = [board, link_tx, iwdg], local = [link_out, link_wake_rx, param_sector])]
    async fn uart_rx(mut cx: uart_rx::Context) {
        loop {
            if cx.local.link_wake_rx.recv().await.is_err() {
                return;
            }
            let mut buf = [0u8; 64];
            loop {
                let n = LINK_FLOW.take(cx.local.link_out, &mut buf);
                if n == 0 {
                    break;
                }
                let now = timebase::Instant::from_micros(clock::lib_now_us());
                let bytes = buf.get(..n).unwrap_or(&[]);
                let sector = cx.local.param_sector.as_mut();
                let mut shared = (
                    &mut cx.shared.board,
                    &mut cx.shared.link_tx,
                    &mut cx.shared.iwdg,
                );
                shared.lock(|board, tx, watchdog| {
                    let mut tx = |frame: &[u8]| queue_frame(tx, frame);
                    match sector {
                        Some(sector) => {
                            let before = board.storage();
                            let mut store =
                                WatchedSector::new(&mut *sector, HEARTBEAT_FED, |timeout| {
                                    board_support::watchdog::set(watchdog, timeout)
                                });
                            board.on_rx_bytes(bytes, now, &mut tx, Some(&mut store));
                            super::log_save(before, board.storage(), sector.last_error());
                        }
                        None => board.on_rx_bytes(bytes, now, &mut tx, None),
                    }
                    // Lockstep flavours: the autopilot's gyro timestamps are world time.
                    #[cfg(any(feature = "qemu", feature = "hil"))]
                    if let Some(g) = board.latest_gyro() {
                        clock::observe_world_gyro(g.timestamp_us);
                    }
                });
            }
        }
    }

    /// USART2 (host link: HIL frames in, estimates out) interrupt.
    #[cfg(any(feature = "qemu", feature = "hil"))]
    #[task(binds = USART2, priority = 4, local = [host_rx, host_in, host_wake_tx, host_pump])]
    fn host_irq(cx: host_irq::Context) {
        use board_support::uart_rx::Receiver as _;
        cx.local.host_pump.pump();
        cx.local
            .host_rx
            .receive(cx.local.host_in, &super::HOST_FLOW, &super::RX_LOST);
        let _ = cx.local.host_wake_tx.try_send(());
    }

    /// DMA1 stream 5 (hil): the host link's receive buffer is half or wholly full; `host_irq`
    /// hands the bytes on.
    #[cfg(all(feature = "hil", not(feature = "qemu")))]
    #[task(binds = DMA1_STREAM5, priority = 4)]
    fn host_dma(_: host_dma::Context) {
        board::HOST_RX_DMA.acknowledge();
        rtic::pend(pac::Interrupt::USART2);
    }

    /// Decodes the host's bytes and assembles frame chunks; a completed frame goes to the
    /// frame slot (replacing, and counting as dropped, one that was not processed yet).
    #[cfg(any(feature = "qemu", feature = "hil"))]
    #[task(priority = 3, shared = [board, frames], local = [host_out, host_wake_rx, assembler])]
    async fn host_rx(mut cx: host_rx::Context) {
        loop {
            if cx.local.host_wake_rx.recv().await.is_err() {
                return;
            }
            let mut buf = [0u8; 256];
            loop {
                let n = super::HOST_FLOW.take(cx.local.host_out, &mut buf);
                if n == 0 {
                    break;
                }
                let bytes = buf.get(..n).unwrap_or(&[]);
                let assembler = &mut *cx.local.assembler;
                let ready = (&mut cx.shared.board, &mut cx.shared.frames).lock(|board, slot| {
                    let mut ready = false;
                    let mut overwritten = 0u32;
                    board.on_host_bytes(bytes, assembler, |frame, capture| {
                        let capture_us = capture.as_micros();
                        if slot.capture_us.is_some() {
                            overwritten += 1;
                        }
                        slot.buf.copy_from_slice(frame);
                        slot.capture_us = Some(capture_us);
                        clock::observe_world_us(capture_us);
                        ready = true;
                    });
                    for _ in 0..overwritten {
                        board.frame_dropped();
                    }
                    ready
                });
                if ready {
                    frame::spawn(()).ok();
                }
            }
        }
    }

    /// DCMI interrupt (frame end, VSYNC, overrun, sync error): a whole frame goes to the frame
    /// task; one ending while the task is still busy is dropped and counted.
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    #[task(binds = DCMI, priority = 4, shared = [capture])]
    fn dcmi_irq(mut cx: dcmi_irq::Context) {
        let now = clock::now_us();
        let ready = cx
            .shared
            .capture
            .lock(|m| super::dcmi::on_dcmi_interrupt(m, now));
        if let Some(ready) = ready {
            if frame::spawn(ready).is_err() {
                super::dcmi::release(&ready);
                super::FRAMES_LOST.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// DMA2 stream 1 (camera) error interrupt.
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    #[task(binds = DMA2_STREAM1, priority = 4, shared = [capture])]
    fn dma_irq(mut cx: dma_irq::Context) {
        cx.shared.capture.lock(super::dcmi::on_dma_interrupt);
    }

    /// Edge-FS on the ready frame, then the estimate to the autopilot (and mirrored to the
    /// host link in the qemu and hil flavours). A frame whose buffer was refilled while it was
    /// processed sends nothing and clears the flow history.
    #[task(priority = 2, shared = [board, frames, link_tx, host_tx, capture])]
    async fn frame(mut cx: frame::Context, ready: FrameReady) {
        match run_frame(
            &mut cx.shared.board,
            &mut cx.shared.frames,
            &mut cx.shared.link_tx,
            ready,
        ) {
            None => cx.shared.capture.lock(|m| m.on_frame_overwritten()),
            Some(Some(est)) => cx.shared.host_tx.lock(|tx| {
                if let Some(tx) = tx {
                    send_to_host(&BoardToHost::Estimate(est), &mut |f| queue_frame(tx, f));
                }
            }),
            Some(None) => {}
        }
    }

    /// The frame task's body: `None` when the frame's buffer was refilled during processing,
    /// `Some(None)` when there was no frame, `Some(Some(estimate))` when one was sent.
    fn run_frame(
        board: &mut impl Mutex<T = &'static mut StereoBoardApp>,
        frames: &mut impl Mutex<T = Frames>,
        link_tx: &mut impl Mutex<T = TxWriter>,
        ready: FrameReady,
    ) -> Option<Option<protocol::Estimate>> {
        let start = timebase::Instant::from_micros(clock::lib_now_us());
        (board, frames, link_tx).lock(|board, frames, tx| {
            for _ in 0..super::FRAMES_LOST.swap(0, Ordering::Relaxed) {
                board.frame_dropped();
            }
            let Some((buf, capture_us)) = frames.take(&ready) else {
                return Some(None);
            };
            let capture = timebase::Instant::from_micros(capture_us);
            let out = board.process_frame(buf, capture, start);
            let intact = frames.intact(&ready);
            frames.release(&ready);
            if !intact {
                board.discard_processed_frame();
                return None;
            }
            let done = timebase::Instant::from_micros(clock::lib_now_us());
            Some(Some(board.send_estimate(&out, capture, done, &mut |f| {
                queue_frame(tx, f)
            })))
        })
    }

    /// 1 Hz: capture state, status and heartbeat to the autopilot, LED, watchdog. A stopped
    /// camera is reported and capture re-armed.
    #[task(priority = 1, shared = [board, link_tx, host_tx, capture, iwdg])]
    async fn status(mut cx: status::Context) {
        loop {
            let now = timebase::Instant::from_micros(clock::now_us());
            #[cfg(not(any(feature = "qemu", feature = "hil")))]
            {
                let (counts, stopped) = cx.shared.capture.lock(|m| {
                    let stopped = m.camera_stopped(now.as_micros());
                    if stopped {
                        super::dcmi::rearm(m);
                    }
                    (m.counts(), stopped)
                });
                cx.shared.board.lock(|b| b.report_capture(counts, stopped));
            }
            let status = (&mut cx.shared.board, &mut cx.shared.link_tx)
                .lock(|board, tx| board.status_tick(now, &mut |f| queue_frame(tx, f)));
            // The host link gets a heartbeat too: a HIL host starts streaming once it sees one
            // (bytes sent before the USART is enabled are lost).
            let hb = protocol::Heartbeat::new(protocol::Node::StereoBoard, status.uptime_ms);
            cx.shared.host_tx.lock(|tx| {
                if let Some(tx) = tx {
                    send_to_host(&BoardToHost::Heartbeat(hb), &mut |f| queue_frame(tx, f));
                }
            });
            super::pins::toggle(&stereo_board::board::LED);
            cx.shared.iwdg.lock(|w| w.feed());
            let tx_dropped = cx.shared.link_tx.lock(|tx| tx.dropped_frames());
            let (rx_ok, host_errors, gyro_age) = cx.shared.board.lock(|b| {
                (
                    b.link_frames_ok(),
                    b.host_link_errors(),
                    b.gyro_age(timebase::Instant::from_micros(clock::lib_now_us()))
                        .map_or(u64::MAX, |d| d.as_micros()),
                )
            });
            let c = status.capture;
            log::info!(
                "status uptime_ms={} frames={} dropped={} link_rx_ok={} link_errors={} host_errors={} host_crc={} host_too_long={} rx_lost={} link_tx_dropped={} gyro_age_us={} camera_stopped={} frames_complete={} frames_torn={} dcmi_overruns={} dcmi_errors={} dma_errors={} rearms={} frames_overwritten={} stack_free={}",
                status.uptime_ms,
                status.frames_processed,
                status.frames_dropped,
                rx_ok,
                status.link_errors.total(),
                host_errors.total(),
                host_errors.crc,
                host_errors.too_long,
                super::RX_LOST.load(Ordering::Relaxed),
                tx_dropped,
                gyro_age,
                status.camera_stopped,
                c.frames_complete,
                c.frames_torn,
                c.dcmi_overruns,
                c.dcmi_sync_errors,
                c.dma_errors,
                c.rearms,
                c.frames_overwritten,
                board_support::stack::free_bytes()
            );
            Mono::delay(Duration::from_ticks(STATUS_PERIOD_US / 1_000)).await;
        }
    }
}

/// The link UART's interrupt body: queued frames out, received bytes into `queue` (pausing at a
/// full queue), the decoding task woken.
fn link_interrupt(
    rx: &mut stm32f4xx_hal::serial::Rx<LinkUart>,
    queue: &mut heapless::spsc::Producer<'static, u8>,
    wake: &mut rtic_sync::channel::Sender<'static, (), 1>,
    pump: &mut board_support::uart_tx::TxPump<LinkUart>,
) {
    pump.pump();
    board_support::uart_rx::drain(rx, queue, &LINK_FLOW, &RX_LOST);
    let _ = wake.try_send(());
}

/// The log line of a save, told from the storage's counters before and after a batch of
/// received bytes: saved, or not and why (the flash's error, if it refused).
fn log_save(
    before: Option<protocol::params::StorageStatus>,
    after: Option<protocol::params::StorageStatus>,
    flash: Option<board_support::param_flash::FlashError>,
) {
    let (Some(before), Some(after)) = (before, after) else {
        return;
    };
    if after.saves != before.saves {
        log::info!("parameters: saved");
    }
    if after.failed_saves != before.failed_saves {
        match flash {
            Some(e) => defmt::warn!("parameters: not saved (the flash refused: {})", e),
            None => defmt::warn!("parameters: not saved (SaveFailed: read back other bytes)"),
        }
    }
}
